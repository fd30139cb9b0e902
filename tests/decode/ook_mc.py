"""Seeded Monte Carlo of the OOK decoder's first reported ID on lights that show few chips a
frame (the hard case for packet assembly: short frames chained by alignment, or pieces placed
by the frame times), with exactly integrated row profiles (tests/signals.py).

Each trial draws a random 16-bit ID and a random stream phase, feeds one fresh `OokDecoder`
up to `frames` frames, and records the first ID it reports (and when). A wrong first ID is a
false accept; the share of trials with the right ID is the ID rate.

Run as a script for the full table (`python tests/decode/ook_mc.py --help`); the tests in
test_ook_false_accepts.py run small versions of the same scenes.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FPS = 30.0


@dataclass(frozen=True)
class Scene:
    """One kind of light: chip rate, sensor row time, exposure, image height (rows), pixel
    noise (gray levels), and whether frames carry timestamps and image rows with the map's
    IDs as candidates (the pieces path) with `jitter_us` rms frame-start jitter."""

    name: str
    rate_hz: float
    row_us: float
    exposure_us: float
    n_rows: int
    noise: float = 8.0
    candidates: int = 0
    jitter_us: float = 100.0


SCENES = (
    Scene("20k-40us-60rows", 20000.0, 15.0, 40.0, 60),
    Scene("20k-56us-60rows", 20000.0, 15.0, 56.0, 60),
    Scene("20k-80us-60rows", 20000.0, 15.0, 80.0, 60),
    Scene("20k-60us-120rows", 20000.0, 15.0, 60.0, 120),
    Scene("10k-10us-130rows", 10000.0, 10.0, 10.0, 130, noise=2.0),
    Scene("10k-56us-130rows", 10000.0, 10.0, 56.0, 130, noise=2.0),
    Scene("10k-10us-100rows-map", 10000.0, 10.0, 10.0, 100, noise=2.0, candidates=60),
    Scene("20k-56us-110rows-map", 20000.0, 10.0, 56.0, 110, candidates=100),
    Scene("20k-87us-140rows-map", 20000.0, 10.0, 87.0, 140, candidates=100),
)
BY_NAME = {s.name: s for s in SCENES}


def trial(scene: Scene, rng: np.random.Generator, frames: int, **overrides) -> tuple[int, int | None, int]:
    """(ID sent, first ID reported or None, frames fed until then); `overrides`: OokSettings
    fields for the decoder."""
    from firmware_tx.schedule import make_schedule
    from receiver.decode.ook import OokDecoder
    from signals import pin_waveform, row_profile

    cands = None
    if scene.candidates:
        cands = rng.choice(1 << 16, scene.candidates, replace=False)
        led_id = int(cands[rng.integers(scene.candidates)])
    else:
        led_id = int(rng.integers(0, 1 << 16))
    sch = make_schedule("ook", led_id, int(scene.rate_hz))
    wave = pin_waveform(sch, 0)
    period_s = len(wave) / sch.tick_hz
    phase = rng.uniform(0.0, period_s)
    dec = OokDecoder(scene.rate_hz, scene.row_us, scene.exposure_us, candidates=cands, **overrides)
    for k in range(frames):
        if scene.candidates:  # the frame times place the pieces: a continuous stream
            y0 = 300 + int(10 * np.sin(k / 7.0))
            t0 = phase + k / FPS + rng.normal(0.0, scene.jitter_us * 1e-6) + y0 * scene.row_us * 1e-6
        else:  # any phase each frame (a camera whose frame rate is no multiple of the packet)
            y0, t0 = None, rng.uniform(0.0, period_s)
        prof, w = row_profile(wave, sch.tick_hz, scene.row_us, scene.exposure_us, scene.n_rows, t0,
                              noise=scene.noise, rng=rng)
        got = dec.step(prof, w, k / FPS if scene.candidates else None, y0=y0).led_id
        if got is not None:
            return led_id, got, k + 1
    return led_id, None, frames


def monte_carlo(scene: Scene, trials: int, seed: int, frames: int = 60, **overrides) -> dict:
    """Counts of right and wrong first IDs over `trials` seeded trials, with the wrong ones
    (sent, reported, frame) and the median frames to a right ID."""
    rng = np.random.default_rng(seed)
    right, wrong, when = 0, [], []
    for _ in range(trials):
        sent, got, k = trial(scene, rng, frames, **overrides)
        if got == sent:
            right += 1
            when.append(k)
        elif got is not None:
            wrong.append((sent, got, k))
    return {"trials": trials, "right": right, "wrong": wrong,
            "median_frames": float(np.median(when)) if when else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", help=f"scene names (default all): {', '.join(BY_NAME)}")
    ap.add_argument("--trials", type=int, default=320, help="trials per scene [320]")
    ap.add_argument("--seed", type=int, default=1, help="random seed [1]")
    ap.add_argument("--frames", type=int, default=60, help="frames per trial [60]")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="an OokSettings or OokTuning field for the decoders, e.g. confirm_max_chips=0 (no confirmation)")
    a = ap.parse_args(argv)
    from receiver.decode.settings import OOK_TUNING, OokSettings, OokTuning

    overrides, tuning = {}, {}
    for item in a.set:
        name, _, value = item.partition("=")
        default = getattr(OokSettings(), name, getattr(OOK_TUNING, name, None))
        if default is None or not value:
            print(f"ook_mc: --set {item!r}: not NAME=VALUE of an OokSettings or OokTuning field", file=sys.stderr)
            return 1
        try:
            (overrides if hasattr(OokSettings, name) else tuning)[name] = type(default)(value)
        except ValueError:
            print(f"ook_mc: --set {item!r}: {value!r} is not a {type(default).__name__}", file=sys.stderr)
            return 1
    if tuning:
        try:
            overrides["tuning"] = OokTuning(**tuning)
        except ValueError as e:
            print(f"ook_mc: --set: {e}", file=sys.stderr)
            return 1
    bad = [n for n in a.scenes if n not in BY_NAME]
    if bad:
        print(f"ook_mc: unknown scene {bad[0]!r} (known: {', '.join(BY_NAME)})", file=sys.stderr)
        return 1
    print("| scene | trials | right IDs | wrong IDs | median frames to the ID |")
    print("|---|---|---|---|---|")
    for name in a.scenes or list(BY_NAME):
        r = monte_carlo(BY_NAME[name], a.trials, a.seed, a.frames, **overrides)
        n = r["trials"]
        print(f"| {name} | {n} | {r['right']} ({100.0 * r['right'] / n:.1f} %) | {len(r['wrong'])} "
              f"({100.0 * len(r['wrong']) / n:.1f} %) | {r['median_frames']} |", flush=True)
        for sent, got, k in r["wrong"]:
            print(f"  wrong: {sent:#06x} reported as {got:#06x} at frame {k}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (signals)
    sys.exit(main())
