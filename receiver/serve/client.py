"""The lighting server's client: `occloc run --server udp://HOST:PORT` (thesis 4.3).

`RemotePositioner` has the interface of `receiver.locate.indoor.Positioner` (`step(t_s, leds) ->
LocateResult`, `unknown_ids`, `n_fixes`) but solves on a lighting server (`receiver.serve.server`):
ranging stays on the device, done by a local `Positioner`'s `measure`, `_ranges` and
`image_points`; the server gets one v1 datagram per frame (LED IDs, undistorted normalized image
points, ranges) and answers with the filtered position.

Orientation for ranging: the oblique range estimator needs the camera orientation (the previous
fix's, then this frame's own for the reported distances). The server's reply carries its fix's
world-to-camera rotation in the solving frame (`solve_R_cw`, full precision), and the device keeps
the latest one for `max_coast_s` seconds, the rule of `PoseFilter.R_prior`. With every reply
received, the distances and positions equal those of a local `Positioner` with the same options.

What the server does not know: `solver` (always "auto") and the ranging re-solve loop
(`receiver.locate.indoor.RANGING_ITERATIONS` 0), and the filter options (the server uses `PoseFilter`'s defaults), so
only the ranging and image-point options of `Positioner` are accepted (`CLIENT_OPTIONS`).
At most `receiver.serve.wire.MAX_LEDS` LEDs (the first, in track order) are sent per frame.

Every wait is bounded: a frame whose reply does not come within `timeout_s` (or whose port is
closed) has no position and is counted in `timeouts`; error replies are counted in `errors`
(`last_error` keeps the reason); replies to older frames are discarded. With `report` (a
function of one line) a silent or refusing server and LED IDs the server's map lacks are told
while the run goes on: the first time of each kind, then at most every REPORT_EVERY_S seconds.
With `key` (bytes) every datagram carries a MAC (`receiver.serve.auth`).

A reply is checked as strictly as the server checks a request (`check_reply`): wrong types,
NaN / infinite or out-of-range numbers in `position`, or a `solve_R_cw` / `R_wc` that is not a
rotation (orthonormal, det +1 within ROTATION_TOL) make it refused: counted in `errors` with
`last_error` "bad_reply: <reason>", and the frame has no position (nothing of it is kept).
"""

from __future__ import annotations

import json
import math
import os
import secrets
import socket
import time
from urllib.parse import urlsplit

import numpy as np

from receiver.core.errors import InputError
from receiver.locate.indoor import Positioner
from receiver.core.records import LocateResult
from receiver.locate.ranging import _with_range
from receiver.serve.wire import MAX_DEVICE_CHARS, MAX_LEDS, PROTOCOL_VERSION, encode, make_request
from receiver.serve.wire_v2 import MAX_DATAGRAM_BYTES_V2, VERSION as V2, camera_fields, make_request_v2, sendable

DEFAULT_TIMEOUT_S = 0.2
MAX_REPLY_BYTES = 65535
# Plausibility of replied numbers: coordinates within 1e6 m of the map origin, a rotation
# orthonormal with det +1 within ROTATION_TOL (the reply's R_wc is rounded to 6 decimals).
MAX_ABS_COORD_M = 1e6
ROTATION_TOL = 1e-5
# The local Positioner's options the client may set: ranging and image points only.
CLIENT_OPTIONS = frozenset({"ranging", "pixel_sigma_px", "edge_sigma_px", "edge_offset_px", "border_margin_px"})
# A server that keeps failing is reported on stderr at most this often (s, wall clock) while the
# run goes on; the first failure of each kind is reported at once.
REPORT_EVERY_S = 5.0


def parse_udp_url(url: str) -> tuple[str, int]:
    """(host, port) of `udp://HOST:PORT` (IPv6 hosts in brackets); InputError otherwise."""
    bad = InputError(f"--server must be udp://HOST:PORT with a port in 1..65535, not {url!r}")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        raise bad from None
    if parts.scheme != "udp" or not parts.hostname or not port or parts.path not in ("", "/") \
            or parts.query or parts.fragment or parts.username:
        raise bad
    return parts.hostname, port


def default_device() -> str:
    """A device name unique to this client (a restarted client is a new device to the server)."""
    return f"occloc-{os.getpid()}-{secrets.token_hex(4)}"


def _connect(url: str) -> socket.socket:
    host, port = parse_udp_url(url)
    try:
        family, kind, proto, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        sock = socket.socket(family, kind, proto)
    except OSError as e:
        raise InputError(f"--server {url}: {e.strerror or e}") from None
    try:
        sock.connect(addr)     # only the server's datagrams are received
    except OSError as e:
        sock.close()
        raise InputError(f"--server {url}: {e.strerror or e}") from None
    return sock


def _reply_object(data: bytes) -> dict | None:
    # Lenient parse (NaN / Infinity tokens read as floats) so that a reply to this frame with
    # non-finite numbers is recognised as one, then refused by `check_reply`.
    try:
        obj = json.loads(data)
    except (ValueError, RecursionError):
        return None
    return obj if isinstance(obj, dict) and obj.get("v") in (PROTOCOL_VERSION, V2) else None


class BadReply(ValueError):
    """A reply that does not hold what the protocol promises (the reason, one line)."""


def _is_number(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def _finite_tree(v, where: str) -> None:
    """Every number in a JSON value finite (json may give inf for 1e999)."""
    if isinstance(v, float) and not math.isfinite(v):
        raise BadReply(f"{where} is not finite")
    if isinstance(v, dict):
        for k, x in v.items():
            _finite_tree(x, f"{where}.{k}")
    elif isinstance(v, list):
        for i, x in enumerate(v):
            _finite_tree(x, f"{where}[{i}]")


def _xyz(obj, where: str) -> None:
    if not isinstance(obj, dict):
        raise BadReply(f"{where} must be an object")
    for k in ("x", "y", "z"):
        if not _is_number(obj.get(k)) or abs(obj[k]) > MAX_ABS_COORD_M:
            raise BadReply(f"{where}.{k} must be a finite number within {MAX_ABS_COORD_M:g} m")


def check_rotation(value, where: str) -> np.ndarray:
    """A 3 x 3 rotation (list of lists of numbers, orthonormal, det +1 within ROTATION_TOL)."""
    if not (isinstance(value, list) and len(value) == 3
            and all(isinstance(r, list) and len(r) == 3 and all(_is_number(x) for x in r) for r in value)):
        raise BadReply(f"{where} must be 3 x 3 finite numbers")
    R = np.array(value, dtype=np.float64)
    if (np.max(np.abs(R)) > 1.0 + ROTATION_TOL or np.max(np.abs(R @ R.T - np.eye(3))) > ROTATION_TOL
            or abs(float(np.linalg.det(R)) - 1.0) > ROTATION_TOL):
        raise BadReply(f"{where} is not a rotation")
    return R


def check_reply(reply: dict) -> tuple[dict | None, np.ndarray | None]:
    """(position or None, solve_R_cw or None) of a non-error reply; BadReply when anything in
    it is malformed (types, non-finite or out-of-range numbers, a matrix that is no rotation)."""
    position = reply.get("position")
    if position is not None:
        if not isinstance(position, dict):
            raise BadReply("position must be an object or null")
        _finite_tree(position, "position")
        _xyz(position, "position")
        if position.get("raw") is not None:
            _xyz(position["raw"], "position.raw")
        for k in ("std_m", "velocity_mps", "raw_std_m"):
            if k in position and not (isinstance(position[k], list) and len(position[k]) == 3
                                      and all(_is_number(x) for x in position[k])):
                raise BadReply(f"position.{k} must be 3 finite numbers")
        if "R_wc" in position:
            check_rotation(position["R_wc"], "position.R_wc")
        if "n_leds" in position and type(position["n_leds"]) is not int:
            raise BadReply("position.n_leds must be an integer")
    ids = reply.get("unknown_ids", [])
    if not isinstance(ids, list) or not all(type(i) is int for i in ids):
        raise BadReply("unknown_ids must be a list of integers")
    if "n_used" in reply and (type(reply["n_used"]) is not int or reply["n_used"] < 0):
        raise BadReply("n_used must be a non-negative integer")
    R = reply.get("solve_R_cw")
    return position, None if R is None else check_rotation(R, "solve_R_cw")


class RemotePositioner:
    """`Positioner` whose solve and Kalman filter run on a lighting server at `url`
    (`udp://HOST:PORT`). `device`: the name the server knows this receiver by (default: unique
    per instance). `timeout_s`: the longest wait for a frame's reply. `ranging_kw`: options of
    the local `Positioner` from `CLIENT_OPTIONS`. Close with `close()` or a `with` block."""

    def __init__(self, camera, led_map, url: str, *, device: str | None = None,
                 timeout_s: float = DEFAULT_TIMEOUT_S, protocol: int = V2, key: bytes | None = None,
                 report=None, **ranging_kw):
        extra = set(ranging_kw) - CLIENT_OPTIONS
        if extra:
            raise TypeError(f"options not supported with a lighting server: {sorted(extra)}")
        if protocol not in (PROTOCOL_VERSION, V2):
            raise ValueError(f"protocol must be {PROTOCOL_VERSION} or {V2}")
        if protocol == V2 and ranging_kw:
            raise TypeError("with protocol 2 the server ranges with its default settings: no ranging options")
        self.protocol, self.key, self.report = protocol, key, report
        self._camera = camera_fields(camera)
        self._reported: dict = {}     # kind -> wall time of its last report
        self.edges_trimmed = 0        # frames sent with some LEDs' edge points left out (size)
        self.device = device if device is not None else default_device()
        if not 1 <= len(self.device) <= MAX_DEVICE_CHARS:
            raise ValueError(f"device names have 1..{MAX_DEVICE_CHARS} characters")
        if not timeout_s > 0:
            raise ValueError("timeout_s must be positive")
        self.local = Positioner(camera, led_map, **ranging_kw)
        self.url, self.timeout_s = url, timeout_s
        self.sock = _connect(url)
        # of the next request; a keyed device (whose last seq the server keeps for good) starts
        # at the wall clock's milliseconds, above every seq of its earlier runs
        self.seq = 0 if key is None else time.time_ns() // 1_000_000
        self.timeouts = 0
        self.errors = 0
        self.last_error: str | None = None
        self._n_fixes = 0

    @property
    def unknown_ids(self) -> set[int]:
        """IDs the local map (or the server's, as replied) does not know."""
        return self.local.unknown_ids

    @property
    def n_fixes(self) -> int:
        """Frames the server had a fix for (`position.raw` not null)."""
        return self._n_fixes

    def step(self, t_s: float, leds) -> LocateResult:
        if self.protocol == V2:
            return self._step_v2(t_s, leds)
        ranger = self.local.ranger
        items = ranger.usable(leds)[:MAX_LEDS]
        # the server's replied orientations, kept by the rule of a local receiver (R_prior)
        d, sd, names = ranger.ranges(items, self.local.pose.R_prior(t_s))
        request = make_request(self.device, self.seq, t_s, self.local.pose.sigma_uv,
                               [obs.id for obs, _, _ in items], ranger.image_points(items), d, sd)
        self.seq += 1
        reply = self._exchange(request)
        position = None
        if reply is not None:
            position, R = self._accept(reply, t_s)
            if R is not None and self.local.ranging == "oblique":
                d, sd, names = ranger.ranges(items, R)    # this frame's own orientation
        return LocateResult(position=position, leds=ranger.annotate(leds, items, d, names))

    def _request_v2(self, t_s: float, sent) -> bytes:
        """The frame's v2 datagram; when it would not fit in one UDP datagram, the edge points
        of the LEDs with the most of them are left out (those LEDs are then solved on their
        centroids only) and the frame is counted in `edges_trimmed`."""
        with_edges = [o.edge_px is not None for o in sent]
        order = sorted(range(len(sent)), key=lambda k: -len(sent[k].edge_px[0]) if with_edges[k] else 0)
        for drop in range(len(order) + 1):
            for k in order[:drop]:
                with_edges[k] = False
            data = self._sign(encode(make_request_v2(self.device, self.seq, t_s, self._camera, sent, with_edges)))
            if len(data) <= MAX_DATAGRAM_BYTES_V2:
                self.edges_trimmed += drop > 0
                return data
        raise ValueError("a frame's observations do not fit in one datagram")

    def _sign(self, body: bytes) -> bytes:
        if self.key is None:
            return body
        from receiver.serve.auth import sign
        return sign(self.key, self.device, self.seq, body)

    def _step_v2(self, t_s: float, leds) -> LocateResult:
        sent = sendable(leds)
        data = self._request_v2(t_s, sent)
        seq = self.seq
        self.seq += 1
        reply = self._exchange_bytes(data, seq)
        if reply is None:
            return LocateResult(position=None, leds=list(leds))
        position, _ = self._accept(reply, t_s)
        ranges = reply.get("ranges")
        ranged = {}
        if isinstance(ranges, list) and len(ranges) == len(sent):
            for o, r in zip(sent, ranges):
                if (isinstance(r, list) and len(r) == 2 and _is_number(r[0]) and r[0] > 0
                        and isinstance(r[1], str)):
                    ranged[id(o)] = (r[0], r[1])
        elif position is not None:
            self.errors += 1
            self.last_error = "bad_reply: ranges must hold one entry per LED sent"
        out = [o if id(o) not in ranged else _with_range(o, *ranged[id(o)]) for o in leds]
        return LocateResult(position=position, leds=out)

    def _note(self, kind: str, text: str) -> None:
        """Tell the user about a failing server while the run goes on: the first time of each
        kind, then at most every REPORT_EVERY_S seconds."""
        if self.report is None:
            return
        now = time.monotonic()
        last = self._reported.get(kind)
        if last is not None and now - last < REPORT_EVERY_S:
            return
        self._reported[kind] = now
        self.report(f"occloc: server {self.url}: {text}")

    def _accept(self, reply: dict, t_s: float) -> tuple[dict | None, np.ndarray | None]:
        """(position, solving-frame R_cw or None) of a matching reply, checked (`check_reply`);
        keeps its orientation. A malformed reply counts as a server error and gives nothing."""
        try:
            position, R = check_reply(reply)
        except BadReply as e:
            self.errors += 1
            self.last_error = f"bad_reply: {e}"
            return None, None
        new = set(reply.get("unknown_ids", [])) - self.local.unknown_ids
        if new:
            self.local.unknown_ids.update(new)
            self._note("unknown_ids", f"LED IDs not in the server's map: {', '.join(map(str, sorted(new)))}")
        if position is not None and position.get("raw") is not None:
            self._n_fixes += 1
        if R is not None:
            self.local.pose.keep_orientation(t_s, R)
        return position, R

    def _exchange(self, request: dict) -> dict | None:
        """Send one request; its reply, or None after `timeout_s` or an error reply."""
        return self._exchange_bytes(self._sign(encode(request)), request["seq"])

    def _timed_out(self) -> None:
        self.timeouts += 1
        self._note("timeout", f"no reply within {self.timeout_s:g} s ({self.timeouts} frames so far); "
                              "going on without positions for them")

    def _exchange_bytes(self, data: bytes, seq: int) -> dict | None:
        """Send one datagram; the reply to `seq`, or None after `timeout_s` or an error reply."""
        deadline = time.monotonic() + self.timeout_s
        try:
            self.sock.send(data)
        except OSError:
            self._timed_out()           # e.g. the refusal of an earlier datagram, reported late
            return None
        while (remaining := deadline - time.monotonic()) > 0:
            self.sock.settimeout(remaining)
            try:
                reply = _reply_object(self.sock.recv(MAX_REPLY_BYTES))
            except OSError:             # timeout, or nothing listens on the port
                break
            if reply is None or reply.get("device") != self.device or reply.get("seq") != seq:
                continue                # a late reply to an earlier frame, or garbage
            if "error" in reply:
                self.errors += 1
                self.last_error = str(reply["error"])
                self._note("error:" + self.last_error, f"refused a frame: {self.last_error} "
                                                       f"({self.errors} so far)")
                return None
            return reply
        self._timed_out()
        return None

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> "RemotePositioner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
