"""NAME.csv, NAME.png and summary.md of an experiments run."""

from __future__ import annotations

import csv
import math
import os

import numpy as np

FIG_DPI = 110
# Lowest value drawn on a log axis (error rates: a few thousand chips per point resolve ~1e-4).
LOG_FLOOR = 1e-5


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def write_csv(path: str, exp, rows: list[dict]) -> None:
    """One row per point and seed: the parameter, the seed, then the measured columns (in the
    order the first row gives them; a missing value is an empty cell)."""
    cols = [exp.param, "seed"]
    for r in rows:
        cols += [k for k in r if k not in cols]
    tmp = path + ".tmp"
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in cols])
    os.replace(tmp, path)


def read_csv(path: str) -> list[dict]:
    """Rows of `write_csv` back: numbers as float, empty cells (and those a cut last row lacks) as
    None."""
    out = []
    with open(path, newline="", encoding="utf-8") as f:
        for r in csv.DictReader(f):
            row = {}
            for k, v in r.items():
                if k is None:   # cells beyond the header's columns
                    continue
                try:
                    row[k] = None if v is None or v == "" else float(v)
                except ValueError:
                    row[k] = v
            out.append(row)
    return out


def record_commands(folder: str, names: list[str], command: str) -> dict:
    """{experiment: the command that made its files in `folder`}, kept in folder/.commands.json."""
    import json
    path = os.path.join(folder, ".commands.json")
    try:
        with open(path, encoding="utf-8") as f:
            commands = json.load(f)
        if not isinstance(commands, dict):
            commands = {}
    except (OSError, ValueError):
        commands = {}
    commands.update({n: command for n in names})
    with open(path + ".tmp", "w", encoding="utf-8") as f:
        json.dump(commands, f, indent=1, sort_keys=True)
    os.replace(path + ".tmp", path)
    return commands


def by_point(rows: list[dict], param: str, column: str):
    """(xs, mean, lo, hi) over seeds of `column` per parameter value (points where no seed has a
    value are left out)."""
    xs, mean, lo, hi = [], [], [], []
    for x in sorted({r[param] for r in rows}):
        vals = [r.get(column) for r in rows if r[param] == x]
        vals = [float(v) for v in vals if v is not None and not isinstance(v, str) and math.isfinite(float(v))]
        if vals:
            xs.append(x)
            mean.append(float(np.mean(vals)))
            lo.append(min(vals))
            hi.append(max(vals))
    return np.array(xs, float), np.array(mean), np.array(lo), np.array(hi)


def pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def write_png(path: str, exp, rows: list[dict], n_seeds: int, cache=None, quick: bool = False) -> None:
    if exp.plot is not None:
        exp.plot(rows, path, cache=cache, quick=quick)
        return
    plt = pyplot()
    from matplotlib.ticker import FuncFormatter
    n = len(exp.panels)
    fig, axes = plt.subplots(n, 1, figsize=(7.0, 3.2 * n), squeeze=False, sharex=True)
    for ax, panel in zip(axes[:, 0], exp.panels):
        floor = LOG_FLOOR if panel.logy else None
        on_floor = False
        for i, (col, label) in enumerate(panel.series):
            xs, m, lo, hi = by_point(rows, exp.param, col)
            color = f"C{i}"
            if not len(xs):
                continue
            if floor is not None:
                # a log axis cannot show 0 (e.g. no bit error among the chips seen): such points are
                # drawn as triangles on the axis floor, the band is cut there
                zero = m <= 0
                if zero.any():
                    on_floor = True
                    ax.plot(xs[zero], np.full(zero.sum(), floor), "v", color=color, ms=5, label=f"ours: {label}: 0 seen")
                m = np.where(zero, np.nan, m)
                lo, hi = np.maximum(lo, floor), np.maximum(hi, floor)
            ax.plot(xs, m, "o-", color=color, ms=3, label=f"ours: {label}")
            if n_seeds > 1:
                ax.fill_between(xs, lo, hi, color=color, alpha=0.2, lw=0)
        for j, (txs, tys, label) in enumerate(panel.thesis):
            txs, tys = np.asarray(txs, float), np.asarray(tys, float)
            if floor is not None:
                keep = tys >= floor
                txs, tys = txs[keep], tys[keep]
            ax.plot(txs, tys, "s--" if len(txs) < 10 else "--", color="k" if j == 0 else "0.45", ms=3, lw=1, label=label)
        ax.set_ylabel(panel.ylabel)
        if panel.ylabel.startswith("fraction"):  # a share of frames: the whole 0..1, so 95 % looks like 95 %
            ax.set_ylim(-0.03, 1.03)
        if panel.logy:
            ax.set_yscale("log")
            if on_floor:  # room for the zero markers; otherwise the axis spans the data only
                ax.set_ylim(bottom=floor / 2)
        if exp.logx:
            from matplotlib.ticker import FixedLocator, NullFormatter
            ax.set_xscale("log")
            xs = sorted({float(r[exp.param]) for r in rows})
            label = exp.tick_label or (lambda v: f"{v:g}")
            ax.xaxis.set_major_locator(FixedLocator(xs))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: label(v)))
            ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel(exp.param_label)
    band = f"; band: min..max over {n_seeds} seeds" if n_seeds > 1 else "; one seed"
    import textwrap
    axes[0, 0].set_title("\n".join(textwrap.wrap(f"{exp.figure}: {exp.title}{band}", 90)), fontsize=9)
    fig.tight_layout()
    save(fig, path)


def save(fig, path: str) -> None:
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=FIG_DPI)
    pyplot().close(fig)
    os.replace(tmp, path)


def _md(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def write_summary(path: str, results: list, commands: dict) -> None:
    """`results`: (experiment, rows, summary dict) in run order; `commands`: {name: command}."""
    made = {}
    for exp, _, _ in results:
        made.setdefault(commands.get(exp.name, "?"), []).append(exp.name)
    lines = ["# occloc experiments: the thesis's chapter 6 redone with the receiver", "", "Made by:", ""]
    lines += [f"- `{c}` ({', '.join(ns)})" for c, ns in made.items()]
    lines += ["",
             "Each row: what the thesis reports, what the whole receiver measures on the synthetic "
             "camera's renders, and where and why they differ. Figures: NAME.png; numbers: NAME.csv.", "",
             "| Figure | Experiment | Thesis reports | We measure | Disagreement and why |",
             "|---|---|---|---|---|"]
    for exp, rows, s in results:
        lines.append(f"| {_md(exp.figure)} | [{exp.name}]({exp.name}.png) | {_md(s.get('thesis', ''))} | "
                     f"{_md(s.get('ours', ''))} | {_md(s.get('why', ''))} |")
    lines.append("")
    for exp, rows, s in results:
        lines += [f"## {exp.figure}: {exp.title}", "", f"![{exp.name}]({exp.name}.png)", ""]
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    os.replace(tmp, path)
