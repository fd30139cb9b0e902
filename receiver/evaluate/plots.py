"""Evaluation plots (PNG, matplotlib Agg backend): kept out of the core so nothing else pays
for matplotlib.

`plot_eval` draws the thesis' Figure 31 (true vs estimated trajectory, top view) and Figure 33
(position error over time), plus distance error vs LED pixel area when distances exist.
"""

from __future__ import annotations

import numpy as np

from receiver.core.errors import InputError

FIG_DPI = 100
PANEL_SIZE_IN = (5.0, 4.5)  # width, height of one panel
AREA_MARGIN = 2.0  # x range of the distance panel extends this factor past data and bin edges


def plot_eval(series: dict, path: str, *, area_bins_px=(400.0, 1600.0, 6400.0),
              dpi: int = FIG_DPI) -> None:
    """Write the evaluation figure to `path`.

    series: as returned by `receiver.evaluate.metrics.evaluate`: `t_s` (N,), `true_xyz`, `filtered_xyz`,
    `raw_xyz` (N, 3) in m, world frame (x, y on the floor), nan where the run had no position;
    `filtered_err_m`, `raw_err_m` (N,); `dist_area_px`, `dist_rel_err` (K,).
    area_bins_px: the size-bin edges of the distance table, drawn as dashed lines (the x range
    always spans them, so figures of different runs share a scale).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_dist = len(series["dist_rel_err"]) > 0
    n_panels = 3 if has_dist else 2
    fig, axes = plt.subplots(1, n_panels, figsize=(PANEL_SIZE_IN[0] * n_panels, PANEL_SIZE_IN[1]))
    try:
        ax = axes[0]
        tru, filt, raw = series["true_xyz"], series["filtered_xyz"], series["raw_xyz"]
        ax.plot(tru[:, 0], tru[:, 1], "k-", lw=2, label="true")
        if np.isfinite(raw).any():
            ax.plot(raw[:, 0], raw[:, 1], ".", color="tab:orange", ms=4, label="raw")
        if np.isfinite(filt).any():
            ax.plot(filt[:, 0], filt[:, 1], "-", color="tab:blue", lw=1, label="filtered")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title("Trajectory, top view")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.legend()

        ax = axes[1]
        t = series["t_s"]
        if np.isfinite(series["raw_err_m"]).any():
            ax.plot(t, series["raw_err_m"] * 100, ".", color="tab:orange", ms=4, label="raw")
        ax.plot(t, series["filtered_err_m"] * 100, "-", color="tab:blue", label="filtered")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("3D position error (cm)")
        ax.set_title("Position error over time")
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend()

        if has_dist:
            ax = axes[2]
            area = np.asarray(series["dist_area_px"], float)
            ax.semilogx(area, np.asarray(series["dist_rel_err"]) * 100, ".", ms=4)
            for edge in area_bins_px:
                ax.axvline(edge, color="gray", ls="--", lw=0.8)
            lo = min(area.min(), *area_bins_px) / AREA_MARGIN
            hi = max(area.max(), *area_bins_px) * AREA_MARGIN
            ax.set_xlim(lo, hi)
            ax.set_ylim(bottom=0)
            ax.set_xlabel("LED pixel area (px)")
            ax.set_ylabel("distance error |d - d_true| / d_true (%)")
            ax.set_title("Distance error vs LED size")
            ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        try:
            fig.savefig(path, dpi=dpi, format="png")
        except OSError as e:
            raise InputError(f"cannot write plot {path}: {e.strerror or e}") from None
    finally:
        plt.close(fig)
