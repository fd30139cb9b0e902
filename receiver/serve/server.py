"""`occloc serve`: the lighting server of thesis sections 4.1-4.4, over UDP.

The device (phone, `occloc run --server`) detects, decodes and ranges its LEDs itself and uploads
one datagram per frame: LED IDs with their undistorted image points and ranges (thesis 4.3,
"the measured distance with the corresponding LED-ID sent to the lighting server as a data
packet"). The server holds the LED map (4.2.1: "all LED light fixture coordinates stored in the
lighting server") and one `receiver.locate.posefilter.PoseFilter` per device: it solves the fix (4.3.1,
multilateration / range + angle) and runs the Kalman filter (4.3.2), and replies with the
position. A device silent for `forget_s` seconds is forgotten (4.4, "suspended signal
propagation": the server stops serving a device it no longer hears).

Datagram format v1 (one UTF-8 JSON object per UDP datagram, at most `MAX_DATAGRAM_BYTES`):

Request (device -> server), one per frame, also for frames without LEDs (the filter coasts):
    {"v": 1, "device": "phone-7", "seq": 12, "t": 0.400, "sigma_uv": 0.0003,
     "leds": [{"id": 42, "u": 0.0123, "v": -0.2051, "distance_m": 2.98, "sigma_m": 0.004,
               "cx": 612.3, "cy": 200.1}],
     "camera": {...}}
  * `device`: string of 1..64 characters naming the device (its filter).
  * `seq`: integer 0..2^53, strictly increasing per device; a datagram whose seq is not above the
    last accepted one (duplicate, out of order) is dropped without a reply.
  * `t`: the device's frame time, seconds (its own clock; the Kalman filter's time axis).
  * `sigma_uv`: 1-sigma of the image points, normalized units (pixels / focal length in pixels).
  * `leds` (at most `MAX_LEDS`): `id` integer 0..2^31-1, unique in the datagram; `u`, `v` the
    undistorted normalized image point of the LED (OpenCV camera frame: x right, y down, divided
    by z; `receiver.locate.indoor.Positioner.image_points`), |u|, |v| <= `MAX_ABS_UV`; `distance_m`,
    `sigma_m`: camera-to-LED range and its 1-sigma, metres, in DISTANCE_RANGE_M and SIGMA_M_RANGE, or both null /
    absent (no range); `cx`, `cy` (optional): the distorted centroid in pixels, informational.
  * `camera` (optional object) and any other keys: informational, ignored.
  * Numbers must be finite (`NaN`, `Infinity` or overflowing literals are rejected); booleans are
    not numbers.

Reply (server -> the request's source address):
    {"v": 1, "device": "phone-7", "seq": 12, "position": {...} | null, "unknown_ids": [7],
     "n_used": 3, "solve_R_cw": [[...], [...], [...]] | null}
  * `position`: exactly the `position` object `occloc run` writes (INTERFACES.md, map frame,
    metres; filtered, with `raw`, `cov`, `R_wc` ... ), or null.
  * `unknown_ids`: the request's IDs the server's map does not know (sorted; not used).
  * `n_used`: LEDs used for the fix.
  * `solve_R_cw`: this frame's fix orientation, world-to-camera, in the server's solving frame
    (the map frame, or its y-mirror for a left-handed map: `receiver.locate.posefilter.PoseFilter`), full
    precision; null without a fix or orientation. The device uses it for its next range
    estimates (the oblique estimator's foreshortening), exactly as a local `Positioner` would.

Error reply, for a request that is dropped as malformed or refused (never for `old_seq`):
    {"v": 1, "error": "<reason>", "detail": "<one line>", "device": ..., "seq": ...}
  with `device` / `seq` present when they could be read. Reasons (each counted): `oversized`,
  `bad_json` (not UTF-8, not JSON, NaN/Infinity tokens, nesting too deep), `not_object`,
  `bad_version` (`v` missing or not 1), `missing_field`, `bad_type`, `bad_value` (also a
  number outside its physical range: `receiver.serve.wire` DISTANCE_RANGE_M ...),
  `too_many_leds`, `too_many_devices` (a new device beyond `max_devices`),
  `too_many_devices_per_source` (a new device beyond `max_devices_per_source` for one source
  host), `internal_error` (the solver failed or gave a non-finite result; the device's filter
  is dropped, so no NaN state is kept). Dropped silently: `old_seq`. Replies are strict JSON
  (`handle_datagram`: never NaN / Infinity; an unencodable reply becomes `internal_error`).

Limits keep every datagram's work bounded: `MAX_DATAGRAM_BYTES`, `MAX_LEDS`, `max_devices`,
`max_devices_per_source`.
Forgetting uses the server's monotonic clock at reception; silent devices are swept lazily when
any datagram arrives (a device is forgotten when silent for more than `forget_s`; an `old_seq`
datagram does not count as hearing from it, so a device that restarts its seq at 0 under the same
name is heard again after `forget_s`).

Layers: `parse_request` (bytes -> `Request`, raising `ProtocolError`) and `LightingServer.handle`
(bytes -> reply dict or None) are plain code, tested without sockets; `serve_until` and
`BackgroundServer` put them on an asyncio UDP endpoint; `main` is the command.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from receiver.core.errors import InputError
from receiver.serve.wire import (PROTOCOL_VERSION, ProtocolError, REASONS, Request, all_finite, encode,
                                 parse_request)

if TYPE_CHECKING:  # the solver is imported once the socket is bound (start-up latency)
    from receiver.locate.posefilter import PoseFilter
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 9720
# Thesis 4.4: stop serving a device after this much silence (s, server clock).
DEFAULT_FORGET_S = 5.0
DEFAULT_MAX_DEVICES = 10000
# Devices one source address (IP, any port) may hold at once, so one client cannot fill the table.
DEFAULT_MAX_DEVICES_PER_SOURCE = 64


# ---------------------------------------------------------------- the server's state

def _pose_filter_class():
    """`receiver.locate.posefilter.PoseFilter`, imported on first use: it pulls in the solver and
    the Kalman filter's SciPy (about 2 s), which `occloc serve` loads after it has announced
    itself (`LightingServer.warm_up`)."""
    from receiver.locate.posefilter import PoseFilter

    return PoseFilter


@dataclass
class _Device:
    pose: PoseFilter
    seq: int
    seen: float           # server monotonic time of the last accepted datagram, s
    source: object = None  # the source address (host) that created it, None without a socket


def _str_or_none(v):
    return v if isinstance(v, str) else None


def _int_or_none(v):
    return v if type(v) is int else None


class LightingServer:
    """The protocol without sockets: `handle(datagram bytes) -> reply dict or None`.

    `led_map`: receiver.io.LedMap. `forget_s`: a device silent for longer (server clock
    `clock()`, seconds, monotonic) is forgotten. `max_devices`: devices held at once; a new one
    beyond it gets a `too_many_devices` error. `max_devices_per_source`: devices created from
    one source address (its host, any port) held at once; a new one beyond it gets a
    `too_many_devices_per_source` error. `counters`: datagrams, replies, positions,
    new_devices, forgotten and each reason of REASONS.
    """

    def __init__(self, led_map, *, forget_s: float = DEFAULT_FORGET_S,
                 max_devices: int = DEFAULT_MAX_DEVICES,
                 max_devices_per_source: int = DEFAULT_MAX_DEVICES_PER_SOURCE, clock=time.monotonic):
        self.led_map, self.forget_s, self.max_devices, self.clock = led_map, forget_s, max_devices, clock
        self.max_devices_per_source = max_devices_per_source
        self.devices: OrderedDict[str, _Device] = OrderedDict()   # least recently heard first
        self.per_source: Counter = Counter()                      # source host -> devices held
        self.counters: Counter = Counter()

    def handle(self, data: bytes, source=None) -> dict | None:
        """One datagram in; the reply (a position or an error) or None (dropped silently).
        `source`: the sender's address ((host, port, ...) or None); devices are bounded per host."""
        self.counters["datagrams"] += 1
        now = self.clock()
        self._forget_silent(now)
        req = None
        try:
            req = parse_request(data)
            reply = self._locate(req, now, None if source is None else source[0])
        except ProtocolError as e:
            self.counters[e.reason] += 1
            if e.reason == "old_seq":
                return None
            reply = e.reply()
        except Exception as e:   # noqa: BLE001 -- a solver failure must not stop the server
            self.counters["internal_error"] += 1
            if req is not None:
                self._drop(req.device)               # its filter may be half updated
            reply = ProtocolError("internal_error", type(e).__name__, getattr(req, "device", None),
                                  getattr(req, "seq", None)).reply()
        self.counters["replies"] += 1
        return reply

    def warm_up(self) -> None:
        """Import the solver and filter now rather than at the first device's datagram."""
        _pose_filter_class()

    def handle_datagram(self, data: bytes, source=None) -> bytes | None:
        """`handle`, encoded as strict JSON (never NaN / Infinity): what the socket sends back.
        A reply that cannot be encoded becomes an `internal_error` reply."""
        reply = self.handle(data, source)
        if reply is None:
            return None
        try:
            return encode(reply)
        except (TypeError, ValueError) as e:
            self.counters["internal_error"] += 1
            if "error" not in reply:
                self._drop(reply.get("device"))
            return encode(ProtocolError("internal_error", f"unencodable reply: {type(e).__name__}",
                                        _str_or_none(reply.get("device")),
                                        _int_or_none(reply.get("seq"))).reply())

    def _forget_silent(self, now: float) -> None:
        while self.devices:
            name, dev = next(iter(self.devices.items()))
            if now - dev.seen <= self.forget_s:
                break
            self._drop(name)
            self.counters["forgotten"] += 1

    def _drop(self, name) -> None:
        dev = self.devices.pop(name, None)
        if dev is not None and dev.source is not None:
            self.per_source[dev.source] -= 1
            if self.per_source[dev.source] <= 0:
                del self.per_source[dev.source]

    def _device(self, req: Request, now: float, source) -> _Device:
        """The request's device (new ones are created), after the seq check; marks it heard."""
        dev = self.devices.get(req.device)
        if dev is None:
            if len(self.devices) >= self.max_devices:
                raise ProtocolError("too_many_devices", f"the server holds {self.max_devices} devices",
                                    req.device, req.seq)
            if source is not None and self.per_source[source] >= self.max_devices_per_source:
                raise ProtocolError("too_many_devices_per_source",
                                    f"this address holds {self.max_devices_per_source} devices",
                                    req.device, req.seq)
            dev = _Device(_pose_filter_class()(handedness=self.led_map.handedness, sigma_uv=req.sigma_uv), -1, now,
                          source)
            self.devices[req.device] = dev
            if source is not None:
                self.per_source[source] += 1
            self.counters["new_devices"] += 1
        elif req.seq <= dev.seq:
            raise ProtocolError("old_seq", device=req.device, seq=req.seq)
        dev.seq, dev.seen = req.seq, now
        self.devices.move_to_end(req.device)
        return dev

    def _locate(self, req: Request, now: float, source=None) -> dict:
        """Map lookup, fix (`PoseFilter.solve`) and filter (`PoseFilter.update`) of one request,
        as `receiver.locate.indoor.Positioner.step` does them for a local receiver."""
        pf = self._device(req, now, source).pose
        pf.sigma_uv = req.sigma_uv
        leds = [self.led_map.lookup(i) for i in req.ids]
        used = [k for k, led in enumerate(leds) if led is not None]
        fix = None
        if used:
            L = np.array([leds[k].xyz for k in used])
            fix = pf.solve(req.t, L, req.uv[used], req.d[used], req.sigma_d[used], pf.R_prior(req.t))
        position = pf.update(req.t, fix, len(used))
        reply = {"v": PROTOCOL_VERSION, "device": req.device, "seq": req.seq, "position": position,
                "unknown_ids": sorted({i for i, led in zip(req.ids, leds) if led is None}),
                "n_used": len(used),
                "solve_R_cw": None if fix is None or fix.R_cw is None else fix.R_cw.tolist()}
        if not all_finite(reply):
            # The solver or filter overflowed: never reply with (or keep) a NaN state.
            raise FloatingPointError("non-finite result")
        self.counters["positions"] += position is not None
        return reply

    def summary(self) -> str:
        """One line of counters for the end of a run."""
        c = self.counters
        dropped = ", ".join(f"{r} {c[r]}" for r in REASONS if c[r]) or "none"
        return (f"{c['datagrams']} datagrams, {c['replies']} replies, {c['positions']} positions; "
                f"devices: {c['new_devices']} new, {c['forgotten']} forgotten, {len(self.devices)} held; "
                f"dropped/refused: {dropped}")


# ---------------------------------------------------------------- UDP transport (asyncio)

class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, server: LightingServer):
        self.server = server
        self.transport = None

    def connection_made(self, transport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        out = self.server.handle_datagram(data, addr)
        if out is not None:
            self.transport.sendto(out, addr)

    def error_received(self, exc: Exception) -> None:
        # E.g. ICMP port unreachable for a reply to a device that went away.
        self.server.counters["socket_errors"] += 1


def format_url(address) -> str:
    host, port = address[0], address[1]
    return f"udp://[{host}]:{port}" if ":" in host else f"udp://{host}:{port}"


async def serve_until(server: LightingServer, host: str, port: int, stop: asyncio.Event,
                      on_ready=None) -> None:
    """Serve `server` on UDP host:port until `stop` is set. `on_ready(address)` is called with the
    bound (host, port) once listening. A port in use or a host not on this machine: InputError."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be in 0..65535, not {port}")
    loop = asyncio.get_running_loop()
    try:
        transport, _ = await loop.create_datagram_endpoint(lambda: _UdpProtocol(server),
                                                           local_addr=(host, port))
    except OSError as e:
        raise InputError(f"cannot listen on {format_url((host, port))}: {e.strerror or e}") from None
    try:
        if on_ready is not None:
            on_ready(transport.get_extra_info("sockname")[:2])
        await stop.wait()
    finally:
        transport.close()


class BackgroundServer:
    """A `LightingServer` served on UDP from its own thread and event loop (tests, embedding).

    Starts at construction (raises what `serve_until` raises, e.g. InputError); `address` is the
    bound (host, port). `stop()` (or leaving the `with` block) ends it and joins the thread; the
    server's counters are then final. Every wait is bounded by `timeout_s`."""

    def __init__(self, server: LightingServer, host: str = DEFAULT_HOST, port: int = 0, *,
                 timeout_s: float = 5.0):
        self.server, self.timeout_s = server, timeout_s
        self.address = None
        self._error: BaseException | None = None
        self._ready = threading.Event()
        self._loop = self._stop = None
        self._thread = threading.Thread(target=asyncio.run, args=(self._main(host, port),),
                                        name="occloc-serve", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError("the lighting server did not start")
        if self._error is not None:
            raise self._error

    async def _main(self, host: str, port: int) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()

        def ready(address):
            self.address = address
            self._ready.set()

        try:
            await serve_until(self.server, host, port, self._stop, ready)
        except BaseException as e:   # noqa: BLE001 -- handed to the constructor's thread
            self._error = e
            self._ready.set()

    @property
    def url(self) -> str:
        return format_url(self.address)

    def stop(self) -> None:
        if self._thread.is_alive() and self._loop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(self.timeout_s)
        if self._thread.is_alive():
            raise RuntimeError("the lighting server did not stop")

    def __enter__(self) -> "BackgroundServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


