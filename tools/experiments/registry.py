"""The experiments: what each sweeps, how a point is measured, how it is drawn and summarised.

An experiment module defines `EXPERIMENTS`, a list of `Experiment`; `all_experiments()` collects
them in the order of `MODULES` (the thesis's figure order, then the ones beyond the thesis).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

MODULES = ("tools.experiments.ber", "tools.experiments.tracking", "tools.experiments.height",
           "tools.experiments.distance", "tools.experiments.road", "tools.experiments.availability")


@dataclass(frozen=True)
class Panel:
    """One plot panel: `series` ((CSV column, legend label), ...) drawn against the parameter,
    the mean over seeds as a line and their min..max as a band; `thesis` ((xs, ys, label), ...)
    reference curves drawn dashed beside ours: the thesis's reported values or trend (labels
    starting "thesis:") or a theoretical formula (labels naming it). A `ylabel` starting "fraction"
    is drawn on the whole 0..1."""

    ylabel: str
    series: tuple
    logy: bool = False
    thesis: tuple = ()


@dataclass(frozen=True)
class Experiment:
    """`name`: CLI name and file stem; `figure`: the thesis's figure(s) or "beyond the thesis";
    `param`: the swept CSV column (with its unit in the name), `param_label` its axis label;
    `points`/`quick_points`: the sweep of a full and of a --quick run; `measure(value, seed,
    quick, cache) -> dict` one point and seed (module-level, so worker processes can run it);
    `summarize(rows) -> {"thesis", "ours", "why"}` the summary.md cells (`rows` as in the CSV);
    `plot(rows, path, cache=, quick=)` replaces the generic panel plot when given (e.g. time
    traces, re-made from the cached renders); `tick_label(value) -> str` names the swept values on
    a log x axis (default `%g`, e.g. "1/2000" for an exposure in s)."""

    name: str
    figure: str
    title: str
    param: str
    param_label: str
    points: tuple
    quick_points: tuple
    measure: Callable
    panels: tuple
    summarize: Callable
    logx: bool = False
    plot: Callable | None = None
    tick_label: Callable | None = None


def all_experiments() -> dict[str, Experiment]:
    out = {}
    for mod in MODULES:
        try:
            m = importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name != mod:
                raise
            continue  # a family not written yet
        for exp in m.EXPERIMENTS:
            out[exp.name] = exp
    return out
