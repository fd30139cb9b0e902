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

    def add(self, res: FrameResult) -> None:
        self.frames += 1
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

    def _latency_text(self) -> str:
        if not self.latency_ms:
            return "latency: no frames"
        return (f"latency p50 {percentile(self.latency_ms, 50):.2f} ms, "
                f"p99 {percentile(self.latency_ms, 99):.2f} ms")

    def text(self, *, skipped: int = 0, dropped: int = 0, truncated: int = 0,
             hv_reason: str | None = None) -> str:
        """The summary line; `hv_reason`: why the host vehicle is not placed (vehicle scenes)."""
        ids = ", ".join(str(i) for i in sorted(self.ids)) or "none"
        line = (f"{self.frames} frames, {self.led_frames} LED observations "
                f"({self.decoded_led_frames} with ID), decoded IDs: {ids}; "
                f"positions: {self.positions}; {self._latency_text()}; skipped corrupt frames: {skipped}; "
                f"dropped: {dropped}")
        if self.vehicle_frames or hv_reason:
            line += f"; vehicle frames: {self.vehicle_frames}, host placed in {self.hv_frames}"
            if hv_reason and self.hv_frames == 0:
                line += f" ({hv_reason})"
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
