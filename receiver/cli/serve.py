"""`occloc serve`: run the lighting server (`receiver.serve.server`) until SIGINT / SIGTERM,
then print its counters.
"""

from __future__ import annotations

import asyncio
import signal
import sys

from receiver.core.errors import InputError
from receiver.serve.server import (DEFAULT_FORGET_S, DEFAULT_HOST, DEFAULT_MAX_DEVICES, DEFAULT_PORT, LightingServer,
                                   format_url, serve_until)

HELP = "lighting server: devices upload LED IDs, image points and ranges over UDP, get positions back"


# ---------------------------------------------------------------- command line

async def _serve_cli(server: LightingServer, host: str, port: int) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)

    def ready(address):
        print(f"occloc serve: listening on {format_url(address)}", file=sys.stderr, flush=True)

    await serve_until(server, host, port, stop, ready)


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


def main(args) -> int:
    from pathlib import Path

    from receiver.io.ledmap import load_map
    from receiver.io.sources import default_source

    if not args.forget_s > 0:
        raise InputError("--forget-s must be positive")
    if args.max_devices < 1:
        raise InputError("--max-devices must be at least 1")
    led_map = load_map(args.map or str(Path(default_source()) / "map.json"))
    server = LightingServer(led_map, forget_s=args.forget_s, max_devices=args.max_devices)
    asyncio.run(_serve_cli(server, args.host, args.port))
    print(f"occloc serve: {server.summary()}", file=sys.stderr, flush=True)
    return 0
