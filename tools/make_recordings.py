"""Regenerate the bundled recordings bit-exactly: `.venv/bin/python -m tools.make_recordings`.

Each recording is a scene of `tools.synth.scenes` rendered with a fixed seed and FFV1; the
table below is the whole recipe.
"""

from __future__ import annotations

import argparse
import os
import sys

from tools.synth.recording import write_recording
from tools.synth.scenes import make_scene

ROOT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "recordings")

# name -> (scene, seed, frames or None for the scene's default)
RECORDINGS = {
    "indoor-walk": ("indoor-walk", 1, 54),
    "indoor-static": ("indoor-static", 1, 30),
    "indoor-sparse": ("indoor-sparse", 1, 90),
    "vehicle": ("vehicle", 1, 150),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=list(RECORDINGS), help="recordings to make (default all)")
    parser.add_argument("--out", default=ROOT, help="parent folder (default recordings/)")
    args = parser.parse_args(argv)
    for name in args.names:
        if name not in RECORDINGS:
            parser.error(f"unknown recording {name}")
        scene_name, seed, frames = RECORDINGS[name]
        scene = make_scene(scene_name, seed=seed, n_frames=frames)
        video = write_recording(scene, os.path.join(args.out, name), seed=seed)
        print(f"{name}: {os.path.getsize(video) / 1e6:.1f} MB video", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
