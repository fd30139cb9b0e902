"""Scoring a run against a recording's `truth.jsonl` (the metrics of `occloc eval`).

Both formats are in INTERFACES.md. Per frame, the run's LEDs are matched to the truth LEDs
that are visible, by nearest image centroid within a gate (one-to-one, closest pairs first);
an S2-PSK truth entry offers its two `emitters` (each with its own cx, cy) as match targets,
because the receiver reports the emitters as separate blobs. From the matches:

* ID rate = matched LED-frames whose decoded ID is the truth ID / all matched LED-frames;
  wrong IDs = matched LED-frames with a decoded ID different from the truth ID (an undecoded
  `id: null` is neither right nor wrong).
* distance error = |d - d_true| / d_true (relative, thesis eq. 18 is evaluated this way in its
  lab experiment), overall, by the run's LED pixel area `area_px` and by the LED's
  `distance_estimator` ("unnamed" when the run does not say).
* position error = 3D Euclidean distance (m) between the run's `position` (filtered) or its
  `position.raw` and the truth camera x, y, z (world frame: x, y on the floor, z up).
* latency p50/p99 over the run's `latency_ms`.

Plots (thesis Figures 31 and 33) live in `receiver.evaluate.plots`, imported only with `--plot`.
"""

from __future__ import annotations

import math

import numpy as np


# Match gate: a detected centroid farther than this from every visible truth LED is unmatched.
# The walk's LEDs are ~200 px across and centroids agree to ~1 px; blobs clipped by the image
# border move their centroid by tens of px, and those are not counted.
DEFAULT_GATE_PX = 15.0
# LED pixel-area bin edges for the distance error (the "by LED size"; eq. 18 degrades
# as eta, the blob area, gets small).
DEFAULT_AREA_BINS_PX = (400.0, 1600.0, 6400.0)


# ---------------------------------------------------------------- matching and metrics


def match_leds(run_xy: np.ndarray, truth_xy: np.ndarray, *, gate_px: float = DEFAULT_GATE_PX) -> list:
    """One-to-one nearest-centroid matching: for each run point the truth index or None.

    run_xy (N, 2) and truth_xy (M, 2) are image points in px. Pairs are taken closest first,
    so two blobs near one truth LED cannot both claim it.
    """
    out = [None] * len(run_xy)
    if len(run_xy) == 0 or len(truth_xy) == 0:
        return out
    d = np.hypot(run_xy[:, None, 0] - truth_xy[None, :, 0], run_xy[:, None, 1] - truth_xy[None, :, 1])
    used_t = set()
    for flat in np.argsort(d, axis=None, kind="stable"):
        i, j = divmod(int(flat), d.shape[1])
        if d[i, j] > gate_px:
            break
        if out[i] is None and j not in used_t:
            out[i] = j
            used_t.add(j)
    return out


def _stats(values, qs=(50, 95)) -> dict:
    v = np.asarray(values, float)
    out = {"n": int(v.size)}
    for q in qs:
        out[f"p{q}"] = float(np.percentile(v, q)) if v.size else None
    return out


def _bin_label(lo: float, hi: float) -> str:
    if lo == 0:
        return f"<{hi:g}"
    if math.isinf(hi):
        return f">={lo:g}"
    return f"{lo:g}-{hi:g}"


def evaluate(run: list[dict], truth: dict[int, dict], *, gate_px: float = DEFAULT_GATE_PX,
             area_bins_px=DEFAULT_AREA_BINS_PX) -> tuple[dict, dict]:
    """(metrics, series). metrics is JSON-ready (None where undefined); series holds the
    per-frame arrays the plots need: t_s (N,), true/filtered/raw xyz (N, 3) with nan where the
    run has no position, their 3D errors (N,), and per distance sample area_px and rel. error."""
    matched = correct = wrong = run_leds = visible = 0
    dist_area, dist_err, dist_est = [], [], []
    n = len(run)
    t_s = np.full(n, np.nan)
    true_xyz, filt_xyz, raw_xyz = (np.full((n, 3), np.nan) for _ in range(3))
    latency = []
    for k, fr in enumerate(run):
        tr = truth[fr["frame"]]
        t_s[k] = fr["t"] if fr["t"] is not None else fr["frame"]
        true_xyz[k] = tr["xyz"]
        if fr["filtered"] is not None:
            filt_xyz[k] = fr["filtered"]
        if fr["raw"] is not None:
            raw_xyz[k] = fr["raw"]
        if fr["latency_ms"] is not None:
            latency.append(fr["latency_ms"])
        targets = tr["targets"]
        run_leds += len(fr["leds"])
        visible += len(targets)
        m = match_leds(np.array([(o["cx"], o["cy"]) for o in fr["leds"]]).reshape(-1, 2),
                       np.array([t[:2] for t in targets]).reshape(-1, 2), gate_px=gate_px)
        for o, j in zip(fr["leds"], m):
            if j is None:
                continue
            _, _, true_id, true_d = targets[j]
            matched += 1
            if o["id"] is not None:
                if o["id"] == true_id:
                    correct += 1
                else:
                    wrong += 1
            if o["distance_m"] is not None and o["area_px"] is not None and true_d:
                dist_area.append(o["area_px"])
                dist_err.append(abs(o["distance_m"] - true_d) / true_d)
                dist_est.append(o["estimator"])
    filt_err = np.linalg.norm(filt_xyz - true_xyz, axis=1)
    raw_err = np.linalg.norm(raw_xyz - true_xyz, axis=1)
    dist_area, dist_err = np.array(dist_area), np.array(dist_err)

    edges = [0.0, *area_bins_px, math.inf]
    bins = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (dist_area >= lo) & (dist_area < hi)
        bins.append({"area_px": _bin_label(lo, hi), **_stats(dist_err[sel])})
    metrics = {
        "frames": n,
        "frames_with_position": int(np.isfinite(filt_err).sum()),
        "gate_px": gate_px,
        "led_frames": run_leds,
        "visible_truth_led_frames": visible,
        "matched_led_frames": matched,
        "unmatched_led_frames": run_leds - matched,
        "ids_correct": correct,
        "wrong_ids": wrong,
        "undecoded": matched - correct - wrong,
        "id_rate": correct / matched if matched else None,
        "distance_rel_error": {**_stats(dist_err), "by_area_px": bins, "by_estimator": {
            name: _stats(dist_err[np.array(dist_est) == name]) for name in sorted(set(dist_est))}},
        "position_error_m": {"filtered": _stats(filt_err[np.isfinite(filt_err)]),
                             "raw": _stats(raw_err[np.isfinite(raw_err)])},
        "latency_ms": _stats(latency, qs=(50, 99)),
    }
    series = {"t_s": t_s, "true_xyz": true_xyz, "filtered_xyz": filt_xyz, "raw_xyz": raw_xyz,
              "filtered_err_m": filt_err, "raw_err_m": raw_err,
              "dist_area_px": dist_area, "dist_rel_err": dist_err}
    return metrics, series


# ---------------------------------------------------------------- output


def _fmt(v, scale=1.0, unit="", nd=2) -> str:
    return "-" if v is None else f"{v * scale:.{nd}f}{unit}"


def format_table(m: dict) -> str:
    """The metrics as a readable plain-text table."""
    rows = [
        ("frames", f"{m['frames']} ({m['frames_with_position']} with a position)"),
        ("LED-frames", f"{m['led_frames']} detected, {m['visible_truth_led_frames']} visible in truth, "
                       f"{m['matched_led_frames']} matched (gate {m['gate_px']:g} px)"),
        ("ID rate", f"{_fmt(m['id_rate'], 100, ' %')} ({m['ids_correct']}/{m['matched_led_frames']})"),
        ("wrong IDs", f"{m['wrong_ids']} (undecoded {m['undecoded']})"),
    ]
    de = m["distance_rel_error"]
    rows.append(("distance error", f"median {_fmt(de['p50'], 100, ' %', 3)}  p95 {_fmt(de['p95'], 100, ' %', 3)}"
                                   f"  (n={de['n']})"))
    for b in de["by_area_px"]:
        rows.append((f"  area {b['area_px']} px", f"median {_fmt(b['p50'], 100, ' %', 3)}  "
                                                  f"p95 {_fmt(b['p95'], 100, ' %', 3)}  (n={b['n']})"))
    for name, b in de["by_estimator"].items():
        rows.append((f"  estimator {name}", f"median {_fmt(b['p50'], 100, ' %', 3)}  "
                                  f"p95 {_fmt(b['p95'], 100, ' %', 3)}  (n={b['n']})"))
    for kind in ("filtered", "raw"):
        pe = m["position_error_m"][kind]
        rows.append((f"position {kind}", f"median {_fmt(pe['p50'], 100, ' cm')}  p95 {_fmt(pe['p95'], 100, ' cm')}"
                                         f"  (n={pe['n']})"))
    la = m["latency_ms"]
    rows.append(("latency", f"p50 {_fmt(la['p50'], unit=' ms')}  p99 {_fmt(la['p99'], unit=' ms')}  (n={la['n']})"))
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
