"""Regenerate docs/performance.md from `occloc bench --json` on this machine.

    .venv/bin/python -m tools.perf_page [--frames N] [--runs R] [--instructions] [--scales WxH,...] [--out FILE]

Runs the bench R times (each a fresh process, so the runs see the machine's noise separately),
takes per case the median of the runs' medians and the range of their p99s, and writes a
Markdown page naming the machine, the date and the exact command. With `--instructions` it adds
callgrind's instructions per frame (independent of the machine's load; minutes per case, tens of
minutes for a 4K scene). The page also gives the cost per megapixel of the indoor walk rendered
at each size of `--scales` (`occloc bench --scale WxH --scale-scene indoor-walk`, at most
SCALE_FRAMES frames: they are held in memory), each size's ms per megapixel as a ratio to the
first size's. Progress goes to standard error.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import re
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs" / "performance.md"
BUDGET_MEDIAN_MS = 2.0
BUDGET_P99_MS = 5.0
# The sizes of the per-megapixel table (the first is the reference of the ratios), its scene and
# its frames per run (held in memory: 40 frames of 3840x2160 are 330 MB).
DEFAULT_SCALES = "1280x720,1920x1080,3840x2160"
SCALE_SCENE = "indoor-walk"
SCALE_FRAMES = 40


def machine() -> str:
    """One line naming the CPU, cores and load average."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = " / ".join(f"{v:.1f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    return f"{cpu}, {os.cpu_count()} cores, load average {load}, Python {platform.python_version()}"


def bench(args: list[str]) -> dict:
    cmd = [sys.executable, "-m", "receiver.cli", "bench", "--json", *args]
    out = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def summarise(runs: list[dict]) -> list[dict]:
    """Per case: median of the runs' whole-frame medians, range of their p99s, per-stage medians."""
    cases: dict[str, list[dict]] = {}
    for r in runs:
        for c in r["cases"]:
            cases.setdefault(c["case"], []).append(c)
    rows = []
    for name, cs in cases.items():
        w, h = cs[0]["size"]
        med = statistics.median(c["total"]["median_ms"] for c in cs)
        p99 = [c["total"]["p99_ms"] for c in cs]
        stages = {s: statistics.median(c["stages"][s]["median_ms"] for c in cs) for s in cs[0]["stages"]}
        instr = [c["instructions_per_frame"] for c in cs if c.get("instructions_per_frame")]
        rows.append({"case": name, "size": f"{w}x{h}", "mp": w * h / 1e6, "median_ms": med,
                     "p99_lo": min(p99), "p99_hi": max(p99), "stages": stages,
                     "instr_m": statistics.median(instr) / 1e6 if instr else None})
    return rows


def scale_table(rows: list[dict]) -> list[str]:
    """The per-megapixel table's lines: per size, ms per MP and its ratio to the first size's."""
    if not rows:
        return []
    ref = rows[0]["median_ms"] / rows[0]["mp"]
    out = ["", f"Cost per megapixel: the {SCALE_SCENE} scene rendered at each size (focal length and row time "
           "scaled so each light covers the same angles and chips; `occloc bench --scale WxH --scale-scene "
           f"{SCALE_SCENE}`), whole frame:", "",
           "| size | MP | median ms | p99 ms (range) | ms per MP | ratio to " + rows[0]["size"] +
           " | instructions / frame | M instructions per MP |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        per_mp = r["median_ms"] / r["mp"]
        instr = f"{r['instr_m']:.2f} M" if r["instr_m"] is not None else "-"
        instr_mp = f"{r['instr_m'] / r['mp']:.2f}" if r["instr_m"] is not None else "-"
        out.append(f"| {r['size']} | {r['mp']:.2f} | {r['median_ms']:.2f} | {r['p99_lo']:.2f}-{r['p99_hi']:.2f} | "
                   f"{per_mp:.2f} | {per_mp / ref:.2f} | {instr} | {instr_mp} |")
    return out


def page(rows: list[dict], command: str, n_runs: int, kernels: str, scaled: list[dict] | None = None) -> str:
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    out = ["# Performance", "",
           "Written by `" + command + "`; do not edit by hand.", "",
           f"- When: {now}",
           f"- Machine: {machine()}",
           f"- Kernels: {kernels}",
           f"- Runs: {n_runs} separate processes; per case the median of their whole-frame medians and the "
           "range of their p99s. CPU time of the main thread on one core, frames decoded before timing "
           "(`occloc bench`).",
           f"- Budget: {BUDGET_MEDIAN_MS:g} ms median and {BUDGET_P99_MS:g} ms p99 per whole frame.", "",
           "| case | size | median ms | p99 ms (range) | ms per MP | instructions / frame | within budget |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = r["median_ms"] <= BUDGET_MEDIAN_MS and r["p99_hi"] <= BUDGET_P99_MS
        instr = f"{r['instr_m']:.2f} M" if r["instr_m"] is not None else "-"
        out.append(f"| {r['case']} | {r['size']} | {r['median_ms']:.2f} | {r['p99_lo']:.2f}-{r['p99_hi']:.2f} | "
                   f"{r['median_ms'] / r['mp']:.2f} | {instr} | {'yes' if ok else 'no'} |")
    stages = sorted({s for r in rows for s in r["stages"]}, key=lambda s: list(rows[0]["stages"]).index(s)
                    if s in rows[0]["stages"] else 99)
    out += ["", "Median ms per stage:", "", "| case | " + " | ".join(stages) + " |",
            "|---|" + "---|" * len(stages)]
    for r in rows:
        out.append(f"| {r['case']} | " + " | ".join(
            f"{r['stages'][s]:.3f}" if s in r["stages"] else "-" for s in stages) + " |")
    out += scale_table(scaled or [])
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.perf_page", description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=80, metavar="N", help="frames per case (80)")
    ap.add_argument("--runs", type=int, default=3, metavar="R", help="separate bench runs (3)")
    ap.add_argument("--instructions", action="store_true", help="also count instructions per frame (callgrind)")
    ap.add_argument("--scales", default=DEFAULT_SCALES, metavar="WxH,...",
                    help=f"sizes of the per-megapixel table ({DEFAULT_SCALES}; '' for none)")
    ap.add_argument("--out", default=str(DEFAULT_OUT), metavar="FILE", help="the page (docs/performance.md)")
    a = ap.parse_args(argv)
    if a.frames < 1 or a.runs < 1:
        ap.error("--frames and --runs must be at least 1")
    scales = [v.strip() for v in a.scales.split(",") if v.strip()]
    if any(re.fullmatch(r"[0-9]{1,5}x[0-9]{1,5}", v) is None for v in scales):
        ap.error(f"--scales needs sizes WxH separated by commas (e.g. 1280x720,1920x1080), not {a.scales!r}")
    runs, scaled_runs = [], []
    scale_frames = str(min(a.frames, SCALE_FRAMES))
    for i in range(a.runs):
        print(f"perf_page: bench run {i + 1}/{a.runs}", file=sys.stderr)
        runs.append(bench(["--frames", str(a.frames)]))
        # one run of every size after each bundled run: the sizes see the same machine state
        scaled_runs.append({"cases": [c for size in scales for c in bench(
            ["--frames", scale_frames, "--scale", size, "--scale-scene", SCALE_SCENE])["cases"]]})
    if a.instructions:
        print("perf_page: instructions (callgrind)", file=sys.stderr)
        counted = bench(["--frames", str(a.frames), "--instructions"])["cases"]
        counted += [c for size in scales for c in bench(
            ["--frames", scale_frames, "--scale", size, "--scale-scene", SCALE_SCENE, "--instructions",
             "--instr-frames", "3"])["cases"]]
        by_case = {c["case"]: c.get("instructions_per_frame") for c in counted}
        for r in runs + scaled_runs:
            for c in r["cases"]:
                c["instructions_per_frame"] = by_case.get(c["case"])
    cmd = "python -m tools.perf_page" + (f" --frames {a.frames}" if a.frames != 80 else "") + \
        (f" --runs {a.runs}" if a.runs != 3 else "") + (" --instructions" if a.instructions else "") + \
        (f" --scales {a.scales}" if a.scales != DEFAULT_SCALES else "")
    text = page(summarise(runs), cmd, a.runs, runs[0].get("kernels", "?"),
                summarise(scaled_runs) if scales else None)
    Path(a.out).write_text(text)
    print(f"perf_page: wrote {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
