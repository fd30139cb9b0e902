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
from receiver.core.records import FrameResult

# Forward-vehicle zones (receiver.locate.vehicle.ZONES), least to most urgent.
ZONE_ORDER = ("safe", "min", "critical")
# Decimal places in the output: sub-pixel centroids, 0.1 px^2 areas, mm distances, us times.
PX_DECIMALS = 2
AREA_DECIMALS = 1
M_DECIMALS = 4
MS_DECIMALS = 3
T_DECIMALS = 6


# 10 ** nd as exact floats, the divisors of `_num`'s short path
_TEN = tuple(10.0 ** nd for nd in range(10))
# |v| x 10 ** nd below this: the product's rounding error (<= 2^-23) is far under `_TIE_MARGIN`
_SHORT_MAX = 2.0 ** 30
_TIE_MARGIN = 1e-6


def _num(v, nd):
    """round(float(v), nd), or None for None and non-finite values. Short path, the same value:
    the integer k nearest v x 10^nd, then k / 10^nd (one correctly rounded division: the double
    nearest the decimal, as round's); round itself near a tie, for large values and for 0."""
    if v is None:
        return None
    v = float(v)
    if not math.isfinite(v):
        return None
    s = _TEN[nd]
    y = v * s
    if -_SHORT_MAX < y < _SHORT_MAX:
        k = math.floor(y)
        f = y - k
        if abs(f - 0.5) > _TIE_MARGIN:
            k += f > 0.5
            if k:
                return k / s
    return round(v, nd)


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
    """One JSON line (no newline). numpy scalars and arrays in a positioner's dict are converted;
    a NaN or infinity anywhere becomes null, never the non-JSON token NaN."""
    from receiver.io.files import dumps
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
