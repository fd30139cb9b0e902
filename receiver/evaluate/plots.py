"""Evaluation plots (PNG, matplotlib Agg backend): kept out of the core so nothing else pays
for matplotlib.

`plot_eval` draws the thesis' Figure 31 (true vs estimated trajectory, top view) and Figure 33
(position error over time), plus distance error vs LED pixel area when distances exist.
In a vehicle scene (series["vehicle"] set) it draws `plot_vehicle` instead: the HV's road
trajectory against truth, the FV distances against truth over time (thesis Figures 38-39 plot
their errors) and the HV error over time.
"""

from __future__ import annotations

import numpy as np

from receiver.core.errors import InputError

FIG_DPI = 100
PANEL_SIZE_IN = (5.0, 4.5)  # width, height of one panel
AREA_MARGIN = 2.0  # x range of the distance panel extends this factor past data and bin edges
# Vehicle figure: a full-width road strip on top, two panels below.
VEHICLE_FIG_IN = (12.0, 9.0)
# The road strip's y range spans at least this (m): two 3.5 m lanes either side of the host lane
# centre, so lane-level errors read as such instead of being blown up to the panel height.
ROAD_MIN_HALF_WIDTH_M = 4.0


def plot_eval(series: dict, path: str, *, area_bins_px=(400.0, 1600.0, 6400.0),
              dpi: int = FIG_DPI) -> None:
    """Write the evaluation figure to `path`.

    series: as returned by `receiver.evaluate.metrics.evaluate`: `t_s` (N,), `true_xyz`, `filtered_xyz`,
    `raw_xyz` (N, 3) in m, world frame (x, y on the floor), nan where the run had no position;
    `filtered_err_m`, `raw_err_m` (N,); `dist_area_px`, `dist_rel_err` (K,).
    area_bins_px: the size-bin edges of the distance table, drawn as dashed lines (the x range
    always spans them, so figures of different runs share a scale).
    """
    if series.get("vehicle") is not None:
        plot_vehicle(series["vehicle"], path, dpi=dpi)
        return
    plt = _pyplot()

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
        _save(fig, path, dpi)
    finally:
        plt.close(fig)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str, dpi: int) -> None:
    try:
        fig.savefig(path, dpi=dpi, format="png")
    except OSError as e:
        raise InputError(f"cannot write plot {path}: {e.strerror or e}") from None


def plot_vehicle(vs: dict, path: str, *, dpi: int = FIG_DPI) -> None:
    """Write the vehicle-scene figure to `path`.

    vs: the `vehicle` series of `receiver.evaluate.metrics.evaluate_vehicle`: `t_s` (N,),
    `hv_true_xy` (N, 2) and `hv` {name: (N, 2)} road x, y in m, `hv_err_m` {name: (N,)}, and
    `fv` {label: {"true_m", "run_m"}} (N,) distances in m; nan where absent.
    """
    plt = _pyplot()
    fig = plt.figure(figsize=VEHICLE_FIG_IN)
    try:
        grid = fig.add_gridspec(2, 2, height_ratios=(1.0, 1.3))
        ax = fig.add_subplot(grid[0, :])
        t = vs["t_s"]
        tru = vs["hv_true_xy"]
        ax.plot(tru[:, 0], tru[:, 1], "k-", lw=2, label="true")
        styles = _hv_styles(vs["hv"])
        for name, xy in vs["hv"].items():
            if np.isfinite(xy).any():
                ax.plot(xy[:, 0], xy[:, 1], **styles[name], label=name)
        ys = np.concatenate([a[:, 1] for a in (tru, *vs["hv"].values())])
        ys = ys[np.isfinite(ys)]
        half = max(ROAD_MIN_HALF_WIDTH_M, float(np.abs(ys).max()) * 1.1 if ys.size else 0.0)
        ax.set_ylim(-half, half)
        ax.set_xlabel("x along the road (m)")
        ax.set_ylabel("y (m, left +)")
        ax.set_title("Host vehicle trajectory, top view")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize="small")

        ax = fig.add_subplot(grid[1, 0])
        colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for i, (label, fv) in enumerate(vs["fv"].items()):
            c = colours[i % len(colours)]
            ax.plot(t, fv["true_m"], "-", color=c, lw=1.5, label=f"FV {label} true")
            if np.isfinite(fv["run_m"]).any():
                ax.plot(t, fv["run_m"], ".", color=c, ms=4, label=f"FV {label} run")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("distance to FV (m)")
        ax.set_title("Forward vehicle distance")
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        if vs["fv"]:
            ax.legend(fontsize="small")

        ax = fig.add_subplot(grid[1, 1])
        for name, err in vs["hv_err_m"].items():
            if np.isfinite(err).any():
                st = dict(styles[name], ls="-" if name == "filtered" else "none")
                ax.plot(t, err, **st, label=name)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("HV 2D position error (m)")
        ax.set_title("Host vehicle error over time")
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        if any(np.isfinite(e).any() for e in vs["hv_err_m"].values()):
            ax.legend(fontsize="small")
        fig.tight_layout()
        _save(fig, path, dpi)
    finally:
        plt.close(fig)


def _hv_styles(fixes: dict) -> dict:
    """Filtered fix a line, raw fixes dots, further locators (hv_<name>) other markers."""
    out = {"filtered": {"color": "tab:blue", "ls": "-", "lw": 1.2},
           "raw": {"color": "tab:orange", "ls": "none", "marker": ".", "ms": 4}}
    markers, colours = "x+^v", ("tab:green", "tab:red", "tab:purple", "tab:brown")
    extra = [n for n in fixes if n not in out]
    for i, name in enumerate(extra):
        out[name] = {"color": colours[i % len(colours)], "ls": "none", "marker": markers[i % len(markers)], "ms": 4}
    return out
