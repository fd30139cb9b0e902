"""`occloc serve`: run the lighting server (`receiver.serve.server`) until SIGINT / SIGTERM /
SIGHUP, then print its counters.

Start-up order: the stop signals are caught first (a signal at any later point of start-up still
ends with the summary and exit 0), then the map is loaded (numpy only), the port bound and
`listening on ...` printed, and only then the solver and Kalman filter (SciPy, ~2 s) imported,
followed by `ready`; datagrams arriving meanwhile wait in the socket's buffer (a client with a
short reply timeout should wait for `ready`).
"""

from __future__ import annotations

import asyncio
import signal
import sys

from receiver.core.errors import InputError
from receiver.serve.server import (DEFAULT_FORGET_S, DEFAULT_HOST, DEFAULT_MAX_DEVICES,
                                   DEFAULT_MAX_DEVICES_PER_SOURCE, DEFAULT_PORT, DEFAULT_SOURCE_RATE,
                                   LightingServer, format_url, serve_until)

HELP = "lighting server: devices upload LED IDs, image points and ranges over UDP, get positions back"

STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                     if hasattr(signal, name))


# ---------------------------------------------------------------- command line

class _EarlyStop:
    """Catches the stop signals from the start of `main` until the event loop takes over."""

    def __init__(self):
        self.signum = None
        self._old = {}
        for sig in STOP_SIGNALS:
            self._old[sig] = signal.signal(sig, self._catch)

    def _catch(self, signum, _frame) -> None:
        self.signum = signum

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


async def _serve_cli(server: LightingServer, host: str, port: int, early: _EarlyStop) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in STOP_SIGNALS:
        loop.add_signal_handler(sig, stop.set)
    try:
        if early.signum is not None:   # a signal before the loop's handlers were in place
            return

        def ready(address):
            print(f"occloc serve: listening on {format_url(address)}", file=sys.stderr, flush=True)
            server.warm_up()           # signals meanwhile are queued for the loop
            print("occloc serve: ready", file=sys.stderr, flush=True)

        await serve_until(server, host, port, stop, ready)
    finally:
        for sig in STOP_SIGNALS:
            loop.remove_signal_handler(sig)


def add_arguments(p) -> None:
    p.add_argument("--map", metavar="FILE",
                   help="LED map.json (default: the bundled recordings/indoor-walk/map.json)")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to listen on (default {DEFAULT_HOST}; 0.0.0.0 for all interfaces)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, metavar="N",
                   help=f"UDP port (default {DEFAULT_PORT}; 0 picks a free one)")
    p.add_argument("--forget-s", type=float, default=DEFAULT_FORGET_S, metavar="S",
                   help=f"forget a device silent for longer than this (default {DEFAULT_FORGET_S:g} s)")
    p.add_argument("--max-devices", type=int, default=DEFAULT_MAX_DEVICES, metavar="N",
                   help=f"devices held at once (default {DEFAULT_MAX_DEVICES})")
    p.add_argument("--max-devices-per-source", type=int, default=DEFAULT_MAX_DEVICES_PER_SOURCE, metavar="N",
                   help="devices one source address (IP) may hold at once "
                        f"(default {DEFAULT_MAX_DEVICES_PER_SOURCE})")
    p.add_argument("--source-rate", type=float, default=DEFAULT_SOURCE_RATE, metavar="N",
                   help=f"datagrams per second served to one source address (default {DEFAULT_SOURCE_RATE:g}; "
                        "more are dropped unread; 0: no limit)")
    p.add_argument("--keys", metavar="FILE",
                   help="device keys, one 'DEVICE HEXKEY' line each: those devices' datagrams must carry "
                        "a valid MAC (occloc run --key-file)")


def _default_map() -> str:
    # The bundled walk recording's map (receiver.io.sources.default_source's folder, without
    # importing that module's OpenCV).
    from pathlib import Path

    import receiver

    path = Path(receiver.__file__).resolve().parent.parent / "recordings" / "indoor-walk" / "map.json"
    if not path.is_file():
        raise InputError(f"no --map given and the default map is missing: {path}")
    return str(path)


def main(args) -> int:
    early = _EarlyStop()
    try:
        from receiver.io.ledmap import load_map

        if not args.forget_s > 0:
            raise InputError("--forget-s must be positive")
        if args.max_devices < 1:
            raise InputError("--max-devices must be at least 1")
        if args.max_devices_per_source < 1:
            raise InputError("--max-devices-per-source must be at least 1")
        if not 0 <= args.source_rate <= 1e7:
            raise InputError("--source-rate must be in 0..1e7")
        keys = None
        if args.keys is not None:
            from receiver.serve.auth import load_keys
            keys = load_keys(args.keys)
        led_map = load_map(args.map or _default_map())
        server = LightingServer(led_map, forget_s=args.forget_s, max_devices=args.max_devices,
                                max_devices_per_source=args.max_devices_per_source, keys=keys,
                                source_rate=args.source_rate)
        asyncio.run(_serve_cli(server, args.host, args.port, early))
    finally:
        early.restore()
    print(f"occloc serve: {server.summary()}", file=sys.stderr, flush=True)
    return 0
