"""Beyond the thesis: ID and position availability of the whole receiver vs camera frame rate,
vs ambient light (the thesis's 6.5.2) and vs lens distortion left uncorrected (6.5.1).

Frame rate and ambient light: `indoor-sparse` (a phone held tilted, walking under 0.25 m panels:
~42 chips a frame, so a new panel needs two or three frames). Distortion: `indoor-static` (still
camera, LEDs of several sizes across the view) rendered through a lens with radial distortion k1
while the receiver is given the same camera without it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from tools.experiments.cache import SceneSpec
from tools.experiments.receive import error_stats, led_ranges, run_receiver
from tools.experiments.registry import Experiment, Panel


def availability(records, truth, scene) -> dict:
    """Shares of frames with a decoded mapped ID and with a fix, the first fix time and the mean
    fix error (3-D, m)."""
    ids = fixes = 0
    errs, first = [], None
    for rec, tr in zip(records, truth):
        ids += any(o["id"] is not None and o["id"] in scene.led_map.leds for o in rec["leds"])
        p = rec["position"]
        if p is not None:
            fixes += 1
            c = tr["camera"]
            errs.append(math.dist((p["x"], p["y"], p["z"]), (c["x"], c["y"], c["z"])))
            first = tr["t"] if first is None else first
    n = max(len(records), 1)
    return {"id_frac": ids / n, "fix_frac": fixes / n, "first_fix_s": first,
            "mean_err_m": float(np.mean(errs)) if errs else None,
            "p95_err_m": float(np.percentile(errs, 95)) if errs else None}


def _means(rows, param, col):
    out = {}
    for r in rows:
        if r.get(col) is not None:
            out.setdefault(r[param], []).append(float(r[col]))
    return {k: float(np.mean(v)) for k, v in sorted(out.items())}


def measure_fps(fps: float, seed: int, quick: bool, cache) -> dict:
    seconds = 1.0 if quick else 2.0
    spec = SceneSpec.of("indoor-sparse", scene_seed=seed, noise_seed=seed, n_frames=int(round(seconds * fps)),
                        fps=float(fps))
    scene, frames, truth = cache.render(spec)
    return availability(run_receiver(scene, frames, truth), truth, scene)


def measure_ambient(ambient_dn: float, seed: int, quick: bool, cache) -> dict:
    spec = SceneSpec.of("indoor-sparse", scene_seed=seed, noise_seed=seed, n_frames=30 if quick else 60,
                        ambient_dn=float(ambient_dn))
    scene, frames, truth = cache.render(spec)
    return availability(run_receiver(scene, frames, truth), truth, scene)


def measure_distortion(k1: float, seed: int, quick: bool, cache) -> dict:
    spec = SceneSpec.of("indoor-static", scene_seed=seed, noise_seed=seed, n_frames=10 if quick else 20,
                        dist=(float(k1), 0.0, 0.0, 0.0, 0.0))
    scene, frames, truth = cache.render(spec)
    ideal = dataclasses.replace(scene.camera, dist=np.zeros(5))
    recs = run_receiver(scene, frames, truth, camera=ideal)
    row = availability(recs, truth, scene)
    st = error_stats(led_ranges(recs, truth, mode="ook"))
    row.update({"range_mean_err_pct": st["mean_err_pct"], "range_max_err_pct": st["max_err_pct"]})
    return row


def summarize_fps(rows):
    idf, fix, first = _means(rows, "fps", "id_frac"), _means(rows, "fps", "fix_frac"), _means(rows, "fps", "first_fix_s")
    ours = "; ".join(f"{f:g} fps: ID {idf[f]:.0%}, fix {fix[f]:.0%}"
                     + (f", first fix {first[f]:.2f} s" if f in first else "") for f in idf)
    why = "Frame rate sets how fast frames of a panel too small for a whole packet fill the 54-chip accumulator. "
    if first and idf:
        lo, hi = min(idf), max(idf)
        why += (f"Here the first fix comes {first.get(lo, float('nan')) * lo:.1f} frames in at {lo:g} fps and "
                f"{first.get(hi, float('nan')) * hi:.1f} at {hi:g} fps, so in seconds the low rate waits longer, while "
                f"the share of frames with a fix stays {min(fix.values()):.0%}-{max(fix.values()):.0%}.")
    return {"thesis": "not measured (Table 2: 30 fps; 6.2: one bit per frame)", "ours": ours or "no data",
            "why": why}


def summarize_ambient(rows):
    idf, fix, err = (_means(rows, "ambient_dn", c) for c in ("id_frac", "fix_frac", "mean_err_m"))
    ours = "; ".join(f"{a:g} DN: ID {idf[a]:.0%}, fix {fix[a]:.0%}"
                     + (f", err {100 * err[a]:.1f} cm" if a in err else "") for a in idf)
    base = idf.get(0.0)
    drop = min((a for a, v in idf.items() if base is not None and v < 0.5 * base), default=None)
    why = ("The LED adds 180 DN on top of the ambient level, so above 75 DN its ON rows saturate at 255 and the "
           "stripe contrast is 255 minus the ambient level; ")
    why += (f"the receiver keeps decoding until that contrast is ~{255 - drop:g} DN (ID share halves at {drop:g} DN)"
            if drop is not None else "the receiver kept decoding over the whole sweep")
    no_fix = min((a for a, v in fix.items() if v == 0.0), default=None)
    why += (f"; no fix from {no_fix:g} DN ({255 - no_fix:g} DN of contrast)." if no_fix is not None else ".")
    return {"thesis": "6.5.2: ambient light disturbs the projection; HDR helps (no numbers)", "ours": ours or "no data",
            "why": why}


def summarize_distortion(rows):
    err, rng, fix = (_means(rows, "k1", c) for c in ("mean_err_m", "range_mean_err_pct", "fix_frac"))
    ours = "; ".join(f"k1 {k:g}: fix {fix[k]:.0%}" + (f", err {100 * err[k]:.1f} cm" if k in err else "")
                     + (f", range err {rng[k]:.2f} %" if k in rng else "") for k in fix)
    return {"thesis": "6.5.1: lens distortion must be corrected (back-propagation proposed; no numbers)",
            "ours": ours or "no data",
            "why": "Uncorrected barrel distortion pulls off-axis LEDs towards the centre and shrinks their area, so "
                   "bearings and area ranges are both biased and the fix error grows with |k1|."}


EXPERIMENTS = [
    Experiment("fps", "beyond the thesis", "availability vs frame rate (indoor-sparse walk)", "fps",
               "frame rate (frames/s)", (10.0, 15.0, 20.0, 30.0, 60.0), (15.0, 60.0), measure_fps,
               (Panel("fraction of frames", (("id_frac", "decoded ID"), ("fix_frac", "position fix"))),
                Panel("first fix after (s)", (("first_fix_s", "first fix"),)),
                Panel("fix error (m)", (("mean_err_m", "mean"), ("p95_err_m", "95th percentile")))),
               summarize_fps),
    Experiment("ambient", "beyond the thesis", "availability vs ambient light (indoor-sparse walk)", "ambient_dn",
               "ambient light level (DN of 255)", (0.0, 40.0, 80.0, 120.0, 160.0, 200.0, 220.0, 240.0), (0.0, 220.0),
               measure_ambient,
               (Panel("fraction of frames", (("id_frac", "decoded ID"), ("fix_frac", "position fix"))),
                Panel("fix error (m)", (("mean_err_m", "mean"), ("p95_err_m", "95th percentile")))),
               summarize_ambient),
    Experiment("distortion", "beyond the thesis", "position error vs uncorrected lens distortion k1 (indoor-static)",
               "k1", "radial distortion k1 left uncorrected", (0.0, -0.05, -0.1, -0.15, -0.2, -0.3), (0.0, -0.2),
               measure_distortion,
               (Panel("fix error (m)", (("mean_err_m", "mean"), ("p95_err_m", "95th percentile"))),
                Panel("range error (%)", (("range_mean_err_pct", "mean"), ("range_max_err_pct", "max"))),
                Panel("fraction of frames", (("id_frac", "decoded ID"), ("fix_frac", "position fix")))),
               summarize_distortion),
]
