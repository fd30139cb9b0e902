"""Indoor reception scored the way a phone user would see it: `python -m tools.indoor_score`.

Each scene is a recording folder with truth: the independent recordings in
`../shared/independent/indoor-*` and held-out renders of our synthetic camera (`tools.synth`,
seeds that no test and no bundled recording uses). Every scene is run through `occloc run`
with its own camera.yaml and map.json and default settings, and scored against its truth:

- IDs: correct IDs in % of the LED-frames matched to a visible truth LED (`occloc eval`'s
  ID rate, all frames), and the wrong IDs (must be 0);
- frames with a position: among the frames from one second after the first frame on (the
  receiver's start, packet assembly and first fix are given that second);
- median / p95 of the filtered position error (cm) over those frames;
- distance median: the median relative error (%) of the per-LED distances, all frames.

    .venv/bin/python -m tools.indoor_score                         # every scene, table on stdout
    .venv/bin/python -m tools.indoor_score --write docs/indoor-score.md
    .venv/bin/python -m tools.indoor_score grid-phone-30us --work /tmp/indoor-score

Renders are cached in `--work` (default `$TMPDIR/occloc-indoor-score`), one folder per scene,
and reused while their specification is unchanged (a render takes minutes).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
INDEPENDENT = ROOT.parent / "shared" / "independent"
# Frames before this time after the first frame are not asked for a position (the start).
SKIP_S = 1.0

# The grid: 0.2 m square panels every 0.8 m (a ceiling like the independent indoor-grid's),
# filmed by the phone camera of `indoor-phone` (1100 px focal, 10 us rows) walking and tilting
# by up to ~19 degrees (`indoor_walk` swings pitch by tilt_deg and roll by 0.8 tilt_deg).
GRID = dict(panel_size_m=(0.2, 0.2), pitch_x_m=0.8, pitch_y_m=0.8, tilt_deg=15.0, focal_px=1100.0,
            pixel_size_um=1.4, row_readout_us=10.0)


@dataclass(frozen=True)
class ScoreScene:
    """One scored scene: an existing recording folder (`folder`) or a render (`synth` scene
    name, `seed`, `--set` values `sets`, `codec`)."""
    name: str
    what: str
    folder: str | None = None
    synth: str | None = None
    seed: int = 0
    sets: dict = field(default_factory=dict)
    codec: str = "h264"
    frames: int = 90

    def spec(self) -> dict:
        return {"synth": self.synth, "seed": self.seed, "sets": {k: repr(v) for k, v in sorted(self.sets.items())},
                "codec": self.codec, "frames": self.frames}


def _grid(name, what, seed, **sets):
    return ScoreScene(name, what, synth="indoor-walk", seed=seed, sets={**GRID, **sets})


def _sparse(name, what, seed, **sets):
    return ScoreScene(name, what, synth="indoor-phone", seed=seed, sets=sets)


SCENES = (
    ScoreScene("indep-grid-s31", "independent: grid, every effect, 87 us", folder="indoor-grid-s31"),
    ScoreScene("indep-sparse-s32", "independent: sparse, every effect, 20 us", folder="indoor-sparse-s32"),
    _grid("grid-ideal-10us", "grid, no camera effects, 10 us", 61, phone=0, exposure_us=10.0),
    _grid("grid-phone-10us", "grid, every effect, 10 us", 61, phone=1, exposure_us=10.0),
    _grid("grid-phone-30us", "grid, every effect, 30 us", 61, phone=1, exposure_us=30.0),
    _grid("grid-phone-56us", "grid, every effect, 56 us", 61, phone=1, exposure_us=56.0),
    _grid("grid-phone-95us", "grid, every effect, 95 us", 61, phone=1, exposure_us=95.0),
    _grid("grid-ideal-10khz", "grid, no camera effects, 10 kHz chips, 10 us", 62, phone=0, exposure_us=10.0,
          rate_hz=10000),
    _grid("grid-ideal-5khz", "grid, no camera effects, 5 kHz chips, 10 us", 62, phone=0, exposure_us=10.0,
          rate_hz=5000),
    _sparse("sparse-ideal-10us", "sparse tilted, no camera effects, 10 us", 63, phone=0, exposure_us=10.0),
    _sparse("sparse-phone-10us", "sparse tilted, every effect, 10 us", 63, phone=1, exposure_us=10.0),
    _sparse("sparse-phone-30us", "sparse tilted, every effect, 30 us", 63, phone=1, exposure_us=30.0),
    _sparse("sparse-phone-95us", "sparse tilted, every effect, 95 us", 63, phone=1, exposure_us=95.0),
)
BY_NAME = {s.name: s for s in SCENES}


def score(run: list[dict], truth: dict[int, dict], *, skip_s: float = SKIP_S) -> dict:
    """The scene's figures (module docstring) from `load_run` / `load_truth` records: ids_pct,
    wrong_ids, matched, position_frames, scored_frames, position_p50_cm, position_p95_cm,
    distance_p50_pct (None where undefined)."""
    from receiver.evaluate.metrics import evaluate

    metrics, series = evaluate(run, truth)
    t = np.array([truth[fr["frame"]]["t"] if truth[fr["frame"]]["t"] is not None else math.nan
                  for fr in run], float)
    if not np.isfinite(t).all():
        t = series["t_s"]
    late = t >= (t[0] + skip_s - 1e-9) if t.size else np.zeros(0, bool)
    err = series["filtered_err_m"][late]
    have = err[np.isfinite(err)]
    dist = metrics["distance_rel_error"]
    return {"ids_pct": None if metrics["id_rate"] is None else 100.0 * metrics["id_rate"],
            "wrong_ids": metrics["wrong_ids"], "matched": metrics["matched_led_frames"],
            "position_frames": int(have.size), "scored_frames": int(late.sum()),
            "position_p50_cm": float(np.percentile(have, 50)) * 100 if have.size else None,
            "position_p95_cm": float(np.percentile(have, 95)) * 100 if have.size else None,
            "distance_p50_pct": None if dist.get("p50") is None else 100.0 * dist["p50"]}


def _render(scene: ScoreScene, work: Path) -> Path:
    """The scene's recording folder, rendered into `work` unless an identical render is there."""
    if scene.folder is not None:
        folder = INDEPENDENT / scene.folder
        if not (folder / "truth.jsonl").is_file():
            raise FileNotFoundError(f"{folder}: no such recording (the independent set sits beside the repository)")
        return folder
    from tools.synth.recording import write_recording
    from tools.synth.scenes import make_scene

    folder = work / scene.name
    stamp = folder / "score-spec.json"
    if stamp.is_file() and json.loads(stamp.read_text()) == scene.spec():
        return folder
    if folder.exists():
        if not stamp.is_file():   # not a render of this tool: never deleted
            raise FileExistsError(f"{folder} exists and is not a render of tools.indoor_score: give another --work")
        shutil.rmtree(folder)
    built = make_scene(scene.synth, seed=scene.seed, n_frames=scene.frames, **scene.sets)
    with contextlib.redirect_stderr(io.StringIO()):
        write_recording(built, str(folder), seed=scene.seed, codec=scene.codec)
    stamp.write_text(json.dumps(scene.spec()))
    return folder


def run_scene(scene: ScoreScene, work: Path) -> dict:
    """`occloc run` on the scene's recording (in this process) and `score` of its output."""
    from receiver.cli import main as cli
    from receiver.io.truth import load_run, load_truth

    folder = _render(scene, work)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run.jsonl"
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            rc = cli(["run", str(folder), "--out", str(out)])
        if rc != 0:
            raise RuntimeError(f"occloc run {folder} failed (exit {rc}): {err.getvalue().strip()[-300:]}")
        truth = load_truth(str(folder / "truth.jsonl"))
        return score(load_run(str(out), truth), truth)


def _f(v, nd=2, unit="") -> str:
    return "-" if v is None else f"{v:.{nd}f}{unit}"


def table(rows: list[tuple[ScoreScene, dict]]) -> str:
    """Markdown table of the scored scenes."""
    lines = ["| scene | what | IDs | wrong IDs | frames with a position (after 1 s) | median / p95 | distance median |",
             "|---|---|---|---|---|---|---|"]
    for sc, r in rows:
        lines.append(f"| {sc.name} | {sc.what} | {_f(r['ids_pct'], 1, ' %')} of {r['matched']} | {r['wrong_ids']} | "
                     f"{r['position_frames']}/{r['scored_frames']} | {_f(r['position_p50_cm'])} / "
                     f"{_f(r['position_p95_cm'])} cm | {_f(r['distance_p50_pct'], 3, ' %')} |")
    return "\n".join(lines) + "\n"


PAGE_HEAD = """# Indoor reception scored as a phone sees it

Regenerate with `.venv/bin/python -m tools.indoor_score --write docs/indoor-score.md` (renders
are cached in `--work`; a render takes a few minutes). `tools/indoor_score.py` says how each
figure is taken: IDs in % of the LED-frames matched to a visible truth LED (all frames), wrong
IDs, frames with a position among those from one second on, the filtered position error's
median / p95 over those frames, and the median relative distance error.

Scenes: `indep-*` are the independent recordings (`../shared/independent/`); the others are
renders of `tools.synth` on seeds no test uses: `grid-*` 0.2 m square panels every 0.8 m
(`indoor-walk`, phone tilted up to ~19 degrees), `sparse-*` the tilted phone under one or two
0.25 m panels (`indoor-phone`, 15-35 degrees); "every effect" is the drawn phone of
`tools/synth/phone.py` (lens distortion, blur and glare, vignetting, noise, bloom, bezel, tone
curve, sharpening, in-frame motion, frame-time jitter), H.264 at 8 Mbit/s throughout.

"""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.indoor_score", description=__doc__.split("\n\n")[0])
    p.add_argument("names", nargs="*", metavar="SCENE", help=f"scenes (default all: {', '.join(BY_NAME)})")
    p.add_argument("--work", default=os.path.join(tempfile.gettempdir(), "occloc-indoor-score"),
                   help="folder for the renders (kept and reused)")
    p.add_argument("--write", metavar="PAGE.md", help="write the page (head and table) to this file")
    args = p.parse_args(argv)
    from receiver.core.errors import InputError

    unknown = [n for n in args.names if n not in BY_NAME]
    if unknown:
        p.error(f"unknown scene {', '.join(unknown)} (choose from {', '.join(BY_NAME)})")
    work = Path(args.work)
    try:
        work.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(f"indoor_score: --work {work}: {e.strerror or e}", file=sys.stderr)
        return 1
    rows = []
    for name in args.names or list(BY_NAME):
        sc = BY_NAME[name]
        try:
            r = run_scene(sc, work)
        except (OSError, RuntimeError, InputError) as e:  # (FileNotFoundError is an OSError)
            print(f"indoor_score: {name}: {e}", file=sys.stderr)
            return 1
        print(f"indoor_score: {name}: {json.dumps(r)}", file=sys.stderr)
        rows.append((sc, r))
    text = table(rows)
    if args.write:
        Path(args.write).write_text(PAGE_HEAD + text)
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
