"""Where in a frame the OOK chips read wrong: `python -m tools.chip_errors REC [REC ...]`.

Runs `occloc run` on each recording folder (default settings) and keeps every OOK frame's soft
chips (`OokDecoder.frame_chips`, stages 1-2 or the exposure model). Each frame of a light that
ends the run with an ID that the recording's truth holds is placed at its best cyclic fit to that
ID's packet; a chip whose sign disagrees with the packet there is a wrong chip. Printed per
recording: the frames, the share that fits its packet with normalised correlation >= 0.9 (the
decoder's `OokTuning.verify_min`), with all chips and without the end chip at each end, and the wrong-chip
rate of the first and last chips of a frame, by distance from the end, and of the chips inside.
Frames fitting below 0.5 (a light's track swapped or a frame misread as a whole) are left out of
the rates.

    .venv/bin/python -m tools.chip_errors ../shared/independent/indoor-grid-s31
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ENDS = 4  # chips from each end whose rates are printed one by one


def fit(soft: np.ndarray, template: np.ndarray) -> tuple[float, np.ndarray]:
    """(best normalised correlation, the packet's chips at that shift) of clipped soft chips."""
    x = np.clip(soft, -1.0, 1.0)
    n = template.size
    pos = (np.arange(n)[:, None] + np.arange(x.size)[None, :]) % n
    den = float(np.abs(x).sum())
    corr = (template[pos] @ x) / den if den > 0 else np.zeros(n)
    s = int(np.argmax(corr))
    return float(corr[s]), template[pos[s]]


def chip_errors(frames: list[tuple[int, np.ndarray]]) -> dict:
    """Figures of the module docstring from (ID, soft chips) of the frames."""
    from receiver.decode.ook import packet_template

    head, tail = np.zeros((2, ENDS)), np.zeros((2, ENDS))
    inner = np.zeros(2)
    fits, fits_inner = [], []
    for led_id, soft in frames:
        t = packet_template(led_id)
        c, at = fit(soft, t)
        fits.append(c)
        fits_inner.append(fit(soft[1:-1], t)[0] if soft.size > 2 else c)
        if c < 0.5 or soft.size < 2 * ENDS + 1:
            continue
        wrong = (at * soft) < 0
        head[0] += wrong[:ENDS]
        tail[0] += wrong[::-1][:ENDS]
        head[1] += 1
        tail[1] += 1
        inner += (wrong[ENDS:-ENDS].sum(), wrong.size - 2 * ENDS)
    f, fi = np.array(fits), np.array(fits_inner)
    return {"frames": int(f.size),
            "fit_share": float((f >= 0.9).mean()) if f.size else None,
            "fit_share_inner": float((fi >= 0.9).mean()) if fi.size else None,
            "head": (head[0] / np.maximum(head[1], 1)).tolist(),
            "tail": (tail[0] / np.maximum(tail[1], 1)).tolist(),
            "inner": float(inner[0] / max(inner[1], 1))}


def collect(folder: Path) -> list[tuple[int, np.ndarray]]:
    """(ID, soft chips) of every frame of the lights that end `occloc run` with an ID the
    recording's truth holds."""
    from receiver.cli import main as cli
    from receiver.decode import ook

    seen: dict[int, tuple[object, list]] = {}
    orig = ook.OokDecoder.frame_chips

    def frame_chips(self, profile, weights=None):
        soft, cw = orig(self, profile, weights)
        if soft.size:
            seen.setdefault(id(self), (self, []))[1].append(np.array(soft))
        return soft, cw

    ook.OokDecoder.frame_chips = frame_chips
    try:
        with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stderr(io.StringIO()):
            rc = cli(["run", str(folder), "--out", str(Path(tmp) / "run.jsonl")])
    finally:
        ook.OokDecoder.frame_chips = orig
    if rc != 0:
        raise RuntimeError(f"occloc run {folder} failed (exit {rc})")
    truth_ids = set()
    with open(folder / "truth.jsonl") as f:
        for line in f:
            for led in json.loads(line).get("leds", []):
                truth_ids.add(int(led["id"]))
    return [(dec.led_id, s) for dec, lst in seen.values() if dec.led_id in truth_ids for s in lst]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.chip_errors", description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="+", metavar="REC", help="recording folders with truth.jsonl")
    args = p.parse_args(argv)
    for name in args.folders:
        folder = Path(name)
        if not (folder / "truth.jsonl").is_file():
            print(f"chip_errors: {folder}: no truth.jsonl", file=sys.stderr)
            return 1
        try:
            r = chip_errors(collect(folder))
        except (OSError, RuntimeError, ValueError, KeyError) as e:
            print(f"chip_errors: {folder}: {e}", file=sys.stderr)
            return 1
        pct = lambda v: " ".join(f"{100 * x:.1f}" for x in v)  # noqa: E731
        share = lambda v: "-" if v is None else f"{100 * v:.1f} %"  # noqa: E731
        print(f"{folder.name}: {r['frames']} frames, fitting {share(r['fit_share'])} "
              f"({share(r['fit_share_inner'])} without the end chips); wrong chips %: "
              f"first {ENDS} [{pct(r['head'])}], last {ENDS} [{pct(r['tail'])}], inside {100 * r['inner']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
