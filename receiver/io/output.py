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
    """One JSON line (no newline). numpy scalars and arrays in a positioner's dict are converted;
    a NaN or infinity anywhere becomes null, never the non-JSON token NaN."""
    from receiver.io.files import dumps
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

    def text(self, *, skipped: int = 0, dropped: int = 0, truncated: int = 0,
             hv_reason: str | None = None) -> str:
        """The summary line; `hv_reason`: why the host vehicle is not placed (vehicle scenes)."""
        ids = ", ".join(str(i) for i in sorted(self.ids)) or "none"
        line = (f"{self.frames} frames, {self.led_frames} LED observations "
                f"({self.decoded_led_frames} with ID), decoded IDs: {ids}; "
                f"positions: {self.positions}; latency p50 {percentile(self.latency_ms, 50):.2f} ms, "
                f"p99 {percentile(self.latency_ms, 99):.2f} ms; skipped corrupt frames: {skipped}; "
                f"dropped: {dropped}")
        if self.vehicle_frames or hv_reason:
            line += f"; vehicle frames: {self.vehicle_frames}, host placed in {self.hv_frames}"
            if hv_reason and self.hv_frames == 0:
                line += f" ({hv_reason})"
        if truncated:
            line += f"; truncated: {truncated} frame(s) missing at the end"
        return line
