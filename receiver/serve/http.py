"""The lighting server's HTTP API and live web map (thesis 4.2: "API-based access ... [and]
web-based visualizations"): a Starlette app served by uvicorn on its own thread, beside the UDP
loop of the same `occloc serve` (`--http HOST:PORT`). Routes: docs/server.md.

    GET /api/v1/map                      the LED map as map.json has it
    GET /api/v1/devices                  live devices (`receiver.serve.live.LiveView.snapshot`)
    GET /api/v1/devices/{device}/track   stored fixes, ?since=T&until=T (Unix s), oldest first
    GET /api/v1/stream                   live fixes as Server-Sent Events (`event: fix`)
    GET /healthz                         200 "ok" while serving
    GET /metrics                         the server's counters, Prometheus text format 0.0.4
    GET /                                the live web map (receiver/serve/web/index.html)

With a bearer token (`--http-token-file FILE`) every route but /healthz needs
`Authorization: Bearer TOKEN` (or `?token=TOKEN`, for the browser's EventSource and page).
"""

from __future__ import annotations

import asyncio
import hmac
import json
import math
import threading
from pathlib import Path

from receiver.core.errors import InputError
from receiver.serve.wire import REASONS

WEB = Path(__file__).resolve().parent / "web"
# A stream sends a comment line this often (s) when there is no fix, so proxies keep it open
# and a closed client is noticed.
KEEPALIVE_S = 15.0


def _json(obj, status: int = 200):
    from starlette.responses import Response

    return Response(json.dumps(obj, separators=(",", ":"), allow_nan=False), status_code=status,
                    media_type="application/json")


def _error(status: int, text: str):
    return _json({"error": text}, status)


def metrics_text(server, live=None, store=None) -> str:
    """The counters in the Prometheus text format."""
    c = server.counters
    out = []

    def metric(name, kind, help_, samples):
        out.append(f"# HELP occloc_{name} {help_}")
        out.append(f"# TYPE occloc_{name} {kind}")
        for labels, v in samples:
            out.append(f"occloc_{name}{labels} {v}")

    metric("datagrams_total", "counter", "UDP datagrams received", [("", c["datagrams"])])
    metric("replies_total", "counter", "replies sent (positions and errors)", [("", c["replies"])])
    metric("positions_total", "counter", "replies with a position", [("", c["positions"])])
    metric("refused_total", "counter", "datagrams dropped or refused, by reason",
           [(f'{{reason="{r}"}}', c[r]) for r in REASONS])
    metric("error_replies_limited_total", "counter", "error replies not sent (rate or size limit)",
           [("", c["error_replies_limited"])])
    metric("state_errors_total", "counter", "failed round trips to the shared state (--state)",
           [("", c["state_errors"])])
    metric("devices_new_total", "counter", "devices created", [("", c["new_devices"])])
    metric("devices_forgotten_total", "counter", "devices forgotten", [("", c["forgotten"])])
    metric("devices", "gauge", "devices held by this process", [("", len(server.devices))])
    if store is not None:
        metric("fixes_stored_total", "counter", "fixes written to the database", [("", store.written)])
        metric("fixes_store_dropped_total", "counter", "fixes not stored (queue full or database error)",
               [("", store.dropped)])
    return "\n".join(out) + "\n"


def _number_arg(request, name: str):
    v = request.query_params.get(name)
    if v is None:
        return None
    try:
        f = float(v)
    except ValueError:
        raise ValueError(f"{name} must be a number (Unix seconds)") from None
    if not math.isfinite(f):
        raise ValueError(f"{name} must be finite")
    return f


def make_app(server, live, map_json: dict, store=None, token: str | None = None):
    """The Starlette app of a LightingServer (`server`, for its counters), its LiveView,
    the map object, an optional FixStore (track history) and bearer token."""
    from starlette.applications import Starlette
    from starlette.responses import FileResponse, PlainTextResponse, StreamingResponse
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    def allowed(request) -> bool:
        if token is None:
            return True
        given = request.headers.get("authorization", "")
        given = given[7:] if given.lower().startswith("bearer ") else request.query_params.get("token", "")
        return hmac.compare_digest(given.encode(), token.encode())

    def guarded(handler):
        async def wrapped(request):
            if not allowed(request):
                r = _error(401, "a bearer token is required")
                r.headers["WWW-Authenticate"] = "Bearer"
                return r
            return await handler(request)
        return wrapped

    async def get_map(request):
        return _json(map_json)

    async def devices(request):
        return _json(live.snapshot())

    async def track(request):
        if store is None:
            return _error(404, "no fixes are stored: start occloc serve with --db FILE")
        try:
            since, until = _number_arg(request, "since"), _number_arg(request, "until")
        except ValueError as e:
            return _error(400, str(e))
        rows = await asyncio.get_running_loop().run_in_executor(
            None, store.track, request.path_params["device"], since, until)
        return _json(rows)

    async def stream(request):
        q = live.subscribe()

        async def events():
            try:
                yield b": occloc live fixes\n\n"
                while True:
                    try:
                        event = await asyncio.wait_for(q.get(), KEEPALIVE_S)
                    except asyncio.TimeoutError:
                        yield b": keepalive\n\n"
                        continue
                    yield b"event: fix\ndata: " + json.dumps(event, separators=(",", ":")).encode() + b"\n\n"
            finally:
                live.unsubscribe(q)

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def healthz(request):
        return PlainTextResponse("ok\n")

    async def metrics(request):
        return PlainTextResponse(metrics_text(server, live, store), media_type="text/plain; version=0.0.4")

    async def index(request):
        return FileResponse(WEB / "index.html", media_type="text/html")

    routes = [
        Route("/api/v1/map", guarded(get_map)),
        Route("/api/v1/devices", guarded(devices)),
        Route("/api/v1/devices/{device:str}/track", guarded(track)),
        Route("/api/v1/stream", guarded(stream)),
        Route("/healthz", healthz),
        Route("/metrics", guarded(metrics)),
        Route("/", guarded(index)),
    ]
    if (WEB / "static").is_dir():
        routes.append(Mount("/static", StaticFiles(directory=str(WEB / "static"))))
    return Starlette(routes=routes)


def parse_host_port(text: str) -> tuple[str, int]:
    """(host, port) of HOST:PORT or [V6]:PORT; InputError otherwise."""
    host, sep, port = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise InputError(f"--http must be HOST:PORT with a port in 0..65535, not {text!r}")
    return host, int(port)


def format_http_url(host: str, port: int) -> str:
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


class HttpThread:
    """uvicorn serving `app` on host:port from a thread of its own (its own event loop; no
    signal handlers: the command's own handle the stop). `address` is the bound (host, port)
    once started; `stop()` ends it. InputError when the port cannot be bound."""

    def __init__(self, app, host: str, port: int, timeout_s: float = 10.0):
        import socket

        import uvicorn

        try:
            family = socket.AF_INET6 if ":" in host else socket.AF_INET
            self.sock = socket.socket(family, socket.SOCK_STREAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, port))
            self.sock.listen(128)
        except OSError as e:
            raise InputError(f"cannot serve http on {format_http_url(host, port)}: {e.strerror or e}") from None
        self.address = self.sock.getsockname()[:2]
        config = uvicorn.Config(app, log_level="error", access_log=False, lifespan="off",
                                timeout_graceful_shutdown=1)
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._run, name="occloc-http", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        asyncio.run(self.server.serve(sockets=[self.sock]))

    @property
    def url(self) -> str:
        return format_http_url(*self.address)

    def stop(self, timeout_s: float = 5.0) -> None:
        self.server.should_exit = True
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            self.server.force_exit = True
            self._thread.join(timeout_s)
        self.sock.close()
