"""Seeded Monte Carlo of packets pieced together over frames by a group of lights that measure
each frame's start jitter for one another (receiver.decode.pieces: `FrameJitter` shared by the
`OokDecoder`s of one chip rate), with exactly integrated row profiles (tests/signals.py).

Each trial films `lights` small lights at once (each its own random stream phase and crystal
error of up to +-50 ppm, its image drifting up or down the frame) through one rolling shutter
whose frame starts jitter by `jitter_us` rms around their timestamps. The map's IDs are the
candidates; a share `outside` of the lights sends an ID that is not among them (an unmapped
light: any ID it gets is wrong). Every ID a decoder reports is recorded: one that is not the
ID its light sends is a false accept; the share of mapped lights decoded is the ID rate.

With `near` k > 0 every light is also given, every frame, k map IDs as the tracked pose would
give them (receiver.locate.map_prior; `PieceAssembler.decide`'s `near`): its own ID and k - 1
others, or, for a share `near_wrong` of the mapped lights and for every unmapped one, k map IDs
that are not its own (the pose is wrong, or the light is not in the map): any ID then given is
wrong. With `twins`, the first of those wrong IDs is a twin of the light's (an ID whose 24 bits
differ from the light's in the code's least 4), added to the map: the hardest wrong candidate.

Run as a script for the full table (`python tests/decode/pieces_mc.py --help`); the tests in
test_ook_pieces.py run small versions of the same scenes.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FPS = 30.0
PPM = 50.0


@dataclass(frozen=True)
class Scene:
    """Chip rate, sensor row time, exposure, image height (rows), pixel noise (gray levels),
    frame-start jitter (us rms), lights in view, map size (candidates) and the share of lights
    outside the map."""

    name: str
    rate_hz: float
    row_us: float
    exposure_us: float
    n_rows: int
    noise: float = 2.0
    jitter_us: float = 100.0
    lights: int = 5
    candidates: int = 60
    outside: float = 0.4


SCENES = (
    Scene("10k-100rows", 10000.0, 10.0, 10.0, 100),
    Scene("10k-100rows-noisy", 10000.0, 10.0, 10.0, 100, noise=12.0),
    Scene("10k-70rows-200us", 10000.0, 10.0, 10.0, 70, jitter_us=200.0),
    Scene("5k-120rows", 5000.0, 10.0, 10.0, 120),
    Scene("5k-120rows-noisy", 5000.0, 10.0, 10.0, 120, noise=12.0, candidates=300),
    Scene("10k-100rows-unmapped", 10000.0, 10.0, 10.0, 100, outside=1.0),
    Scene("5k-120rows-unmapped", 5000.0, 10.0, 10.0, 120, outside=1.0, candidates=300),
    Scene("20k-20us-110rows", 20000.0, 10.0, 20.0, 110, noise=8.0, candidates=100),
    Scene("20k-56us-110rows", 20000.0, 10.0, 56.0, 110, noise=8.0, candidates=100),
    Scene("20k-87us-140rows", 20000.0, 10.0, 87.0, 140, noise=8.0, candidates=100),
    Scene("20k-20us-110rows-unmapped", 20000.0, 10.0, 20.0, 110, noise=8.0, outside=1.0, candidates=300),
    Scene("20k-56us-110rows-unmapped", 20000.0, 10.0, 56.0, 110, noise=8.0, outside=1.0, candidates=300),
    Scene("20k-87us-140rows-unmapped", 20000.0, 10.0, 87.0, 140, noise=8.0, outside=1.0, candidates=300),
)
BY_NAME = {s.name: s for s in SCENES}


def twin_of(led_id: int, rng: np.random.Generator) -> int:
    """A random ID whose 24 bits (16 ID + CRC-8) differ from `led_id`'s in the code's least
    number of bits (a linear code: led_id XOR a least-weight codeword)."""
    from firmware_tx.crc import crc8
    from receiver.decode.pieces import CRC_MIN_DISTANCE_BITS

    global _LEAST
    if _LEAST is None:
        ids = np.arange(1, 1 << 16)
        words = (ids << 8) | np.array([crc8(int(i), 16) for i in ids])
        _LEAST = ids[np.array([bin(int(w)).count("1") for w in words]) == CRC_MIN_DISTANCE_BITS]
    return int(led_id) ^ int(rng.choice(_LEAST))


_LEAST = None


def trial(scene: Scene, rng: np.random.Generator, frames: int, margins: list | None = None, near: int = 0,
          near_wrong: float = 0.0, twins: bool = False, **overrides) -> list[tuple[int, bool, int | None, int]]:
    """Per light: (ID sent, in the map, first ID reported or None, frames fed until then).
    `margins`: a list to append every decision of a light without an ID to: (mean correlation,
    gap, best ID is the one sent, share of the pieces placed by the other lights' jitter, and
    against the weakest rival the agreement and evidence in sds, nan when not tested).
    `near`, `near_wrong`, `twins`: the map IDs each light is given as the pose's (module
    docstring).
    `overrides`: OokSettings fields for the decoders."""
    from firmware_tx.schedule import make_schedule
    from receiver.decode.ook import OokDecoder
    from receiver.decode.pieces import FrameJitter
    from signals import pin_waveform, row_profile

    cands = rng.choice(1 << 16, scene.candidates, replace=False)
    inside = set(int(c) for c in cands)
    jitter = FrameJitter()
    lights = []
    grng = np.random.default_rng(int(rng.integers(1 << 62))) if near else None  # the gates' own draws
    for i in range(scene.lights):
        mapped = rng.uniform() >= scene.outside
        if mapped:
            led_id = int(cands[rng.integers(scene.candidates)])
        else:
            led_id = int(rng.integers(1 << 16))
            while led_id in inside:
                led_id = int(rng.integers(1 << 16))
        gate = ()
        if near:
            right = mapped and grng.uniform() >= near_wrong
            others = [int(c) for c in cands[:scene.candidates] if int(c) != led_id]
            gate = tuple(int(v) for v in grng.choice(others, near - right, replace=False))
            if not right and twins:
                tw = twin_of(led_id, grng)
                if tw not in inside:
                    inside.add(tw)
                    cands = np.append(cands, tw)
                gate = (tw,) + gate[1:]
            gate = ((led_id,) + gate) if right else gate
        sch = make_schedule("ook", led_id, int(scene.rate_hz))
        wave = pin_waveform(sch, 0)
        lights.append(dict(id=led_id, mapped=mapped, near=gate, wave=wave, tick=sch.tick_hz,
                           phase=rng.uniform(0.0, len(wave) / sch.tick_hz),
                           scale=1.0 + rng.uniform(-PPM, PPM) * 1e-6,
                           y=rng.uniform(50, 600), vy=rng.uniform(-4.0, 4.0), got=None, k=frames))
    for lt in lights:  # (the map as the twins left it)
        lt["dec"] = OokDecoder(scene.rate_hz, scene.row_us, scene.exposure_us, candidates=cands, frame_jitter=jitter,
                               **overrides)
    for k in range(frames):
        t_true = k / FPS + rng.normal(0.0, scene.jitter_us * 1e-6)
        for lt in lights:
            y0 = int(lt["y"] + lt["vy"] * k)
            t0 = (t_true + y0 * scene.row_us * 1e-6) * lt["scale"] + lt["phase"]
            prof, w = row_profile(lt["wave"], lt["tick"], scene.row_us, scene.exposure_us, scene.n_rows, t0,
                                  noise=scene.noise, rng=rng)
            got = lt["dec"].step(prof, w, k / FPS, y0=y0, near=lt["near"]).led_id
            pa = lt["dec"].pieces
            if margins is not None and got is None and pa.ll is not None and pa.best_id is not None:
                margins.append((pa.score, pa.gap, pa.best_id == lt["id"], pa.timed / max(len(pa.pieces), 1),
                                pa.agree, pa.z))
                pa.best_id = None  # (recorded once per decision)
            if got is not None and lt["got"] is None:
                lt["got"], lt["k"] = got, k + 1
    return [(lt["id"], lt["mapped"], lt["got"], lt["k"]) for lt in lights]


def monte_carlo(scene: Scene, trials: int, seed: int, frames: int = 60, margins: list | None = None,
                near: int = 0, near_wrong: float = 0.0, twins: bool = False, **overrides) -> dict:
    """Counts over `trials` seeded trials: mapped lights, right first IDs, the wrong ones
    (sent, reported, frame) and the median frames to a right ID (`margins`: see `trial`)."""
    rng = np.random.default_rng(seed)
    mapped, right, wrong, when = 0, 0, [], []
    for _ in range(trials):
        for sent, inside, got, k in trial(scene, rng, frames, margins, near, near_wrong, twins, **overrides):
            mapped += inside
            if got == sent:
                right += 1
                when.append(k)
            elif got is not None:
                wrong.append((sent, got, k))
    return {"lights": trials * scene.lights, "mapped": mapped, "right": right, "wrong": wrong,
            "median_frames": float(np.median(when)) if when else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", help=f"scene names (default all): {', '.join(BY_NAME)}")
    ap.add_argument("--trials", type=int, default=40, help="trials per scene [40]")
    ap.add_argument("--seed", type=int, default=1, help="random seed [1]")
    ap.add_argument("--frames", type=int, default=60, help="frames per trial [60]")
    ap.add_argument("--margins", action="store_true",
                    help="also, among the decisions of lights without an ID that reached the test against the "
                         "rivals, the largest evidence of a wrong best ID with the accepted agreement")
    ap.add_argument("--near", type=int, default=0, metavar="K",
                    help="give every light K map IDs as the pose's (module docstring) [0: none]")
    ap.add_argument("--near-wrong", type=float, default=0.0, metavar="P",
                    help="share of the mapped lights whose K IDs are all others' [0]")
    ap.add_argument("--twins", action="store_true", help="a wrong set of IDs holds a twin of the light's")
    a = ap.parse_args(argv)
    from receiver.decode.settings import OOK_TUNING
    bad = [n for n in a.scenes if n not in BY_NAME]
    if bad:
        print(f"pieces_mc: unknown scene {bad[0]!r} (known: {', '.join(BY_NAME)})", file=sys.stderr)
        return 1
    print("| scene | lights (mapped) | right IDs | wrong IDs | median frames to the ID |")
    print("|---|---|---|---|---|")
    for name in a.scenes or list(BY_NAME):
        margins = [] if a.margins else None
        r = monte_carlo(BY_NAME[name], a.trials, a.seed, a.frames, margins, a.near, a.near_wrong, a.twins)
        pct = 100.0 * r["right"] / r["mapped"] if r["mapped"] else 0.0
        print(f"| {name} | {r['lights']} ({r['mapped']}) | {r['right']} ({pct:.1f} % of mapped) | {len(r['wrong'])} | "
              f"{r['median_frames']} |", flush=True)
        for sent, got, k in r["wrong"]:
            print(f"  wrong: {sent:#06x} reported as {got:#06x} at frame {k}", file=sys.stderr)
        if margins:
            m = np.array(margins, float)
            k = OOK_TUNING
            tested = m[~np.isnan(m[:, 4])]
            for right, what in ((0, "wrong"), (1, "right")):
                v = tested[tested[:, 2] == right]
                agree = v[:, 4] >= k.pieces_min_agree
                z_max = v[agree, 5].max() if agree.any() else float("nan")
                passed = int((agree & (v[:, 5] >= k.pieces_min_z)).sum())
                print(f"    {what}-best decisions tested against their rivals: {len(v)}; agreement >= "
                      f"{k.pieces_min_agree}: {int(agree.sum())}, their largest evidence {z_max:.2f} sds; "
                      f"passed: {passed}", flush=True)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/ (signals)
    sys.exit(main())
