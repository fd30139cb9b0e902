"""The vehicle scenes on the straight night road (`tools.experiments.scenes.night_road`): forward
vehicle (FV) distance error vs its speed (Figure 38) and host vehicle (HV) positioning vs the
street-light spacing (Figure 39); plus the FV matching shared with Figure 37."""

from __future__ import annotations

import math

import numpy as np

from tools.experiments.cache import SceneSpec
from tools.experiments.receive import run_receiver
from tools.experiments.registry import Experiment, Panel


def fv_ranges(records: list[dict], truth: list[dict]):
    """Per frame with a visible truth FV: (true distance m, the receiver's FV distance m or None).
    Run FVs are matched to truth ones by `receiver.evaluate.metrics.match_fvs` (ID, else bearing)."""
    from receiver.evaluate.metrics import match_fvs

    out = []
    for rec, tr in zip(records, truth):
        tfv = (tr.get("vehicle") or {}).get("fv") or []
        rfv = ((rec.get("vehicle") or {}).get("fv")) or []
        got = {}
        if rfv and tfv:
            for fv, m in zip(rfv, match_fvs(rfv, tfv)):
                if m is not None and fv.get("distance_m") is not None:
                    got.setdefault(m[0], fv["distance_m"])
        for j, t in enumerate(tfv):
            if t["visible"]:
                out.append((float(t["distance_m"]), got.get(j)))
    return out


def fv_stats(pairs) -> dict:
    ranged = [(dt, de) for dt, de in pairs if de is not None]
    err = np.array([abs(de - dt) for dt, de in ranged])
    some = len(ranged) > 0
    return {"n_frames_visible": len(pairs), "ranged_frac": len(ranged) / len(pairs) if pairs else None,
            "mean_err_m": float(err.mean()) if some else None, "max_err_m": float(err.max()) if some else None,
            "std_err_m": float(err.std()) if some else None,
            "mean_err_pct": float(np.mean([100 * abs(de - dt) / dt for dt, de in ranged])) if some else None,
            "true_distance_min_m": min(p[0] for p in pairs) if pairs else None,
            "true_distance_max_m": max(p[0] for p in pairs) if pairs else None}


def _means(rows, param, col):
    out = {}
    for r in rows:
        if r.get(col) is not None:
            out.setdefault(r[param], []).append(float(r[col]))
    return {k: float(np.mean(v)) for k, v in sorted(out.items())}


# ------------------------------------------------------------------ Figure 38

def measure_fv_speed(fv_kmh: float, seed: int, quick: bool, cache) -> dict:
    spec = SceneSpec.of("night-road", scene_seed=seed, noise_seed=seed, n_frames=45 if quick else 90,
                        hv_kmh=30.0, fv_kmh=float(fv_kmh), fv_gap_m=40.0)
    scene, frames, truth = cache.render(spec)
    return fv_stats(fv_ranges(run_receiver(scene, frames, truth), truth))


def summarize_fv_speed(rows):
    mean = _means(rows, "fv_kmh", "mean_err_m")
    mx = _means(rows, "fv_kmh", "max_err_m")
    if not mean:
        return {"thesis": "mean and max error grow steadily with FV speed 0-110 km/h", "ours": "FV never ranged",
                "why": "no FV ranged"}
    lo, hi = min(mean), max(mean)
    pct = _means(rows, "fv_kmh", "mean_err_pct")
    rng = _means(rows, "fv_kmh", "ranged_frac")
    never = sum(1 for r in rows if r.get("ranged_frac") == 0.0)
    ours = (f"mean |error| {mean[lo]:.2f} m ({pct[lo]:.1f} %) at {lo:g} km/h, {mean[hi]:.2f} m ({pct[hi]:.1f} %) at "
            f"{hi:g} km/h; max {mx[lo]:.2f} -> {mx[hi]:.2f} m (gap starts at 40 m, 3 s); FV ranged in "
            f"{min(rng.values()):.0%}-{max(rng.values()):.0%} of frames (mean over seeds)"
            + (f"; {never} of {len(rows)} runs never ranged it" if never else ""))
    why = ("Agrees in trend, but here a faster FV also ends the 3 s further away (15 m at 0 km/h, 107 m at "
           "110 km/h) and the range from a 1.4 m taillight baseline loses accuracy with distance, so this sweep does "
           "not separate speed from distance; the thesis attributes the growth to execution time. Runs where the "
           "pair was never ranged are the receiver failing, shown as such.")
    return {"thesis": "mean and max error grow steadily with FV speed 0-110 km/h (HV 30 km/h, within 200 m)",
            "ours": ours, "why": why}


# ------------------------------------------------------------------ Figure 39

def hv_errors(records: list[dict], truth: list[dict]):
    """Per frame: HV position error m (None without a fix), SLs in view, SL IDs decoded, and
    whether a decoded SL ID is none of the SLs in view (a wrong ID that places the HV at another
    light)."""
    out = []
    for rec, tr in zip(records, truth):
        v = rec.get("vehicle") or {}
        hv = v.get("hv")
        th = (tr.get("vehicle") or {}).get("hv")
        err = None
        if hv is not None and th is not None and hv.get("x") is not None:
            err = math.hypot(hv["x"] - th["x"], hv["y"] - th["y"])
        fv_ids = {f["id"] for f in (tr.get("vehicle") or {}).get("fv", [])}
        visible = {d["id"] for d in tr["leds"] if d["visible"] and d["mode"] == "s2psk" and d["id"] not in fv_ids}
        ids = {o["id"] for o in rec["leds"] if o["id"] is not None and o.get("kind") == "SL"}
        out.append((err, len(visible), len(ids), bool(ids - visible)))
    return out


def measure_spacing(spacing_m: float, seed: int, quick: bool, cache) -> dict:
    spec = SceneSpec.of("night-road", scene_seed=seed, noise_seed=seed, n_frames=90 if quick else 180,
                        hv_kmh=50.0, light_spacing_m=float(spacing_m))
    scene, frames, truth = cache.render(spec)
    per = hv_errors(run_receiver(scene, frames, truth), truth)
    errs = np.array([p[0] for p in per if p[0] is not None])
    some = len(errs) > 0
    return {"fix_frac": len(errs) / len(per), "mean_err_m": float(errs.mean()) if some else None,
            "p95_err_m": float(np.percentile(errs, 95)) if some else None,
            "max_err_m": float(errs.max()) if some else None,
            "within_1m_frac": float(np.mean([p[0] is not None and p[0] <= 1.0 for p in per])),
            "sl_in_view": float(np.mean([p[1] for p in per])),
            "sl_decoded": float(np.mean([p[2] for p in per])),
            "wrong_sl_id_frac": float(np.mean([p[3] for p in per]))}


def summarize_spacing(rows):
    fix = _means(rows, "spacing_m", "fix_frac")
    err = {}
    for r in rows:
        if r.get("mean_err_m") is not None:
            err.setdefault(r["spacing_m"], []).append(float(r["mean_err_m"]))
    err = {k: float(np.median(v)) for k, v in err.items()}  # a run that fails far off does not hide the others
    view = _means(rows, "spacing_m", "sl_in_view")
    w1 = _means(rows, "spacing_m", "within_1m_frac")
    best = max(w1, key=w1.get) if w1 else None
    ours = ("; ".join(f"{s:g} m: fix {fix[s]:.0%}" + (f", err {err[s]:.2f} m" if s in err else "")
                      + f", {view[s]:.1f} SLs in view" for s in fix) + " (err: median over seeds of each run's mean)"
            + (f"; best share of frames within 1 m: {w1[best]:.0%} at {best:g} m" if best is not None else ""))
    dec = _means(rows, "spacing_m", "sl_decoded")
    gone = min((sp for sp, v in fix.items() if v == 0.0 and any(f > 0 for k, f in fix.items() if k < sp)), default=None)
    why = "The thesis's 'accuracy %' is not defined; we report fix availability and error. "
    far = [r for r in rows if r.get("mean_err_m") is not None and r["mean_err_m"] > 10.0]
    if far:
        wrong = [r["wrong_sl_id_frac"] for r in far if r.get("wrong_sl_id_frac") is not None]
        why += (f"In {len(far)} of {len(rows)} runs the fixes were off by "
                + ", ".join(f"{r['mean_err_m']:.0f} m" for r in far) + " on average ("
                + ", ".join(f"{r['spacing_m']:g} m spacing seed {r['seed']:g}" for r in far) + ")")
        if len(wrong) == len(far):
            why += (", with an SL ID of no light in view in " + ", ".join(f"{w:.0%}" for w in wrong)
                    + " of their frames"
                    + ("; a wrong ID does not explain a run without one: there the HV locator itself failed"
                       if min(wrong) == 0.0 else ""))
        why += ". The error above is the median over seeds. "
    if gone is not None:
        why += (f"From {gone:g} m spacing on there is no HV fix: only {dec[gone]:.1f} SLs are decoded per frame on "
                f"average ({view[gone]:.0f} in view), because a 2.4 s S2-PSK packet must be seen before an SL counts, "
                "and far heads are a few px; the thesis's peak at 40 m is not reproduced.")
    else:
        why += "Dense lights give more SLs in view and more fixes."
    return {"thesis": "accuracy rises sharply from 10 to 40 m (~90 % at 40 m, 4 SLs in view), then falls to 150 m",
            "ours": ours, "why": why}


EXPERIMENTS = [
    Experiment("fig38", "Fig. 38", "FV distance error vs FV speed (HV 30 km/h)", "fv_kmh", "FV speed (km/h)",
               (0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 110.0), (0.0, 110.0), measure_fv_speed,
               (Panel("|FV distance error| (m)", (("mean_err_m", "mean"), ("max_err_m", "max"))),
                Panel("fraction of frames", (("ranged_frac", "FV ranged"),)),
                Panel("true FV distance (m)", (("true_distance_min_m", "min"), ("true_distance_max_m", "max")))),
               summarize_fv_speed),
    Experiment("fig39", "Fig. 39", "HV positioning vs street-light spacing (HV 50 km/h)", "spacing_m",
               "street-light spacing (m)", (10.0, 25.0, 40.0, 75.0, 150.0),
               (25.0, 150.0), measure_spacing,
               (Panel("HV position error (m)", (("mean_err_m", "mean"), ("p95_err_m", "95th percentile")), logy=True),
                Panel("fraction of frames", (("fix_frac", "HV fix"), ("within_1m_frac", "fix within 1 m")),
                      thesis=(((40.0,), (0.9,), "thesis: accuracy ~90 % at 40 m (its metric)"),)),
                Panel("street lights per frame", (("sl_in_view", "in view"), ("sl_decoded", "ID decoded")),
                      thesis=(((40.0,), (4.0,), "thesis: SL-IDs from 4 SLs at 40 m"),))),
               summarize_spacing),
]
