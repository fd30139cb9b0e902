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
VEHICLE_FIG_IN = (12.0, 12.5)
# The time-to-collision panel spans up to this (s): longer times are not urgent, drawn at the edge.
TTC_AXIS_MAX_S = 15.0
# The road strip's y range spans at least this (m): two 3.5 m lanes either side of the host lane
# centre, so lane-level errors read as such instead of being blown up to the panel height.
ROAD_MIN_HALF_WIDTH_M = 4.0
# Axis ranges robust to outliers: an axis spans the reference series (truth, the filtered fix) and
# the other series' ROBUST_PERCENTILE times ROBUST_MARGIN; points beyond are drawn at the edge
# (clipped) and counted in the panel's title, so one wild fix of an extra locator cannot squash
# a 0.05 m error into a 260 m axis.
ROBUST_PERCENTILE = 95.0
ROBUST_MARGIN = 1.5


# The error panel turns logarithmic when its range exceeds this many times the filtered fix's
# median error; errors below LOG_FLOOR_M (m) sit on the floor.
LOG_AXIS_RATIO = 50.0
LOG_FLOOR_M = 1e-3


def robust_upper(reference, others) -> float:
    """Upper axis limit: max of the finite `reference` arrays' values and of ROBUST_MARGIN x the
    ROBUST_PERCENTILE of each array in `others` (0 when nothing is finite)."""
    top = 0.0
    for a in reference:
        a = np.asarray(a, float)
        a = a[np.isfinite(a)]
        if a.size:
            top = max(top, float(a.max()))
    for a in others:
        a = np.asarray(a, float)
        a = a[np.isfinite(a)]
        if a.size:
            top = max(top, ROBUST_MARGIN * float(np.percentile(a, ROBUST_PERCENTILE)))
    return top


def _clipped(values, lo: float, hi: float):
    """(values clipped to [lo, hi], how many finite values were outside)."""
    v = np.asarray(values, float)
    out = int(np.sum(np.isfinite(v) & ((v < lo) | (v > hi))))
    return np.clip(v, lo, hi), out


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
        grid = fig.add_gridspec(3, 2, height_ratios=(1.0, 1.3, 1.1))
        ax = fig.add_subplot(grid[0, :])
        t = vs["t_s"]
        tru = vs["hv_true_xy"]
        ax.plot(tru[:, 0], tru[:, 1], "k-", lw=2, label="true")
        styles = _hv_styles(vs["hv"])
        ref = [np.abs(tru[:, 1])] + [np.abs(xy[:, 1]) for n, xy in vs["hv"].items() if n == "filtered"]
        rest = [np.abs(xy[:, 1]) for n, xy in vs["hv"].items() if n != "filtered"]
        half = max(ROAD_MIN_HALF_WIDTH_M, 1.1 * robust_upper(ref, rest))
        xs = tru[:, 0][np.isfinite(tru[:, 0])]
        x_lo, x_hi = (float(xs.min()) - 10.0, float(xs.max()) + 10.0) if xs.size else (-np.inf, np.inf)
        off = 0
        for name, xy in vs["hv"].items():
            if np.isfinite(xy).any():
                x, n1 = _clipped(xy[:, 0], x_lo, x_hi)
                y, n2 = _clipped(xy[:, 1], -half, half)
                off += n1 + n2
                ax.plot(x, y, **styles[name], label=name)
        ax.set_ylim(-half, half)
        if xs.size:
            ax.set_xlim(x_lo, x_hi)
        ax.set_xlabel("x along the road (m)")
        ax.set_ylabel("y (m, left +)")
        ax.set_title("Host vehicle trajectory, top view"
                     + (f" ({off} coordinates off scale, drawn at the edge)" if off else ""))
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
        errs = vs["hv_err_m"]
        top = robust_upper([e for n, e in errs.items() if n == "filtered"],
                           [e for n, e in errs.items() if n != "filtered"]) * 1.05 or 1.0
        # Series errors orders of magnitude apart (a cm-level filter beside a metres-level extra
        # locator): a log axis shows both.
        filt = np.asarray(errs.get("filtered", []), float)
        filt = filt[np.isfinite(filt) & (filt > 0)]
        log = bool(filt.size) and top > LOG_AXIS_RATIO * float(np.median(filt))
        floor = 0.0
        if log:
            allv = np.concatenate([np.asarray(e, float) for e in errs.values()])
            allv = allv[np.isfinite(allv) & (allv > 0)]
            floor = max(LOG_FLOOR_M, 0.5 * float(np.percentile(allv, 1)))
        off = 0
        for name, err in errs.items():
            if np.isfinite(err).any():
                st = dict(styles[name], ls="-" if name == "filtered" else "none")
                e, n_off = _clipped(err, floor, top)
                off += n_off
                ax.plot(t, e, **st, label=name + (f" ({n_off} off scale)" if n_off else ""))
        ax.set_xlabel("time (s)")
        ax.set_ylabel("HV 2D position error (m)")
        ax.set_title("Host vehicle error over time" + (f" ({off} off the axis, at the edge)"
                                                       if off else ""))
        if log:
            ax.set_yscale("log")
            ax.set_ylim(floor, top)
        else:
            ax.set_ylim(0, top)
        ax.grid(True, alpha=0.3)
        if any(np.isfinite(e).any() for e in vs["hv_err_m"].values()):
            ax.legend(fontsize="small")
        _fv_urgency(fig.add_subplot(grid[2, 0]), fig.add_subplot(grid[2, 1]), t, vs["fv"], colours)
        fig.tight_layout()
        _save(fig, path, dpi)
    finally:
        plt.close(fig)


def _fv_urgency(ax_ttc, ax_zone, t, fvs: dict, colours) -> None:
    """Time to collision (clipped at TTC_AXIS_MAX_S) and zone of each forward vehicle over time."""
    from receiver.evaluate.metrics import FV_ZONES
    off = 0
    for i, (label, fv) in enumerate(fvs.items()):
        c = colours[i % len(colours)]
        ttc = fv.get("ttc_s")
        if ttc is not None and np.isfinite(ttc).any():
            v, n_off = _clipped(ttc, 0.0, TTC_AXIS_MAX_S)
            off += n_off
            ax_ttc.plot(t, v, ".", color=c, ms=4, label=f"FV {label}")
        zone = fv.get("zone")
        if zone is not None and np.isfinite(zone).any():
            ax_zone.step(t, zone + 0.06 * i, where="post", color=c, label=f"FV {label}")
    ax_ttc.set_ylim(0, TTC_AXIS_MAX_S)
    ax_ttc.set_xlabel("time (s)")
    ax_ttc.set_ylabel("time to collision (s)")
    ax_ttc.set_title("Time to collision (closing cars only)"
                     + (f" ({off} above {TTC_AXIS_MAX_S:g} s, at the edge)" if off else ""))
    ax_ttc.grid(True, alpha=0.3)
    ax_zone.set_yticks(range(len(FV_ZONES)), FV_ZONES)
    ax_zone.set_ylim(-0.5, len(FV_ZONES) - 0.3)
    ax_zone.set_xlabel("time (s)")
    ax_zone.set_title("Zone (thesis Figure 27)")
    ax_zone.grid(True, alpha=0.3)
    for ax in (ax_ttc, ax_zone):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small")


def _hv_styles(fixes: dict) -> dict:
    """Filtered fix a line, raw fixes dots, further locators (hv_<name>) other markers."""
    out = {"filtered": {"color": "tab:blue", "ls": "-", "lw": 1.2},
           "raw": {"color": "tab:orange", "ls": "none", "marker": ".", "ms": 4}}
    markers, colours = "x+^v", ("tab:green", "tab:red", "tab:purple", "tab:brown")
    extra = [n for n in fixes if n not in out]
    for i, name in enumerate(extra):
        out[name] = {"color": colours[i % len(colours)], "ls": "none", "marker": markers[i % len(markers)], "ms": 4}
    return out
