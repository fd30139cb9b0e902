"""`occloc experiments`: the thesis's chapter 6 sweeps, end to end through the receiver."""

from __future__ import annotations

import argparse
import os
import sys
import time

HELP = "redo the thesis's chapter 6 experiments with the synthetic camera and the receiver: CSV, PNG, summary"
MAX_SEEDS = 100
MAX_JOBS = 64


def _positive(limit: int):
    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if not 1 <= n <= limit:
            raise argparse.ArgumentTypeError(f"must be a whole number 1..{limit}, not {text!r}")
        return n
    return parse


def add_arguments(p) -> None:
    p.add_argument("names", nargs="*", metavar="NAME",
                   help="experiments to run (default: all; `--list` names them)")
    p.add_argument("--quick", action="store_true", help="a few points and one seed per experiment (for CI)")
    p.add_argument("--out", metavar="DIR", default="experiments-out",
                   help="folder for NAME.csv, NAME.png and summary.md (default experiments-out)")
    p.add_argument("--seeds", type=_positive(MAX_SEEDS), default=None, metavar="N",
                   help="seeds per point (default 3, --quick 1)")
    p.add_argument("--jobs", type=_positive(MAX_JOBS), default=1, metavar="N",
                   help="worker processes (default 1)")
    p.add_argument("--cache", metavar="DIR", default=None,
                   help="render cache (default DIR/.cache; 'none' renders every time)")
    p.add_argument("--list", action="store_true", help="list the experiments and exit")
    p.add_argument("--report", action="store_true",
                   help="measure nothing: redraw NAME.png and summary.md from the CSVs already in --out")


def _task(name: str, value, seed: int, quick: bool, cache_dir):
    """One point and seed in a worker: (row, cache hits, misses, error text or None)."""
    from receiver.core.budget import limit_blas_threads
    limit_blas_threads(1)
    import cv2
    cv2.setNumThreads(1)
    from tools.experiments.cache import Cache
    from tools.experiments.registry import all_experiments

    exp = all_experiments()[name]
    cache = Cache(cache_dir)
    try:
        row = exp.measure(value, seed, quick, cache)
        err = None
    except Exception as e:  # a point that crashes is reported, the others still run
        row, err = {}, f"{type(e).__name__}: {e}"
    return {exp.param: value, "seed": seed, **row}, cache.hits, cache.misses, err


def _report(args, exps, names) -> int:
    """--report: NAME.png and summary.md again from DIR/NAME.csv (e.g. after a change of a
    summary text or plot), with the commands recorded when the CSVs were made."""
    import json
    from receiver.core.errors import InputError
    from tools.experiments import report
    from tools.experiments.cache import Cache

    out = args.out
    try:
        with open(os.path.join(out, ".commands.json"), encoding="utf-8") as f:
            commands = json.load(f)
    except (OSError, ValueError):
        raise InputError(f"--report: no experiments run into {out} yet") from None
    cache_dir = None if args.cache == "none" else (args.cache or os.path.join(out, ".cache"))
    results = []
    for n in (args.names or list(exps)):
        path = os.path.join(out, f"{n}.csv")
        if n not in commands or not os.path.exists(path):
            continue
        rows = report.read_csv(path)
        n_seeds = len({r["seed"] for r in rows})
        quick = "--quick" in commands[n].split()
        report.write_png(os.path.join(out, f"{n}.png"), exps[n], rows, n_seeds, cache=Cache(cache_dir), quick=quick)
        results.append((exps[n], rows, exps[n].summarize(rows)))
    if not results:
        raise InputError(f"--report: no CSV of {', '.join(names)} in {out}")
    done = {e.name for e, _, _ in results}
    for n, exp in exps.items():
        path = os.path.join(out, f"{n}.csv")
        if n not in done and n in commands and os.path.exists(path):
            rows = report.read_csv(path)
            results.append((exp, rows, exp.summarize(rows)))
    order = list(exps)
    results.sort(key=lambda r: order.index(r[0].name))
    report.write_summary(os.path.join(out, "summary.md"), results, commands)
    print(f"occloc experiments: redrew {len(done)} PNG and summary.md in {out}", file=sys.stderr)
    return 0


def main(args) -> int:
    from receiver.core.errors import InputError
    from tools.experiments.registry import all_experiments
    from tools.experiments import report
    from tools.experiments.cache import Cache

    exps = all_experiments()
    if args.list:
        for exp in exps.values():
            print(f"{exp.name:14s} {exp.figure:22s} {exp.title}")
        return 0
    names = args.names or list(exps)
    unknown = [n for n in names if n not in exps]
    if unknown:
        raise InputError(f"unknown experiment {', '.join(unknown)} (choose from {', '.join(exps)})")
    names = list(dict.fromkeys(names))
    n_seeds = args.seeds or (1 if args.quick else 3)
    if args.report:
        return _report(args, exps, names)
    out = args.out
    if os.path.exists(out) and not os.path.isdir(out):
        raise InputError(f"--out {out}: not a folder")
    os.makedirs(out, exist_ok=True)
    cache_dir = None if args.cache == "none" else (args.cache or os.path.join(out, ".cache"))
    tasks = [(n, v, s) for n in names for v in (exps[n].quick_points if args.quick else exps[n].points)
             for s in range(n_seeds)]
    rows = {n: [] for n in names}
    errors = []
    t0 = time.monotonic()
    done = {"n": 0, "hits": 0, "misses": 0}

    left = {n: sum(1 for t in tasks if t[0] == n) for n in names}

    def finish(name, value, seed, result):
        row, hits, misses, err = result
        rows[name].append(row)
        left[name] -= 1
        if left[name] == 0:  # its files as soon as it is complete: a long run stopped early keeps them
            write_files(name)
        done["n"] += 1
        done["hits"] += hits
        done["misses"] += misses
        note = f" FAILED: {err}" if err else ""
        if err:
            errors.append(f"{name} {exps[name].param}={value} seed {seed}: {err}")
        print(f"[{done['n']}/{len(tasks)}] {name} {exps[name].param}={value:g} seed {seed} "
              f"({time.monotonic() - t0:.0f} s){note}", file=sys.stderr, flush=True)

    def write_files(n):
        exp = exps[n]
        rs = sorted(rows[n], key=lambda r: (r[exp.param], r["seed"]))
        report.write_csv(os.path.join(out, f"{n}.csv"), exp, rs)
        report.write_png(os.path.join(out, f"{n}.png"), exp, rs, n_seeds, cache=Cache(cache_dir), quick=args.quick)
        results.append((exp, rs, exp.summarize(rs)))
        report.record_commands(out, [n], command)

    command = "occloc experiments " + " ".join(
        (["--quick"] if args.quick else []) + [f"--seeds {n_seeds}", f"--jobs {args.jobs}"] + (args.names or []))
    results = []
    print(f"occloc experiments: {len(names)} experiments, {len(tasks)} points x seeds, {args.jobs} jobs, "
          f"cache {cache_dir or 'off'}", file=sys.stderr, flush=True)
    if args.jobs == 1:
        for n, v, s in tasks:
            finish(n, v, s, _task(n, v, s, args.quick, cache_dir))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futs = {pool.submit(_task, n, v, s, args.quick, cache_dir): (n, v, s) for n, v, s in tasks}
            for f in as_completed(futs):
                finish(*futs[f], f.result())
    commands = report.record_commands(out, [], command)
    # Experiments of earlier runs into the same folder stay in the summary (read back from their CSV).
    for n, exp in exps.items():
        path = os.path.join(out, f"{n}.csv")
        if n not in names and n in commands and os.path.exists(path):
            rs = report.read_csv(path)
            results.append((exp, rs, exp.summarize(rs)))
    order = list(exps)
    results.sort(key=lambda r: order.index(r[0].name))
    report.write_summary(os.path.join(out, "summary.md"), results, commands)
    print(f"occloc experiments: wrote {len(names)} CSV/PNG and summary.md to {out} in "
          f"{time.monotonic() - t0:.0f} s; renders cached {done['hits']}, made {done['misses']}"
          + (f"; {len(errors)} points failed" if errors else ""), file=sys.stderr)
    return 1 if errors else 0
