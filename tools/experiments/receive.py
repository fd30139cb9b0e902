"""The whole receiver on rendered frames, built the way `occloc run` builds it (its positioner
and vehicle locator come from `receiver.cli.run`), and the truth-matching the experiments share.
"""

from __future__ import annotations

import math

import numpy as np


def run_receiver(scene, frames, truth, camera=None) -> list[dict]:
    """The INTERFACES.md frame objects `occloc run` would write for `frames` (N, H, W) of
    `scene`, frame k stamped with its render time truth[k]["t"]. `camera`: the camera file the
    receiver is given (default: the scene's true camera)."""
    from receiver.cli.run import make_positioner, make_vehicle_locator
    from receiver.core.records import Frame
    from receiver.io.output import frame_record
    from receiver.pipeline import Receiver

    cam, led_map = (camera if camera is not None else scene.camera), scene.led_map
    rx = Receiver(cam, led_map, positioner=make_positioner(cam, led_map),
                  vehicle=make_vehicle_locator(cam, led_map))
    return [frame_record(rx.process(Frame(k, float(t["t"]), img))) for k, (img, t) in enumerate(zip(frames, truth))]


def led_ranges(records: list[dict], truth: list[dict], mode: str | None = None, skip_frames: int = 0):
    """Per visible truth LED per frame (after the first `skip_frames`): (true distance m, the
    receiver's distance m or None, decoded bool, true area px). An LED counts as decoded when the
    frame has a run LED with its ID, and as ranged when one such LED has a distance."""
    out = []
    for rec, tr in zip(records[skip_frames:], truth[skip_frames:]):
        by_id = {}
        for o in rec["leds"]:
            if o["id"] is not None:
                by_id.setdefault(o["id"], []).append(o["distance_m"])
        for t in tr["leds"]:
            if not t["visible"] or (mode is not None and t["mode"] != mode):
                continue
            ds = [d for d in by_id.get(t["id"], []) if d is not None]
            out.append((float(t["distance_m"]), float(np.mean(ds)) if ds else None, t["id"] in by_id,
                        float(t["area_px"])))
    return out


def error_stats(pairs, prefix: str = "") -> dict:
    """mean/max absolute error (m and % of the true distance) and its standard deviation over the
    ranged entries of `led_ranges`; the ranged and decoded fractions. Missing: None."""
    n = len(pairs)
    ranged = [(dt, de) for dt, de, _, _ in pairs if de is not None]
    err = np.array([abs(de - dt) for dt, de in ranged])
    rel = np.array([100.0 * abs(de - dt) / dt for dt, de in ranged])
    some = len(ranged) > 0
    return {f"{prefix}n_led_frames": n,
            f"{prefix}decoded_frac": (sum(1 for p in pairs if p[2]) / n) if n else None,
            f"{prefix}ranged_frac": (len(ranged) / n) if n else None,
            f"{prefix}mean_err_m": float(err.mean()) if some else None,
            f"{prefix}max_err_m": float(err.max()) if some else None,
            f"{prefix}std_err_m": float(err.std()) if some else None,
            f"{prefix}mean_err_pct": float(rel.mean()) if some else None,
            f"{prefix}max_err_pct": float(rel.max()) if some else None}


def finite_or_none(v):
    """A float for the CSV, None for a missing or non-finite value (never NaN in an output)."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None
