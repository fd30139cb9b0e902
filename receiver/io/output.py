"""JSON Lines output (INTERFACES.md "Receiver command line") and the run summary.

One object per processed frame:
`{"frame", "t", "latency_ms", "leds": [{"track", "id", "mode", "cx", "cy", "area_px",
"distance_m", ...}], "position", "vehicle"}`; with `profile` the per-stage milliseconds are
added as `"stage_ms"`. Extra LED fields: `border`, `distance_estimator` (when a distance is
known), `freq_hz` (tone LEDs: measured stripe frequency), `kind` (S2-PSK: 'SL' or 'FV').
"""

from __future__ import annotations

import math

from receiver.core.budget import percentile
from receiver.core.native import load
from receiver.core.records import FrameResult

# Forward-vehicle zones (receiver.locate.vehicle.ZONES), least to most urgent.
ZONE_ORDER = ("safe", "min", "critical")
# Decimal places in the output: sub-pixel centroids, 0.1 px^2 areas, mm distances, us times.
PX_DECIMALS = 2
AREA_DECIMALS = 1
M_DECIMALS = 4
MS_DECIMALS = 3
T_DECIMALS = 6


def _num(v, nd):
    if v is None:
        return None
    v = float(v)
    return round(v, nd) if math.isfinite(v) else None


def frame_record(res: FrameResult, *, profile: bool = False) -> dict:
    """The INTERFACES.md object of one frame."""
    leds = []
    for o in res.leds:
        d = {"track": o.track, "id": o.id, "mode": o.mode, "cx": _num(o.cx, PX_DECIMALS),
             "cy": _num(o.cy, PX_DECIMALS), "area_px": _num(o.area_px, AREA_DECIMALS),
             "distance_m": None, "border": bool(o.border)}
        if o.kind is not None:
            d["kind"] = o.kind
        if o.freq_hz is not None:
            d["freq_hz"] = o.freq_hz
        if o.distance_m is not None:
            d["distance_m"] = _num(o.distance_m, M_DECIMALS)
            d["distance_estimator"] = o.distance_estimator
        leds.append(d)
    rec = {"frame": res.frame, "t": _num(res.t_s, T_DECIMALS),
           "latency_ms": _num(res.latency_ms, MS_DECIMALS), "leds": leds,
           "position": res.position, "vehicle": res.vehicle}
    if profile:
        rec["stage_ms"] = {k: _num(v, MS_DECIMALS) for k, v in res.stage_ms.items()}
    return rec


def frame_line(res: FrameResult, *, profile: bool = False) -> str:
    """One JSON line (no newline). numpy scalars in a positioner's dict are converted."""
    if _k is not None:
        line = _k.frame_line(res, profile)
        if line is not None:
            return line
    line = _fast_line(res, profile)
    if line is not None:
        return line
    from receiver.io.files import dumps
    # allow_nan=False: a positioner's NaN becomes null, never the non-JSON token NaN
    return dumps(frame_record(res, profile=profile), separators=(",", ":"), default=_jsonable)


def with_fields(line: str, fields: dict) -> str:
    """One JSON line (`frame_line`) with `fields` appended as top-level keys (e.g. `"file"` of
    a photo, `"no_fix"` of a frame without a position); the line itself when there are none."""
    if not fields:
        return line
    from receiver.io.files import dumps
    return line[:-1] + "," + dumps(fields, separators=(",", ":"))[1:]


def _jsonable(v):
    try:
        return v.tolist()  # numpy arrays and scalars
    except AttributeError:
        raise TypeError(f"not JSON serialisable: {type(v).__name__}") from None


class RunSummary:
    """Counts for the end-of-run summary on stderr."""

    def __init__(self):
        self.frames = 0
        self.latency_ms: list[float] = []
        self.ids: set[int] = set()
        self.led_frames = 0
        self.decoded_led_frames = 0
        self.positions = 0
        self.vehicle_frames = 0  # frames with a vehicle object
        self.hv_frames = 0  # ... of them with the host vehicle placed
        self.no_fix: dict[str, int] = {}  # why frames have no position -> frames
        # the cars ahead (vehicle "fv"): IDs, closest (m, frame), lowest TTC (s, frame), the
        # frames by their worst zone
        self.fv_ids: set = set()
        self.fv_closest: tuple[float, int] | None = None
        self.fv_min_ttc: tuple[float, int] | None = None
        self.fv_zone_frames: dict[str, int] = {}

    def add(self, res: FrameResult, no_fix: str | None = None) -> None:
        self.frames += 1
        if no_fix is not None:
            self.no_fix[no_fix] = self.no_fix.get(no_fix, 0) + 1
        self.latency_ms.append(res.latency_ms)
        self.led_frames += len(res.leds)
        for o in res.leds:
            if o.id is not None:
                self.ids.add(o.id)
                self.decoded_led_frames += 1
        self.positions += res.position is not None
        if res.vehicle is not None:
            self.vehicle_frames += 1
            self.hv_frames += res.vehicle.get("hv") is not None
            self._add_fv(res.frame, res.vehicle.get("fv") or ())

    def _add_fv(self, frame: int, fvs) -> None:
        worst = None
        for fv in fvs:
            if fv.get("id") is not None:
                self.fv_ids.add(fv["id"])
            d, ttc, zone = fv.get("distance_m"), fv.get("ttc_s"), fv.get("zone")
            if d is not None and (self.fv_closest is None or d < self.fv_closest[0]):
                self.fv_closest = (d, frame)
            if ttc is not None and (self.fv_min_ttc is None or ttc < self.fv_min_ttc[0]):
                self.fv_min_ttc = (ttc, frame)
            if zone in ZONE_ORDER and (worst is None or ZONE_ORDER.index(zone) > ZONE_ORDER.index(worst)):
                worst = zone
        if worst is not None:
            self.fv_zone_frames[worst] = self.fv_zone_frames.get(worst, 0) + 1

    def cars_text(self) -> str:
        """The summary's words on the cars ahead ('' when none was seen)."""
        if not self.fv_zone_frames and self.fv_closest is None:
            return ""
        ids = ", ".join(str(i) for i in sorted(self.fv_ids)) or "none decoded"
        parts = [f"cars ahead (IDs {ids})"]
        if self.fv_closest is not None:
            parts.append(f"closest {self.fv_closest[0]:.1f} m (frame {self.fv_closest[1]})")
        parts.append(f"lowest TTC {self.fv_min_ttc[0]:.1f} s (frame {self.fv_min_ttc[1]})"
                     if self.fv_min_ttc is not None else "never closing")
        parts.append("frames by worst zone: " + ", ".join(f"{z} {self.fv_zone_frames.get(z, 0)}"
                                                        for z in ZONE_ORDER))
        return "; " + ", ".join(parts)

    def text(self, *, skipped: int = 0, dropped: int = 0, truncated: int = 0,
             hv_reason: str | None = None) -> str:
        """The summary line; `hv_reason`: why the host vehicle is not placed (vehicle scenes)."""
        ids = ", ".join(str(i) for i in sorted(self.ids)) or "none"
        line = (f"{self.frames} frames, {self.led_frames} LED observations "
                f"({self.decoded_led_frames} with ID), decoded IDs: {ids}; "
                f"positions: {self.positions}; latency p50 {percentile(self.latency_ms, 50):.2f} ms, "
                f"p99 {percentile(self.latency_ms, 99):.2f} ms; skipped corrupt frames: {skipped}; "
                f"dropped: {dropped}")
        if self.no_fix:
            line += "; no position: " + ", ".join(
                f"{n} {why}" for why, n in sorted(self.no_fix.items(), key=lambda kv: (-kv[1], kv[0])))
        if self.vehicle_frames or hv_reason:
            line += f"; vehicle frames: {self.vehicle_frames}, host placed in {self.hv_frames}"
            if hv_reason and self.hv_frames == 0:
                line += f" ({hv_reason})"
            line += self.cars_text()
        if truncated:
            line += f"; truncated: {truncated} frame(s) missing at the end"
        return line


# -- the same line, built directly (issue 14: json.dumps of `frame_record` costs ~2 decimal
# conversions per number, round() then repr(); this formats each rounded number once)

# |v| range where "%.{nd}f" % v with its trailing zeros dropped is exactly repr(round(v, nd)):
# no exponent notation in repr (>= 1e-4), and doubles finer than 1e-6 apart (< 1e9), so the
# nd-decimal string is the only shortest one that reads back as round(v, nd).
_FAST_MIN, _FAST_MAX = 1e-4, 1e9
_FMT = {nd: f"%.{nd}f" for nd in range(1, 10)}

# The compiled writer (receiver/io/_jsonline.pyx: the line in one C buffer, the same characters
# as `_fast_line`), or None: `_fast_line` below, its tested reference.
_k = load("receiver.io._jsonline")
if _k is not None:
    _k.configure(PX_DECIMALS, AREA_DECIMALS, M_DECIMALS, MS_DECIMALS, T_DECIMALS, _FAST_MIN, _FAST_MAX)


class _Slow(Exception):
    """A value the direct builder does not format: `frame_line` falls back to json.dumps."""


def _num_tok(v, nd: int) -> str:
    """The JSON token of `_num(v, nd)`."""
    if v is None:
        return "null"
    v = float(v)
    a = abs(v)
    if nd > 0 and (_FAST_MIN <= a < _FAST_MAX or a == 0.0):
        t = (_FMT[nd] % v).rstrip("0")
        return t + "0" if t[-1] == "." else t
    if not math.isfinite(v):
        return "null"
    return repr(round(v, nd))


def _int_tok(v) -> str:
    if v is None:
        return "null"
    if type(v) is not int:
        raise _Slow
    return repr(v)


def _str_tok(v) -> str:
    """A plain ASCII word (mode, kind, estimator, stage name) as a JSON string."""
    if v is None:
        return "null"
    if type(v) is not str or not (v.isascii() and v.replace("_", "").isalnum()):
        raise _Slow
    return '"' + v + '"'


def _led_tok(o) -> str:
    parts = ['{"track":', _int_tok(o.track), ',"id":', _int_tok(o.id), ',"mode":', _str_tok(o.mode),
             ',"cx":', _num_tok(o.cx, PX_DECIMALS), ',"cy":', _num_tok(o.cy, PX_DECIMALS),
             ',"area_px":', _num_tok(o.area_px, AREA_DECIMALS), ',"distance_m":',
             "null" if o.distance_m is None else _num_tok(o.distance_m, M_DECIMALS),
             ',"border":', "true" if o.border else "false"]
    if o.kind is not None:
        parts += [',"kind":', _str_tok(o.kind)]
    if o.freq_hz is not None:
        f = o.freq_hz
        if type(f) is not float or not math.isfinite(f):
            raise _Slow
        parts += [',"freq_hz":', repr(f)]
    if o.distance_m is not None:
        parts += [',"distance_estimator":', _str_tok(o.distance_estimator)]
    parts.append("}")
    return "".join(parts)


def _fast_line(res: FrameResult, profile: bool) -> str | None:
    """`frame_line`'s text built without json.dumps of the whole record (the same characters:
    tests/test_output.py), or None where it would differ (then json.dumps is used)."""
    from receiver.io.files import dumps
    try:
        leds = ",".join([_led_tok(o) for o in res.leds])
        rest = [dumps(v, separators=(",", ":"), default=_jsonable) if v is not None else "null"
                for v in (res.position, res.vehicle)]
        stages = ""
        if profile:
            stages = ',"stage_ms":{' + ",".join(
                [_str_tok(k) + ":" + _num_tok(v, MS_DECIMALS) for k, v in res.stage_ms.items()]) + "}"
        return "".join(['{"frame":', _int_tok(res.frame), ',"t":', _num_tok(res.t_s, T_DECIMALS),
                        ',"latency_ms":', _num_tok(res.latency_ms, MS_DECIMALS), ',"leds":[', leds,
                        '],"position":', rest[0], ',"vehicle":', rest[1], stages, "}"])
    except (_Slow, ValueError, TypeError):
        return None
