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
                                   DEFAULT_MAX_DEVICES_PER_SOURCE, DEFAULT_PORT, DEFAULT_SOURCE_CPU_SHARE,
                                   DEFAULT_SOURCE_RATE,
                                   LightingServer, format_url, serve_until)

DEFAULT_RETENTION_S = 7 * 24 * 3600.0   # receiver.serve.store's (not imported before the port is bound)
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


async def _serve_cli(server: LightingServer, host: str, port: int, early: _EarlyStop, http_start=None,
                     reuse_port: bool = False) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in STOP_SIGNALS:
        loop.add_signal_handler(sig, stop.set)
    try:
        if early.signum is not None:   # a signal before the loop's handlers were in place
            return

        def ready(address):
            print(f"occloc serve: listening on {format_url(address)}", file=sys.stderr, flush=True)
            if http_start is not None:
                print(f"occloc serve: http on {http_start()}", file=sys.stderr, flush=True)
            server.warm_up()           # signals meanwhile are queued for the loop
            print("occloc serve: ready", file=sys.stderr, flush=True)

        await serve_until(server, host, port, stop, ready, reuse_port)
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
                        "more are dropped unread; 0: no per-source limits at all)")
    p.add_argument("--source-cpu-share", type=float, default=DEFAULT_SOURCE_CPU_SHARE, metavar="F",
                   help=f"CPU seconds per second one source address's datagrams may take (default "
                        f"{DEFAULT_SOURCE_CPU_SHARE:g}); beyond it they are dropped unread")
    p.add_argument("--http", metavar="HOST:PORT",
                   help="also serve the HTTP API and live web map there (e.g. 127.0.0.1:8080; port 0 "
                        "picks a free one; docs/server.md)")
    p.add_argument("--http-token-file", metavar="FILE",
                   help="the HTTP API then needs 'Authorization: Bearer TOKEN', TOKEN the file's first line")
    p.add_argument("--db", metavar="FILE",
                   help="store every fix in this SQLite database (kept across restarts; the track API "
                        "reads it)")
    p.add_argument("--retention-days", type=float, default=DEFAULT_RETENTION_S / 86400, metavar="D",
                   help=f"delete stored fixes older than this (default {DEFAULT_RETENTION_S / 86400:g} days)")
    p.add_argument("--state", metavar="redis://HOST:PORT/DB",
                   help="keep device state in this Redis, shared with every occloc serve using it "
                        "(any of them serves any device; its HTTP stream relays all positions)")
    p.add_argument("--reuse-port", action="store_true",
                   help="bind with SO_REUSEPORT: several occloc serve --state ... on one port of one host")
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


def _read_token(path: str) -> str:
    try:
        with open(path, encoding="utf-8") as f:
            token = f.readline(4096).strip()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"--http-token-file {path}: {getattr(e, 'strerror', None) or e}") from None
    if len(token) < 16 or any(c.isspace() or not c.isprintable() for c in token):
        raise InputError(f"--http-token-file {path}: the first line must be a token of at least 16 "
                         "printable characters")
    return token


class _Service:
    """What `occloc serve` runs beside the UDP loop: the live view, the fix store (--db) and the
    HTTP thread (--http), wired to the server's observers."""

    def __init__(self, server: LightingServer, args, map_path: str):
        self.server, self.args, self.map_path = server, args, map_path
        self.http = self.store = None
        self.live = None
        if args.db is not None:
            from receiver.serve.store import FixStore
            self.store = FixStore(args.db, args.retention_days * 86400.0)
            server.key_seq.update({d: s for d, s in self.store.seqs().items() if d in server.keys})
        if args.http is not None or self.store is not None:
            from receiver.serve.live import LiveView
            self.live = LiveView(forget_s=args.forget_s)
            server.on_fix, server.on_forget = self._on_fix, self.live.forget
            if server.shared is not None:
                live = self.live
                server.shared.relay(lambda e: live.fix(str(e.get("device")), e.get("t_device"), e.get("position"),
                                                       e.get("ids") or []))

    def _on_fix(self, device, t_device, position, ids, seq, keyed) -> None:
        self.live.fix(device, t_device, position, ids)
        if self.store is not None and position is not None:
            self.store.add(device, t_device, position, ids, seq if keyed else None)

    def start_http(self) -> str:
        import json

        from receiver.serve.http import HttpThread, make_app, parse_host_port

        with open(self.map_path, encoding="utf-8") as f:
            map_json = json.load(f)
        token = _read_token(self.args.http_token_file) if self.args.http_token_file else None
        host, port = parse_host_port(self.args.http)
        self.http = HttpThread(make_app(self.server, self.live, map_json, self.store, token), host, port)
        return self.http.url

    def close(self) -> None:
        if self.http is not None:
            self.http.stop()
        if self.store is not None:
            self.store.close()        # every queued fix is written
        if self.server.shared is not None:
            self.server.shared.close()


def main(args) -> int:
    early = _EarlyStop()
    service = None
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
        if not 0 < args.source_cpu_share <= 64:
            raise InputError("--source-cpu-share must be in 0..64 (exclusive of 0)")
        if not 0 < args.retention_days <= 1e5:
            raise InputError("--retention-days must be in 0..1e5 (exclusive of 0)")
        if args.http is not None:
            from receiver.serve.http import parse_host_port
            parse_host_port(args.http)
        if args.http_token_file is not None:
            if args.http is None:
                raise InputError("--http-token-file needs --http HOST:PORT")
            _read_token(args.http_token_file)
        keys = None
        if args.keys is not None:
            from receiver.serve.auth import load_keys
            keys = load_keys(args.keys)
        if args.state is not None:
            from receiver.serve.shared import check_url
            check_url(args.state)
        map_path = args.map or _default_map()
        led_map = load_map(map_path)
        shared = None
        if args.state is not None:
            from receiver.serve.shared import SharedState
            shared = SharedState(args.state, led_map, args.forget_s)
        server = LightingServer(led_map, forget_s=args.forget_s, max_devices=args.max_devices,
                                max_devices_per_source=args.max_devices_per_source, keys=keys,
                                source_rate=args.source_rate, shared=shared,
                                source_cpu_share=args.source_cpu_share)
        service = _Service(server, args, map_path)
        if args.reuse_port and args.state is None:
            raise InputError("--reuse-port needs --state redis://...: the servers must share their devices")
        asyncio.run(_serve_cli(server, args.host, args.port, early,
                               service.start_http if args.http is not None else None, args.reuse_port))
    finally:
        early.restore()
        if service is not None:
            service.close()
    print(f"occloc serve: {server.summary()}", file=sys.stderr, flush=True)
    return 0
