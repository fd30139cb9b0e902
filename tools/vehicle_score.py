"""Score the receiver on vehicle recordings, one line each:
`.venv/bin/python -m tools.vehicle_score [FOLDER ...] [--runs DIR] [--jobs N]`.

Per recording folder (video, camera.yaml, map.json, truth.jsonl): `occloc run` writes its JSON
lines to DIR/<name>.jsonl, `occloc eval` scores them, and one line gives what the vehicle
chapter is judged by: street-light and car IDs over resolvable light-frames (`s2psk_resolvable`,
receiver.evaluate.metrics), S2-PSK wrong IDs, frames with a host fix and its median 2D error (m),
the car distance median relative error (%) and bearing median error (deg). Without FOLDER: the
independent recordings (../shared/independent/vehicle-*), recordings/vehicle and the
`vehicle-road` seeds rendered under DIR/road-s1 .. road-s4 (rendered first when missing:
`occloc synth vehicle-road --seed N`). `--truth-shift`: the camera shift from the truth instead
of the receiver's estimate (tools.truth_shift_run); `--settings FILE`: `occloc run`'s settings
file (e.g. `{"receiver": {"pair": {"shake": "motion"}}}`), its runs kept apart by the file's name.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
INDEPENDENT = ROOT.parent / "shared" / "independent"
ROAD_SEEDS = (1, 2, 3, 4)


def _occloc() -> list[str]:
    return [sys.executable, "-m", "receiver.cli"]


def default_folders(runs: Path) -> list[Path]:
    """The independent vehicle recordings, the bundled one and the rendered road seeds."""
    out = sorted(INDEPENDENT.glob("vehicle-*")) if INDEPENDENT.is_dir() else []
    out.append(ROOT / "recordings" / "vehicle")
    out += [runs / f"road-s{s}" for s in ROAD_SEEDS]
    return out


def render_road(folder: Path) -> None:
    """`vehicle-road` with the seed of the folder's name (road-sN), when the folder is missing."""
    if (folder / "truth.jsonl").is_file():
        return
    seed = int(folder.name.rsplit("-s", 1)[1])
    subprocess.run(_occloc() + ["synth", "vehicle-road", "--out", str(folder), "--seed", str(seed)],
                   check=True, cwd=ROOT)


def score(folder: Path, runs: Path, rerun: bool, truth_shift: bool = False, settings: Path | None = None) -> dict:
    """Run (unless its output is there and not `rerun`) and evaluate one recording; with
    `truth_shift`, the camera shift from the truth (tools.truth_shift_run); with `settings`, that
    settings file given to `occloc run`."""
    name = folder.name
    tag = ".truth-shift" if truth_shift else (f".{settings.stem}" if settings is not None else "")
    out = runs / f"{name}{tag}.jsonl"
    if name.startswith("road-s"):
        render_road(folder)
    if rerun or not out.is_file():
        out.unlink(missing_ok=True)
        cmd = ([sys.executable, "-m", "tools.truth_shift_run", str(folder), str(out)] if truth_shift
               else _occloc() + ["run", str(folder), "--out", str(out)]
               + (["--settings", str(settings)] if settings is not None else []))
        subprocess.run(cmd, check=True, cwd=ROOT, stderr=subprocess.DEVNULL)
    res = subprocess.run(_occloc() + ["eval", str(out), "--truth", str(folder / "truth.jsonl"), "--json"],
                         check=True, cwd=ROOT, capture_output=True, text=True)
    m = json.loads(res.stdout)
    return {"name": name, **summary(m)}


def summary(m: dict) -> dict:
    """The judged numbers of one `occloc eval --json` result."""
    r = m.get("s2psk_resolvable") or {}
    v = m.get("vehicle") or {}
    hv = (v.get("hv") or {}).get("filtered") or {}

    def rate(k):
        g = r.get(k) or {}
        return g.get("right", 0), g.get("qualifying", 0)

    return {"sl": rate("SL"), "fv": rate("FV"), "wrong": r.get("wrong_ids"),
            "hv_frames": v.get("frames_with_hv", 0), "hv_m": (hv.get("error_2d_m") or {}).get("p50"),
            "fv_dist_pct": _pct((v.get("fv_distance_rel_error") or {}).get("p50")),
            "fv_bear_deg": (v.get("fv_bearing_error_deg") or {}).get("p50"), "fv_n": v.get("fv_matched", 0)}


def _pct(v):
    return None if v is None else 100.0 * v


def _fmt(v, spec):
    return "-" if v is None else format(v, spec)


def line(s: dict) -> str:
    def rate(rq):
        right, qual = rq
        return f"{right:4d}/{qual:<4d} {_fmt(100.0 * right / qual if qual else None, '5.1f'):>5}%"

    return (f"{s['name']:<18} SL {rate(s['sl'])}  car {rate(s['fv'])}  wrong {s['wrong']}  "
            f"host {s['hv_frames']:3d} fr {_fmt(s['hv_m'], '.2f')} m  "
            f"car dist {_fmt(s['fv_dist_pct'], '.1f')} %  bearing {_fmt(s['fv_bear_deg'], '.2f')} deg "
            f"({s['fv_n']} matched)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="*", help="recording folders (default: see the module docstring)")
    parser.add_argument("--runs", default="/tmp/vehicle_score", help="where runs and rendered road seeds go")
    parser.add_argument("--jobs", type=int, default=1, help="recordings scored at once")
    parser.add_argument("--keep", action="store_true", help="reuse a run's output when it is there")
    parser.add_argument("--truth-shift", action="store_true",
                        help="the frame's camera shift from the truth camera (tools.truth_shift_run): the "
                             "pairing apart from the camera-motion estimate")
    parser.add_argument("--settings", default=None,
                        help="settings file for `occloc run` (not with --truth-shift)")
    args = parser.parse_args(argv)
    settings = Path(args.settings) if args.settings else None
    if settings is not None and (args.truth_shift or not settings.is_file()):
        print(f"tools.vehicle_score: --settings {args.settings}: " +
              ("not with --truth-shift" if args.truth_shift else "no such file"), file=sys.stderr)
        return 2
    runs = Path(args.runs)
    runs.mkdir(parents=True, exist_ok=True)
    folders = [Path(f) for f in args.folders] or default_folders(runs)
    for f in folders:
        if not f.name.startswith("road-s") and not (f / "truth.jsonl").is_file():
            print(f"tools.vehicle_score: {f}: not a recording folder (no truth.jsonl)", file=sys.stderr)
            return 2
    with ThreadPoolExecutor(max(args.jobs, 1)) as ex:
        for s in ex.map(lambda f: score(f, runs, not args.keep, args.truth_shift, settings), folders):
            print(line(s), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
