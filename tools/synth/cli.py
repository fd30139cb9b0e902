"""`occloc synth`: render a synthetic scene into a recording folder."""

from __future__ import annotations

import argparse
import ast

HELP = "render a synthetic scene (indoor-walk, indoor-static, vehicle) into a recording folder"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tools.synth.recording import CODECS
    from tools.synth.scenes import SCENES

    parser.add_argument("scene", choices=SCENES)
    parser.add_argument("--out", required=True, help="recording folder to write")
    parser.add_argument("--frames", type=int, help="number of frames (default: the scene's)")
    parser.add_argument("--seed", type=int, default=1, help="scene and noise seed (default 1)")
    parser.add_argument("--codec", choices=sorted(CODECS), default="ffv1")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene, camera or sensor parameter, e.g. --set fps=60 "
                             "--set panel_size_m=(0.1,0.1) (repeatable)")
    parser.add_argument("--force", action="store_true",
                        help="replace the recording in an existing, non-empty --out folder")


def parse_overrides(items: list[str]) -> dict:
    """`KEY=VALUE` pairs; VALUE is a Python literal (number, tuple, string)."""
    from receiver.core.errors import InputError

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(f"--set needs KEY=VALUE, got '{item}'")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key] = value
    return out


def main(args: argparse.Namespace) -> int:
    from receiver.core.errors import InputError
    from tools.synth.recording import write_recording
    from tools.synth.scenes import make_scene

    from tools.synth.recording import check_out_dir

    if args.frames is not None and not 0 < args.frames <= 1_000_000:
        raise InputError("--frames must be within 1..1000000")
    if not 0 <= args.seed < 2 ** 32:
        raise InputError(f"--seed must be within 0..{2 ** 32 - 1}, not {args.seed}")
    check_out_dir(args.out, force=args.force)
    try:
        scene = make_scene(args.scene, seed=args.seed, n_frames=args.frames, **parse_overrides(args.set))
    except (TypeError, ValueError, OverflowError) as e:  # e.g. --set fps=abc reaches float('abc') in make_camera
        raise InputError(f"bad --set value: {e}") from None
    write_recording(scene, args.out, seed=args.seed, codec=args.codec)
    return 0
