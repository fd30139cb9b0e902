"""Indoor tracking (Figures 30, 31, 33): a phone walking under the ceiling of `indoor-walk`
(0.3 x 0.6 m OOK panels: Table 2's 10 x 10 cm panels are not decoded from 2 m, see fig32), the
receiver's raw fix (`position["raw"]`, one frame's solve) against its Kalman-filtered position
(`position` x, y, z), over time. The sweep is the walking speed; the PNG shows the error over
time and the x / y traces against the truth for the first seed at 1 m/s."""

from __future__ import annotations

import math

import numpy as np

from tools.experiments.cache import SceneSpec
from tools.experiments.receive import run_receiver
from tools.experiments.registry import Experiment, Panel

SECONDS = 6.0
TRACE_SPEED = 1.0


def _spec(speed_mps: float, seed: int, quick: bool) -> SceneSpec:
    return SceneSpec.of("indoor-walk", scene_seed=seed, noise_seed=seed, n_frames=int(30 * (3.0 if quick else SECONDS)),
                        speed_mps=float(speed_mps), room_m=20.0)


def traces(speed_mps: float, seed: int, quick: bool, cache):
    """(t s, truth xyz (N, 3), filtered xyz or NaN (N, 3), raw xyz or NaN (N, 3))."""
    scene, frames, truth = cache.render(_spec(speed_mps, seed, quick))
    recs = run_receiver(scene, frames, truth)
    t = np.array([tr["t"] for tr in truth])
    true = np.array([[tr["camera"][k] for k in "xyz"] for tr in truth])
    filt = np.full_like(true, np.nan)
    raw = np.full_like(true, np.nan)
    for i, r in enumerate(recs):
        p = r["position"]
        if p is not None:
            filt[i] = [p["x"], p["y"], p["z"]]
            if p.get("raw"):
                raw[i] = [p["raw"]["x"], p["raw"]["y"], p["raw"]["z"]]
    return t, true, filt, raw


def _stats(err: np.ndarray, prefix: str) -> dict:
    ok = err[np.isfinite(err)]
    return {f"{prefix}fix_frac": len(ok) / len(err), f"{prefix}mean_err_m": float(ok.mean()) if len(ok) else None,
            f"{prefix}p95_err_m": float(np.percentile(ok, 95)) if len(ok) else None}


def measure_walk(speed_mps: float, seed: int, quick: bool, cache) -> dict:
    t, true, filt, raw = traces(speed_mps, seed, quick, cache)
    e_f = np.linalg.norm((filt - true)[:, :2], axis=1)
    e_r = np.linalg.norm((raw - true)[:, :2], axis=1)
    row = {**_stats(e_r, "raw_"), **_stats(e_f, "kalman_")}
    late = t >= 1.0
    row["kalman_mean_err_after_1s_m"] = float(np.nanmean(e_f[late])) if np.isfinite(e_f[late]).any() else None
    row["raw_mean_err_after_1s_m"] = float(np.nanmean(e_r[late])) if np.isfinite(e_r[late]).any() else None
    first = np.flatnonzero(np.isfinite(e_f))
    row["first_fix_s"] = float(t[first[0]]) if len(first) else None
    return row


def plot_walk(rows, path, cache=None, quick=False):
    from tools.experiments.report import pyplot, save, by_point

    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(10.0, 6.4))
    ax = axes[0, 0]
    for i, (col, label) in enumerate((("raw_mean_err_m", "raw fix"), ("kalman_mean_err_m", "Kalman-filtered"))):
        xs, m, lo, hi = by_point(rows, "speed_mps", col)
        ax.plot(xs, 100 * m, "o-" if i == 0 else "s--", color=f"C{i}", ms=6 if i == 0 else 4, label=f"ours: {label}")
        ax.fill_between(xs, 100 * lo, 100 * hi, color=f"C{i}", alpha=0.2, lw=0)
    ax.axhspan(9, 10, color="k", alpha=0.15, label="thesis: 9-10 cm with the filter")
    ax.set_xlabel("walking speed (m/s)")
    ax.set_ylabel("mean horizontal error (cm)")
    ax.set_title("Fig. 30/33: error vs speed (band: seeds)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    if cache is not None:
        t, true, filt, raw = traces(TRACE_SPEED, 0, quick, cache)
        ax = axes[0, 1]
        ax.plot(t, 100 * np.linalg.norm((filt - true)[:, :2], axis=1), "-", color="C1", lw=1, label="ours: Kalman")
        ax.plot(t, 100 * np.linalg.norm((raw - true)[:, :2], axis=1), ".", ms=3, color="C0", zorder=3,
                label="ours: raw fix")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("horizontal error (cm)")
        ax.set_title(f"Fig. 33: error over time at {TRACE_SPEED:g} m/s, seed 0 (no point: no fix)", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
        for j, (k, name) in enumerate(((0, "x"), (1, "y"))):
            ax = axes[1, j]
            ax.plot(t, true[:, k], "-", color="g", label="truth")
            ax.plot(t, raw[:, k], ".", ms=2, color="C0", label="ours: raw fix")
            ax.plot(t, filt[:, k], "-", color="r", lw=1, label="ours: Kalman")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"{name} (m)")
            ax.set_title(f"Fig. 31({'ab'[j]}): {name} vs truth", fontsize=9)
            ax.legend(fontsize=7)
            ax.grid(True, alpha=0.3)
    fig.tight_layout()
    save(fig, path)


def summarize_walk(rows):
    def m(col):
        v = [float(r[col]) for r in rows if r.get(col) is not None and r["speed_mps"] == TRACE_SPEED]
        return float(np.mean(v)) if v else None
    kf, raw, fix = m("kalman_mean_err_m"), m("raw_mean_err_m"), m("kalman_fix_frac")
    if kf is None:
        return {"thesis": "9-10 cm with the Kalman filter; 50 % error without it at 10 s", "ours": "no fix",
                "why": "the walk was never positioned"}
    ours = (f"at {TRACE_SPEED:g} m/s: Kalman {100 * kf:.2f} cm, raw fix {100 * raw:.2f} cm mean horizontal error; "
            f"fix in {fix:.0%} of frames" + (f"; first fix after {m('first_fix_s'):.2f} s"
                                               if m("first_fix_s") is not None else ""))
    why = ("Ours is far below the thesis's 9-10 cm because each raw fix already uses several large decoded panels "
           "and their outlines at 30 fps; "
           + ("the filter smooths these mm-level fixes a little." if kf < raw else
              f"the filter adds nothing measurable ({100 * kf:.2f} vs {100 * raw:.2f} cm raw): fixes this precise "
              "leave it little noise to remove.")
           + " The thesis's 50 % error without a filter has no unit we can reproduce.")
    return {"thesis": "9-10 cm with the Kalman filter; 50 % error without it at 10 s (1 Hz samples, 50 s)",
            "ours": ours, "why": why}


EXPERIMENTS = [
    Experiment("tracking", "Figs. 30, 31, 33", "indoor tracking: raw fix vs Kalman filter", "speed_mps",
               "walking speed (m/s)", (0.5, 1.0, 1.5), (1.0,), measure_walk, (), summarize_walk, plot=plot_walk),
]
