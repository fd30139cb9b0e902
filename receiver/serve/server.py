"""`occloc serve`: the lighting server of thesis sections 4.1-4.4, over UDP.

The device (phone, `occloc run --server`) detects, decodes and ranges its LEDs itself and uploads
one datagram per frame: LED IDs with their undistorted image points and ranges (thesis 4.3,
"the measured distance with the corresponding LED-ID sent to the lighting server as a data
packet"). The server holds the LED map (4.2.1: "all LED light fixture coordinates stored in the
lighting server") and one `receiver.locate.posefilter.PoseFilter` per device: it solves the fix (4.3.1,
multilateration / range + angle) and runs the Kalman filter (4.3.2), and replies with the
position. A device silent for `forget_s` seconds is forgotten (4.4, "suspended signal
propagation": the server stops serving a device it no longer hears).

Datagram format v2 (`receiver.serve.wire_v2`, what `occloc run --server` sends): the frame's
observations with their outlines; the server steps a `receiver.locate.indoor.Positioner` per
device, so the positions are the local run's. v1 stays accepted:

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

Layers: `wire_v2.parse_any` (bytes -> `Request` or `RequestV2`, raising `ProtocolError`) and `LightingServer.handle`
(bytes -> reply dict or None; `handle_many` for datagrams received together, whose fixes are
solved in one batch) are plain code, tested without sockets; `serve_socket` serves them on a UDP
socket in a plain loop (every datagram already queued is handled in the same batch), and
`serve_until` / `BackgroundServer` run that loop on a thread until an asyncio event / `stop()`;
`receiver.cli.serve` is the command.
"""

from __future__ import annotations

import asyncio
import json
import select
import socket
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import dataclass
from json.encoder import encode_basestring_ascii
from typing import TYPE_CHECKING

import numpy as np

from receiver.core import native
from receiver.core.errors import InputError
from receiver.serve.wire import PROTOCOL_VERSION, ProtocolError, REASONS, Request, all_finite, encode
from receiver.serve.auth import PREFIX as MAC_PREFIX, verify
from receiver.serve.limits import SourceBuckets
from receiver.serve.queues import SourceQueues
from receiver.serve.wire_v2 import VERSION as V2, RequestV2, parse_any, ranges_of

if TYPE_CHECKING:  # the solver is imported once the socket is bound (start-up latency)
    from receiver.locate.posefilter import PoseFilter
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 9720
# Thesis 4.4: stop serving a device after this much silence (s, server clock).
DEFAULT_FORGET_S = 5.0
DEFAULT_MAX_DEVICES = 10000
# Devices one source address (IP, any port) may hold at once, so one client cannot fill the table.
DEFAULT_MAX_DEVICES_PER_SOURCE = 64
# Datagrams served per second per source host (a token bucket of twice that many): ten phones at
# 30 frames/s behind one address; a flood beyond it is dropped before parsing ("rate_limited").
DEFAULT_SOURCE_RATE = 300.0
# CPU seconds per second the datagrams of one source host may take (a bucket of a tenth of a
# second): a flood of expensive datagrams (64 LEDs: ~0.33 ms each; v2 frames with outlines:
# ~1.6 ms) from a few addresses cannot take the core from the others. 0.15 serves three v2
# phones or thirty 4-LED v1 ones at 30 frames/s behind one address.
DEFAULT_SOURCE_CPU_SHARE = 0.15
# Error replies per second (burst: twice) sent to one host for datagrams not proven by a MAC:
# a forged source address gets at most this many replies, each no larger than its request.
ERROR_REPLY_RATE = 5.0
# How far ahead of a live device's last accepted seq a datagram may jump (a missing stretch of
# 2^20 frames is 9.7 hours at 30 frames/s); beyond it the datagram is refused ("seq_jump").
SEQ_WINDOW = 1 << 20
# Socket loop (`serve_socket`): datagrams handled together at most (the ones already queued when
# the loop looks: it never waits for a batch to fill), the stop flag's polling interval (s), the
# receive buffer asked for (bytes: a burst of ~10,000 four-LED datagrams) and the largest datagram
# read (bytes, > MAX_DATAGRAM_BYTES so that an oversized one is seen as such). A batch's replies
# are sent when the whole batch is solved; with the compiled fix a datagram costs about the same
# alone as in a batch (README "Measured"), so the bound only caps how long the first datagram of
# a backlog waits for its reply: 16 x ~0.1 ms.
MAX_BATCH = 16
# A batch also ends once it holds this many bytes: its datagrams are answered together, so a
# datagram waits for the whole batch's work, which grows with the LEDs and points carried (four
# 64-LED datagrams, ~1.3 ms; one v2 frame with outlines). A small one behind a run of large ones
# (another source's flood) waits for at most this much more work.
MAX_BATCH_BYTES = 32768
# Datagrams read from the socket into the per-source queues at most between two batches (what the
# socket's buffer holds of 4-LED datagrams: after the server was held up, everything waiting is
# read, ~3 us each, before the next batch, so every host's datagrams join the turns at once),
# and the bytes queued at most for one source host and for all (`serve_socket`,
# `receiver.serve.queues`): a quarter of a second of one host's 64-LED datagrams at the default
# --source-rate (75 x ~7 kB; ~1,000 4-LED ones: a deeper queue only adds delay to what an
# overloaded server serves), and sixty-four such hosts.
READ_AHEAD = 4096
MAX_SOURCE_QUEUE_BYTES = 512 << 10
MAX_QUEUE_BYTES = 32 << 20
POLL_S = 0.1
RCVBUF_BYTES = 1 << 22
RECV_BYTES = 65536
# The compiled check of requests in their common form (`wire.parse_request`'s `fast`).
WIRE_KERNEL = "receiver.serve._wire"
_UNSET = object()
# How every position reply's JSON starts (`LightingServer._reply_json`).
_REPLY_HEAD = b'{"v":' + str(PROTOCOL_VERSION).encode() + b',"device":'


# ---------------------------------------------------------------- the server's state

def _solve_batch():
    """The batch solver (`receiver.serve.fixes.frame_solver`: `receiver.locate.posefilter.solve_batch`
    with the compiled warm fix when built), imported on first use (`_pose_filter_class`)."""
    from receiver.serve.fixes import frame_solver

    return frame_solver()


def _pose_filter_class():
    """The devices' `receiver.locate.posefilter.PoseFilter` (`receiver.serve.devices`),
    imported on first use: it pulls in the solver and
    the Kalman filter's SciPy (about 2 s), which `occloc serve` loads after it has announced
    itself (`LightingServer.warm_up`)."""
    from receiver.serve.devices import pose_filter_class

    return pose_filter_class()


@dataclass
class _Device:
    pose: PoseFilter | None  # the v1 datagrams' filter (made at the device's first v1 datagram)
    seq: int
    seen: float           # server monotonic time of the last accepted datagram, s
    source: object = None  # the source address (host) that created it, None without a socket
    loc: object = None    # the v2 datagrams' receiver.locate.indoor.Positioner, or None
    bound: object = None  # the (host, port) an unkeyed device's name is bound to until forgotten
    camera_key: tuple | None = None  # the camera `loc` was made for


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
    new_devices, forgotten and each reason of REASONS. `warm_start`: the devices' filters start
    each fix from their previous pose (`PoseFilter` warm_start: the same fixes within the solver's
    tolerance, at a fraction of the cost; on 600 walk datagrams the replies differed from cold
    solves by at most 1e-5 m, one unit of their 5-decimal rounding); False solves every frame from scratch,
    exactly as a local `receiver.locate.indoor.Positioner` does.
    """

    def __init__(self, led_map, *, forget_s: float = DEFAULT_FORGET_S,
                 max_devices: int = DEFAULT_MAX_DEVICES,
                 max_devices_per_source: int = DEFAULT_MAX_DEVICES_PER_SOURCE, clock=time.monotonic,
                 warm_start: bool = True, keys: dict | None = None, source_rate: float = DEFAULT_SOURCE_RATE,
                 error_rate: float = ERROR_REPLY_RATE, shared=None,
                 source_cpu_share: float = DEFAULT_SOURCE_CPU_SHARE):
        self.led_map, self.forget_s, self.max_devices, self.clock = led_map, forget_s, max_devices, clock
        self.warm_start = warm_start
        self.keys = dict(keys or {})
        # keyed device -> its last accepted seq, kept after it is forgotten (no replay, ever)
        self.key_seq: dict[str, int] = {}
        # source_rate 0: no per-source limits at all (one trusted source, e.g. a load test)
        self.source_limit = SourceBuckets(source_rate, 2 * source_rate)
        self.cpu_limit = SourceBuckets(source_cpu_share if source_rate else 0.0, 0.1)
        # Observers (the HTTP API's live view, storage, Redis): on_fix(device, t_device, position
        # dict or None, LED ids, seq, keyed) for every accepted datagram's reply, on_forget(device).
        self.on_fix = None
        self.on_forget = None
        # receiver.serve.shared.SharedState: device state in Redis, shared with other servers
        self.shared = shared
        self.error_limit = SourceBuckets(error_rate, 2 * error_rate)
        self.max_devices_per_source = max_devices_per_source
        self.devices: OrderedDict[str, _Device] = OrderedDict()   # least recently heard first
        self.per_source: Counter = Counter()                      # source host -> devices held
        self.counters: Counter = Counter()
        self._solvers = None
        self._fast_wire = _UNSET

    def handle(self, data: bytes, source=None) -> dict | None:
        """One datagram in; the reply (a position or an error) or None (dropped silently).
        `source`: the sender's address ((host, port, ...) or None); devices are bounded per host."""
        return self.handle_many([(data, source)])[0]

    def handle_many(self, datagrams) -> list[dict | None]:
        """`handle` of datagrams [(bytes, source), ...] received together, in order: the same
        replies as one `handle` call each, but the warm-started fixes of different devices are
        solved in one batch (`receiver.locate.posefilter.solve_batch`; a device's later datagram
        waits for its earlier one's fix and filter update)."""
        return self._handle(datagrams)[0]

    def _handle(self, datagrams, as_bytes: bool = False) -> tuple[list[dict | None], dict[int, bytes]]:
        """`handle_many`'s replies, and the encoded position replies by index (encoding is how
        `_reply` checks them). `as_bytes`: the position replies only encoded (no dict: None in
        the first list; the compiled filter writes the JSON itself, `ServerPoseFilter.update_json`)."""
        replies: list[dict | None] = [None] * len(datagrams)
        encoded: dict[int, bytes] = {}
        pending = []
        cpu0 = time.thread_time()
        charged = []                                 # (host, bytes) of the datagrams served
        for i, (data, source) in enumerate(datagrams):
            self.counters["datagrams"] += 1
            now = self.clock()
            host = None if source is None else source[0]
            if not (self.source_limit.take(host, now) and self.cpu_limit.allowed(host, now)):
                self.counters["rate_limited"] += 1
                continue
            charged.append((host, len(data)))
            self._forget_silent(now)
            signed = None
            try:
                if data[:len(MAC_PREFIX)] == MAC_PREFIX:
                    signed = verify(data, self.keys)
                    data = signed[2]
                req = parse_any(data, self._wire_kernel())
                if signed is not None and (req.device, req.seq) != signed[:2]:
                    raise ProtocolError("bad_mac", "the header's device or seq is not the request's",
                                        req.device, req.seq)
                if signed is None and req.device in self.keys:
                    raise ProtocolError("bad_mac", "this device's datagrams need its MAC", req.device, req.seq)
            except Exception as e:   # noqa: BLE001 -- ProtocolError, or a parser bug: never stop the server
                replies[i] = self._unproven(self._failed(e, None), len(data), source, now)
                continue
            # nbytes: the request's size for an unproven one's error reply (`_unproven`), 0 when
            # its MAC proved it (then error replies are not limited)
            pending.append((i, req, now, source, 0 if signed is not None else len(datagrams[i][0])))
        names = self._shared_in(pending) if self.shared is not None and pending else None
        while pending:                               # rounds with one datagram per device
            seen, this, later = set(), [], []
            for item in pending:
                (later if item[1].device in seen else this).append(item)
                seen.add(item[1].device)
            self._locate_round(this, replies, encoded, as_bytes)
            pending = later
        if names:
            self._shared_out(names)
        if self.cpu_limit.rate and charged:
            # The batch's CPU time, shared out by size (a datagram's work grows with its LEDs).
            per_byte = (time.thread_time() - cpu0) / max(1, sum(n for _, n in charged))
            for host, n in charged:
                self.cpu_limit.charge(host, n * per_byte)
        return replies, encoded

    def _shared_in(self, pending) -> list[str]:
        """The batch's devices as the shared state has them (`receiver.serve.shared`): a device
        another server served meanwhile is taken over, one expired there is forgotten here."""
        names = list(dict.fromkeys(item[1].device for item in pending))
        try:
            devs, seqs = self.shared.load(names, self.devices)
        except Exception:   # noqa: BLE001 -- Redis away: serve from the local state, counted
            self.counters["state_errors"] += 1
            return names
        now = self.clock()
        for name in names:
            dev, seq = devs[name], seqs[name]
            if seq is not None and seq > self.key_seq.get(name, -1):
                self.key_seq[name] = seq
            if dev is None:
                if name in self.devices:
                    self._drop(name, shared=False)
                    self.counters["forgotten"] += 1
                continue
            if name in self.devices:
                self._drop(name, shared=False, tell=False)
            dev.seen = now
            self.devices[name] = dev
            if dev.source is not None:
                self.per_source[dev.source] += 1
        return names

    def _shared_out(self, names) -> None:
        try:
            self.shared.save({n: self.devices[n] for n in names if n in self.devices},
                             {n: self.key_seq[n] for n in names if n in self.key_seq})
        except Exception:   # noqa: BLE001 -- counted; the next batch tries again
            self.counters["state_errors"] += 1

    def _refused(self, e: Exception, req, nbytes: int, source, now: float) -> dict | None:
        """`_failed`'s reply, limited (`_unproven`) unless a MAC proved the request (nbytes 0)."""
        reply = self._failed(e, req)
        return reply if nbytes == 0 else self._unproven(reply, nbytes, source, now)

    def _unproven(self, reply: dict | None, request_bytes: int, source, now: float) -> dict | None:
        """An error reply to a datagram no MAC proves, as the socket may send it: at most
        `error_rate` a second to one host, and never larger than the request (without its detail,
        device and seq if need be; else none). Without a source (in-process use) unchanged."""
        if reply is None or source is None:
            return reply
        if not self.error_limit.take(source[0], now):
            self.counters["error_replies_limited"] += 1
            return None
        if len(encode(reply)) <= request_bytes:
            return reply
        short = {"v": reply["v"], "error": reply["error"]}
        if len(encode(short)) <= request_bytes:
            return short
        self.counters["error_replies_limited"] += 1
        return None

    def _failed(self, e: Exception, req: Request | None) -> dict | None:
        """The reply to a request that raised e (None for `old_seq`), counted; a failure other
        than a ProtocolError drops the request's device (its filter may be half updated)."""
        if isinstance(e, ProtocolError):
            self.counters[e.reason] += 1
            if e.reason == "old_seq":
                return None
            reply = e.reply()
        else:
            self.counters["internal_error"] += 1
            if req is not None:
                self._drop(req.device)
            reply = ProtocolError("internal_error", type(e).__name__, getattr(req, "device", None),
                                  getattr(req, "seq", None)).reply()
        self.counters["replies"] += 1
        return reply

    def _locate_round(self, items, replies: list, encoded: dict, as_bytes: bool = False) -> None:
        """Map lookup, fix (`PoseFilter.solve`, batched over the round) and filter
        (`PoseFilter.update`) of requests of distinct devices, as
        `receiver.locate.indoor.Positioner.step` does them for a local receiver."""
        jobs = []                                    # (i, req, pose filter, leds, used, solve args)
        for i, req, now, source, nbytes in items:
            if isinstance(req, RequestV2):
                self._locate_v2(i, req, now, source, nbytes, replies, encoded)
                continue
            try:
                pf = self._v1_filter(self._device(req, now, source, nbytes == 0), req)
                pf.sigma_uv = req.sigma_uv
                leds = [self.led_map.lookup(led_id) for led_id in req.ids]
                used = [k for k, led in enumerate(leds) if led is not None]
                args = None
                if used:
                    sel = slice(None) if len(used) == len(leds) else used   # all known: no copies
                    L = np.array([(leds[k].x, leds[k].y, leds[k].z) for k in used], dtype=np.float64)
                    args = (pf, req.t, L, req.uv[sel], req.d[sel], req.sigma_d[sel], pf.R_prior(req.t))
                jobs.append((i, req, pf, leds, used, args))
            except Exception as e:   # noqa: BLE001
                replies[i] = self._refused(e, req, nbytes, source, now)
        fixes = self._solve([job[5] for job in jobs])
        for (i, req, pf, leds, used, _), fix in zip(jobs, fixes):
            try:
                if isinstance(fix, Exception):
                    raise fix
                replies[i], encoded[i] = self._reply(req, pf, fix, leds, used, as_bytes)
                self.counters["replies"] += 1
            except Exception as e:   # noqa: BLE001 -- a solver failure must not stop the server
                replies[i] = self._failed(e, req)

    def _v1_filter(self, dev: _Device, req: Request):
        if dev.pose is None:
            dev.pose = self._solver()[1](handedness=self.led_map.handedness, sigma_uv=req.sigma_uv,
                                         warm_start=self.warm_start)
        return dev.pose

    def _locate_v2(self, i: int, req: RequestV2, now: float, source, nbytes: int, replies: list,
                   encoded: dict) -> None:
        """A v2 request: the device's own `receiver.locate.indoor.Positioner` (made for its
        camera, with its default settings, as `occloc run` makes it) steps on the frame's
        observations, exactly as on the device."""
        try:
            dev = self._device(req, now, source, nbytes == 0)
            if dev.loc is None or dev.camera_key != req.camera_key:
                from receiver.locate.indoor import Positioner

                dev.loc, dev.camera_key = Positioner(req.camera, self.led_map), req.camera_key
            res = dev.loc.step(req.t, req.leds)
            known = [o for o in req.leds if self.led_map.lookup(o.id) is not None]
            reply = {"v": V2, "device": req.device, "seq": req.seq, "position": res.position,
                     "unknown_ids": sorted({o.id for o in req.leds} - {o.id for o in known}),
                     "n_used": sum(1 for o in known if not o.border),
                     "ranges": ranges_of(res.leds, req.leds)}
            try:
                data = encode(reply)
            except ValueError:
                raise FloatingPointError("non-finite result") from None
            self.counters["positions"] += res.position is not None
            self.counters["replies"] += 1
            self._tell(req, res.position)
            replies[i], encoded[i] = reply, data
        except Exception as e:   # noqa: BLE001 -- a solver failure must not stop the server
            replies[i] = self._refused(e, req, nbytes, source, now)

    def _wire_kernel(self):
        """The compiled request check (`receiver.serve._wire`) or None, looked up once per server."""
        if self._fast_wire is _UNSET:
            self._fast_wire = native.load(WIRE_KERNEL)
        return self._fast_wire

    def _solver(self):
        """(batch solver, devices' filter class), chosen once per server at first use (the
        compiled kernels are looked up then: `receiver.core.native`)."""
        if self._solvers is None:
            self._solvers = (_solve_batch(), _pose_filter_class())
        return self._solvers

    def _solve(self, frames) -> list:
        """Fixes of the frames (None for no LEDs); a frame whose solve raised gets the exception.
        One batch (`_solver`, also for one frame), or one by one (`PoseFilter.solve`) if the batch
        raised."""
        todo = [f for f in frames if f is not None]
        out: list = [None] * len(frames)
        fixes = None
        if todo:
            try:
                fixes = iter(self._solver()[0](todo))
            except Exception:   # noqa: BLE001 -- find the frame that fails, below
                fixes = None
        for k, f in enumerate(frames):
            if f is None:
                continue
            if fixes is not None:
                out[k] = next(fixes)
                continue
            try:
                out[k] = f[0].solve(*f[1:])
            except Exception as e:   # noqa: BLE001
                out[k] = e
        return out

    def _reply(self, req: Request, pf, fix, leds, used, as_bytes: bool = False) -> tuple[dict | None, bytes]:
        """The position reply and its encoding (`as_bytes` and a filter that writes its own JSON:
        only the encoding, the dict None)."""
        if as_bytes and hasattr(pf, "update_json"):
            return None, self._reply_json(req, pf, fix, leds, used)
        position = pf.update(req.t, fix, len(used))
        reply = {"v": PROTOCOL_VERSION, "device": req.device, "seq": req.seq, "position": position,
                 "unknown_ids": sorted({i for i, led in zip(req.ids, leds) if led is None}),
                 "n_used": len(used),
                 "solve_R_cw": None if fix is None or fix.R_cw is None else fix.R_cw.tolist()}
        try:
            data = encode(reply)          # strict JSON: raises ValueError on a NaN or infinity
        except ValueError:
            if all_finite(reply):
                raise
            # The solver or filter overflowed: never reply with (or keep) a NaN state.
            raise FloatingPointError("non-finite result") from None
        self.counters["positions"] += position is not None
        self._tell(req, position)
        return reply, data

    def _tell(self, req, position) -> None:
        """Hand an accepted datagram's position (dict, JSON bytes or None) to `on_fix`."""
        if self.on_fix is not None:
            if isinstance(position, bytes):
                position = json.loads(position)
            ids = req.ids if isinstance(req, Request) else [o.id for o in req.leds]
            self.on_fix(req.device, req.t, position, ids, req.seq, req.device in self.keys)
        if self.shared is not None:
            ids = req.ids if isinstance(req, Request) else [o.id for o in req.leds]
            self.shared.publish_fix(req.device, time.time(), req.t, position, ids)

    def _reply_json(self, req: Request, pf, fix, leds, used) -> bytes:
        """`_reply`'s encoding without the dict: the same bytes (`wire.encode` of the reply:
        compact, ASCII-escaped device, repr of every float; tested), the position object written
        by the compiled filter (`ServerPoseFilter.update_json`)."""
        try:
            position = pf.update_json(req.t, fix, len(used))
            rotation = b"null" if fix is None or fix.R_cw is None else pf.rotation_json(fix.R_cw)
        except ValueError:
            # The solver or filter overflowed: never reply with (or keep) a NaN state.
            raise FloatingPointError("non-finite result") from None
        unknown = sorted({i for i, led in zip(req.ids, leds) if led is None})
        self.counters["positions"] += position is not None
        self._tell(req, position)
        return b"".join((_REPLY_HEAD, encode_basestring_ascii(req.device).encode(), b',"seq":',
                         str(req.seq).encode(), b',"position":', b"null" if position is None else position,
                         b',"unknown_ids":[', ",".join(map(str, unknown)).encode(), b'],"n_used":',
                         str(len(used)).encode(), b',"solve_R_cw":', rotation, b"}"))

    def warm_up(self) -> None:
        """Import the solver and filter now rather than at the first device's datagram."""
        self._solver()

    def handle_datagram(self, data: bytes, source=None) -> bytes | None:
        """`handle`, encoded as strict JSON (never NaN / Infinity): what the socket sends back.
        A reply that cannot be encoded becomes an `internal_error` reply."""
        return self._handle_encoded([(data, source)])[0]

    def handle_datagrams(self, datagrams) -> list[bytes | None]:
        """`handle_datagram` of datagrams [(bytes, source), ...] received together
        (`handle_many`: one batched solve)."""
        return self._handle_encoded(datagrams)

    def _handle_encoded(self, datagrams) -> list[bytes | None]:
        """The encoded replies (each position reply encoded once: `_reply`)."""
        replies, encoded = self._handle(datagrams, as_bytes=True)
        return [encoded[i] if i in encoded else None if reply is None else self._encode(reply)
                for i, reply in enumerate(replies)]

    def _encode(self, reply: dict) -> bytes:
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
            self._drop(name, shared=False)   # shared state: Redis's expiry forgets it for all servers
            self.counters["forgotten"] += 1

    def _drop(self, name, shared: bool = True, tell: bool = True) -> None:
        """Forget a device here (`tell`: its observers too) and, with `shared`, in the shared state."""
        dev = self.devices.pop(name, None)
        if dev is not None and self.shared is not None:
            self.shared.forget(name)
        if dev is not None and tell and self.on_forget is not None:
            self.on_forget(name)
        if dev is not None and shared and self.shared is not None:
            try:
                self.shared.drop(name)
            except Exception:   # noqa: BLE001 -- its expiry forgets it anyway
                self.counters["state_errors"] += 1
        if dev is not None and dev.source is not None:
            self.per_source[dev.source] -= 1
            if self.per_source[dev.source] <= 0:
                del self.per_source[dev.source]

    def _device(self, req: Request, now: float, source, proven: bool = False) -> _Device:
        """The request's device (new ones are created), after the checks that keep others from
        steering it; marks it heard. `source`: the sender's (host, port) or None; `proven`: a
        MAC proved the request. A keyed device's seq must pass the last one it ever had accepted
        (kept after forgetting: no replay); an unkeyed device's name is bound to the source
        that created it until it is forgotten; a live device's seq moves at most SEQ_WINDOW
        ahead. Nothing of a refused request touches the device."""
        dev = self.devices.get(req.device)
        host = None if source is None else source[0]
        keyed = req.device in self.keys
        if keyed and req.seq <= self.key_seq.get(req.device, -1):
            raise ProtocolError("old_seq", device=req.device, seq=req.seq)
        if dev is None:
            if len(self.devices) >= self.max_devices:
                raise ProtocolError("too_many_devices", f"the server holds {self.max_devices} devices",
                                    req.device, req.seq)
            if host is not None and self.per_source[host] >= self.max_devices_per_source:
                raise ProtocolError("too_many_devices_per_source",
                                    f"this address holds {self.max_devices_per_source} devices",
                                    req.device, req.seq)
            dev = _Device(None, -1, now, host, bound=None if keyed or source is None else tuple(source[:2]))
            self.devices[req.device] = dev
            if host is not None:
                self.per_source[host] += 1
            self.counters["new_devices"] += 1
        else:
            if dev.bound is not None and (source is None or tuple(source[:2]) != dev.bound):
                raise ProtocolError("wrong_source", "this device is bound to another address", req.device,
                                    req.seq)
            if req.seq <= dev.seq:
                raise ProtocolError("old_seq", device=req.device, seq=req.seq)
            if req.seq > dev.seq + SEQ_WINDOW:
                raise ProtocolError("seq_jump", f"seq may move at most {SEQ_WINDOW} ahead", req.device, req.seq)
        dev.seq, dev.seen = req.seq, now
        if keyed:
            self.key_seq[req.device] = req.seq
        self.devices.move_to_end(req.device)
        return dev

    def summary(self) -> str:
        """One line of counters for the end of a run."""
        c = self.counters
        dropped = ", ".join(f"{r} {c[r]}" for r in REASONS if c[r]) or "none"
        return (f"{c['datagrams']} datagrams, {c['replies']} replies, {c['positions']} positions; "
                f"devices: {c['new_devices']} new, {c['forgotten']} forgotten, {len(self.devices)} held; "
                f"dropped/refused: {dropped}")


# ---------------------------------------------------------------- UDP transport

def format_url(address) -> str:
    host, port = address[0], address[1]
    return f"udp://[{host}]:{port}" if ":" in host else f"udp://{host}:{port}"


def bind_udp(host: str, port: int, reuse_port: bool = False) -> socket.socket:
    """A non-blocking UDP socket bound to host:port (receive buffer `RCVBUF_BYTES`, as far as
    the system allows). `reuse_port`: SO_REUSEPORT, so several server processes (sharing their
    devices with `--state`) bind the same port and the kernel spreads the sources over them.
    A port in use or a host not on this machine: InputError."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be in 0..65535, not {port}")
    try:
        family, _, _, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        sock = socket.socket(family, socket.SOCK_DGRAM)
    except OSError as e:
        raise InputError(f"cannot listen on {format_url((host, port))}: {e.strerror or e}") from None
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
        if reuse_port:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        sock.bind(address)
    except OSError as e:
        sock.close()
        raise InputError(f"cannot listen on {format_url((host, port))}: {e.strerror or e}") from None
    sock.setblocking(False)
    return sock


def serve_socket(server: LightingServer, sock: socket.socket, stop: threading.Event, *,
                 max_batch: int = MAX_BATCH, max_batch_bytes: int = MAX_BATCH_BYTES) -> None:
    """Serve `server` on the bound non-blocking UDP socket until `stop` is set (checked every
    `POLL_S`, and between batches): wait for a datagram, read every datagram already queued in
    the socket (at most READ_AHEAD at a time) into per-source queues (`receiver.serve.queues`:
    beyond a host's or the whole bound, a datagram is dropped as read, counted `rate_limited`),
    take a batch from them, a datagram of each source host in turn (at most `max_batch`, ending
    after the one that reaches `max_batch_bytes`: never waiting for more), handle it
    (`LightingServer.handle_datagrams`), send the replies, and go on with what queued meanwhile.
    A plain blocking loop: asyncio's per-datagram callbacks cost more than the datagram's JSON.
    Socket errors (e.g. ICMP port unreachable for a reply to a device that went away) are
    counted as `socket_errors`, the batches as `batches`."""
    poller = select.poll()
    poller.register(sock, select.POLLIN)
    recvfrom, sendto = sock.recvfrom, sock.sendto
    counters = server.counters
    queues = SourceQueues(MAX_SOURCE_QUEUE_BYTES, MAX_QUEUE_BYTES)
    while not stop.is_set():
        if not queues.count:
            events = poller.poll(POLL_S * 1000)
            if not events:
                continue
            if events[0][1] & select.POLLNVAL:   # the socket was closed under us: nothing more to serve
                counters["socket_errors"] += 1
                return
        for _ in range(READ_AHEAD):
            try:
                data, addr = recvfrom(RECV_BYTES)
            except BlockingIOError:
                break
            except OSError:
                # Counted, then back to the poll: a persistent error (a closed socket) must not
                # spin here, away from the `stop` check.
                counters["socket_errors"] += 1
                break
            if not queues.put(data, addr):
                counters["datagrams"] += 1
                counters["rate_limited"] += 1
        batch = queues.take(max_batch, max_batch_bytes)
        if not batch:
            continue
        counters["batches"] += 1
        outs = _handle_batch(server, batch)
        for (_, addr), out in zip(batch, outs):
            if out is not None:
                try:
                    sendto(out, addr)
                except OSError:
                    counters["socket_errors"] += 1


def _handle_batch(server: LightingServer, batch) -> list[bytes | None]:
    """The encoded replies of a batch; should the batched path fail (`handle_many` answers every
    request's failure itself, so this is a bug's guard), each datagram is handled alone, and a
    datagram that fails alone too gets no reply and counts as `internal_error`."""
    try:
        return server.handle_datagrams(batch)
    except Exception:   # noqa: BLE001 -- never stop serving
        outs = []
        for data, addr in batch:
            try:
                outs.append(server.handle_datagram(data, addr))
            except Exception:   # noqa: BLE001
                server.counters["internal_error"] += 1
                outs.append(None)
        return outs


async def serve_until(server: LightingServer, host: str, port: int, stop: asyncio.Event,
                      on_ready=None, reuse_port: bool = False) -> None:
    """Serve `server` on UDP host:port until `stop` is set. `on_ready(address)` is called with the
    bound (host, port) once listening (datagrams arriving meanwhile wait in the socket's buffer).
    A port in use or a host not on this machine: InputError. The datagrams are served by
    `serve_socket` on a thread of its own; this coroutine only waits for `stop`."""
    sock = bind_udp(host, port, reuse_port)
    done = threading.Event()
    worker = None
    try:
        if on_ready is not None:
            on_ready(sock.getsockname()[:2])
        worker = threading.Thread(target=serve_socket, args=(server, sock, done), name="occloc-serve-udp",
                                  daemon=True)
        worker.start()
        await stop.wait()
    finally:
        done.set()
        if worker is not None:
            await asyncio.get_running_loop().run_in_executor(None, worker.join)
        sock.close()


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


