"""`occloc synth`: render a synthetic scene into a recording folder."""

from __future__ import annotations

import argparse
import ast

HELP = "render a synthetic scene (indoor rooms, a phone's view, roads) into a recording folder"

# Units of --set keys, by the end of the key's name (the project's names carry their units).
UNIT_SUFFIXES = (("_mps2", "m/s^2"), ("_mps", "m/s"), ("_kmh", "km/h"), ("_hz", "Hz"), ("_deg", "deg"),
                 ("_us", "us"), ("_um", "um"), ("_px", "px"), ("_dn", "DN (8-bit levels)"), ("_m", "m"),
                 ("_xy", "m (x, y)"), ("_xyz", "m (x, y, z)"), ("_s", "s"))
# Keys whose names do not end in a unit.
UNITS = {"width": "px", "height": "px", "fps": "frames/s", "seconds": "s", "dist": "OpenCV k1, k2, p1, p2, k3",
         "symclk": "clock cycles per symbol", "subrows": "samples per row", "motion_blur_samples": "poses per exposure",
         "shot_noise_alpha": "DN per DN of signal (thesis eq. 4)", "exact_coverage_rows": "image rows",
         "halo_frac": "fraction of a light's flux", "glare_frac": "fraction of a light's flux",
         "bloom_frac": "fraction of a clipped pixel's excess", "vignetting": "fraction of light lost at the corners",
         "centre_gain": "fraction brighter at a panel's centre", "bezel_frac": "fraction of a panel's half size",
         "tone_gamma": "exponent of the tone curve", "sharpen": "unsharp-mask amount", "rs_band_rows": "image rows",
         "turn_rad": "rad", "light_brightness": "times led_peak_dn", "taillight_brightness": "times led_peak_dn",
         "light_layout": "staggered, one-side or opposite", "head_style": "split or merged",
         "fv_gap_scale": "times the scripted gaps to the cars ahead"}


def unit_of(key: str) -> str:
    if key in UNITS:
        return UNITS[key]
    return next((u for suffix, u in UNIT_SUFFIXES if key.endswith(suffix)), "")


def _keys_text(params) -> str:
    """'key=default [unit]' of each parameter (inspect.Parameter), wrapped."""
    import textwrap
    items = []
    for p in params:
        unit = unit_of(p.name)
        items.append(f"{p.name}={p.default!r}" + (f" [{unit}]" if unit else ""))
    return textwrap.fill(", ".join(items), width=96, initial_indent="    ", subsequent_indent="    ")


def set_keys_help() -> str:
    """The --set keys: camera and sensor keys of every scene, then each scene's own, with
    their defaults and units."""
    import dataclasses
    import inspect

    from tools.synth.camera import make_camera
    from tools.synth.model import RenderParams
    from tools.synth.scenes import BUILDERS, SCENES

    cam = list(inspect.signature(make_camera).parameters.values())
    sensor = [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default)
              for f in dataclasses.fields(RenderParams)]
    lines = ["scenes: " + ", ".join(SCENES), "",
             "--set KEY=VALUE keys (VALUE a Python literal; defaults shown; some scenes set other "
             "camera and sensor defaults):", "  camera (every scene):", _keys_text(cam),
             "  sensor (every scene, tools/synth/model.py RenderParams):", _keys_text(sensor)]
    for name in SCENES:
        own = [p for p in inspect.signature(BUILDERS[name]).parameters.values() if p.name not in ("rng", "cam") and p.kind is not p.VAR_KEYWORD]
        lines += [f"  scene {name}:", _keys_text(own)]
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tools.synth.recording import CODECS
    from tools.synth.scenes import SCENES

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = set_keys_help()

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
    import os

    from receiver.io.files import cv_path
    cv_path(os.path.abspath(args.out), "recording folder")  # OpenCV's video writer opens a file in it
    check_out_dir(args.out, force=args.force)
    try:
        scene = make_scene(args.scene, seed=args.seed, n_frames=args.frames, **parse_overrides(args.set))
    except (TypeError, ValueError, OverflowError) as e:  # e.g. --set fps=abc reaches float('abc') in make_camera
        raise InputError(f"bad --set value: {e}") from None
    write_recording(scene, args.out, seed=args.seed, codec=args.codec)
    return 0
