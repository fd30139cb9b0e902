"""The receiver's per-frame camera shift against truth, for one S2-PSK recording.

    .venv/bin/python -m tools.shift_truth recordings/vehicle --shake pairs motion

For each `PairSettings.shake` given, runs the receiver over the recording (no positioner, no
vehicle locator: the shift does not depend on them) and compares the common image shift it
used in each frame (`Receiver.shift`, None counted as no shift) with the true one.

The true motion of a frame is what the camera's turn since the previous frame (truth.jsonl's
camera yaw, pitch and roll) does to each truth emitter visible in both frames (`true_motion`):
the camera's turn alone, not each light's own motion from the forward drive, which a track's
velocity follows. A frame's error is the median over those emitters of the distance between
the displacement the receiver predicted for it and the true one.

Printed per mode, against the camera's turn ("turn") and against each emitter's whole
displacement, its own motion included ("lights": what a track without a velocity would need):
the median error over the frames after the first (px), its 95th percentile and the frames whose
error is over 2 px.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from receiver.core.errors import InputError

BAD_PX = 2.0  # a frame's shift is counted as wrong beyond this error


def true_motion(truth_path: str, focal_px: float, center_px: tuple[float, float]):
    """Per frame after the first: (frame index, (K, 2) places of the truth emitters in the previous
    frame (visible in both), their displacement by the camera's turn (K, 2) px, their whole
    displacement (K, 2) px). The turn's
    displacement of a point p: (f d_yaw, f d_pitch) + d_roll * (-(p_y - c_y), p_x - c_x), the
    angle changes in radians from truth.jsonl's camera pose; each angle's sign (how the renderer
    counts it) is the one that agrees with the lights' own displacements over the recording."""
    from receiver.io.files import read_jsonl

    rows = [obj for _, obj in read_jsonl(truth_path, "truth")]
    rows.sort(key=lambda o: o["frame"])
    if len(rows) < 2 or any("camera" not in o for o in rows):
        raise InputError(f"{truth_path}: needs the camera pose (yaw, pitch, roll) of two frames or more")
    ang = np.radians([[o["camera"]["yaw"], o["camera"]["pitch"], o["camera"].get("roll", 0.0)] for o in rows])
    d_ang = np.diff(ang, axis=0)
    lights = [_emitters(o) for o in rows]
    cx, cy = center_px
    frames = []
    for k in range(1, len(rows)):
        a, b = lights[k - 1], lights[k]
        keys = sorted(a.keys() & b.keys())
        p0 = np.array([a[q] for q in keys], float).reshape(-1, 2)
        d = np.array([b[q] for q in keys], float).reshape(-1, 2) - p0
        # the three angles' image patterns at these points (yaw x, pitch y, roll about c)
        basis = np.stack([np.column_stack([np.full(len(p0), focal_px), np.zeros(len(p0))]),
                          np.column_stack([np.zeros(len(p0)), np.full(len(p0), focal_px)]),
                          np.column_stack([-(p0[:, 1] - cy), p0[:, 0] - cx])])
        frames.append((int(rows[k]["frame"]), p0, d, basis, d_ang[k - 1]))
    # signs: each angle's pattern correlated with the lights' displacements over the recording
    corr = np.zeros(3)
    for _, _, d, basis, da in frames:
        for i in range(3):
            corr[i] += np.sum(basis[i] * da[i] * d)
    signs = np.where(corr >= 0, 1.0, -1.0)
    return [(f, p0, np.einsum("i,ikj->kj", da * signs, basis), d) for f, p0, d, basis, da in frames]


def _emitters(obj: dict) -> dict:
    """{(light id, emitter index): (cx, cy)} of the frame's visible emitters."""
    out = {}
    for led in obj.get("leds", []):
        for i, e in enumerate(led.get("emitters") or []):
            if e.get("visible") and not e.get("occluded"):
                out[(led["id"], i)] = (e["cx"], e["cy"])
    return out


def receiver_shifts(folder: str, shake: str, max_frames: int | None, motion: dict | None = None) -> dict[int, object]:
    """{frame index: displacement(points (K, 2)) -> (K, 2) px} of the receiver with
    `PairSettings(shake=shake)`: the common shift it gave its tracks and pairs (`Receiver.shift`,
    None as no shift)."""
    import dataclasses

    from receiver.io.camera import fit_camera, load_camera
    from receiver.io.ledmap import load_map
    from receiver.io.sources import find_recording_files, open_source
    from receiver.pipeline import Receiver, ReceiverSettings

    files = find_recording_files(folder)
    if files["video"] is None or files["camera"] is None or files["map"] is None:
        raise InputError(f"{folder}: not a recording folder (video.*, camera.yaml, map.json)")
    cam = load_camera(files["camera"])
    led_map = load_map(files["map"])
    src = open_source(folder, camera=cam)
    cam, rotate = fit_camera(cam, src.size)
    if rotate:
        raise InputError(f"{folder}: frames are turned against the camera file")
    base = ReceiverSettings()
    pair = dataclasses.replace(base.pair, shake=shake)
    ms = dataclasses.replace(base.motion, **(motion or {}))
    rx = Receiver(cam, led_map, settings=dataclasses.replace(base, pair=pair, motion=ms))
    if rx.pairer is None:
        raise InputError(f"{folder}: the map has no S2-PSK lights (no camera shift is estimated)")
    out = {}
    for n, frame in enumerate(src):
        if max_frames is not None and n >= max_frames:
            break
        rx.process(frame)
        shift = np.array(rx.shift or (0.0, 0.0))
        out[frame.index] = (lambda p, s=shift: p + s)
    return out


def _motion_fields(items: list[str]) -> dict:
    """{field: value} of NAME=VALUE items, each a MotionSettings field, its value of the field's type."""
    from receiver.vision.camera_motion import MotionSettings

    base = MotionSettings()
    out = {}
    for item in items:
        name, _, text = item.partition("=")
        if not hasattr(base, name) or not text:
            raise InputError(f"--motion {item!r}: expected NAME=VALUE with NAME a MotionSettings field")
        kind = type(getattr(base, name))
        try:
            value = kind(text)
        except ValueError:
            raise InputError(f"--motion {item!r}: {text!r} is not a {kind.__name__}") from None
        if not math.isfinite(value):
            raise InputError(f"--motion {item!r}: not a finite number")
        out[name] = value
    return out


def score(err: np.ndarray) -> dict:
    return {"frames": int(len(err)), "median_px": float(np.median(err)) if len(err) else None,
            "p95_px": float(np.percentile(err, 95)) if len(err) else None,
            "over_2px": int(np.sum(err > BAD_PX))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="recording folder (video.*, camera.yaml, map.json, truth.jsonl)")
    parser.add_argument("--shake", nargs="+", default=["pairs", "motion"],
                        choices=["pairs", "vertical", "pitch", "motion"],
                        help="PairSettings.shake values to compare (default: pairs motion)")
    parser.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    parser.add_argument("--motion", nargs="+", default=[], metavar="NAME=VALUE",
                        help="MotionSettings fields for \"motion\" (receiver.vision.camera_motion)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    try:
        motion = _motion_fields(args.motion)
        from receiver.io.camera import load_camera
        from receiver.io.sources import find_recording_files

        files = find_recording_files(args.recording)
        if files["truth"] is None or files["camera"] is None:
            raise InputError(f"{args.recording}: needs truth.jsonl and camera.yaml")
        if args.max_frames is not None and args.max_frames < 2:
            raise InputError("--max-frames must be at least 2")
        cam = load_camera(files["camera"])
        truth = true_motion(files["truth"], 0.5 * (cam.fx + cam.fy), (cam.cx, cam.cy))
        result = {}
        for shake in args.shake:
            got = receiver_shifts(args.recording, shake, args.max_frames, motion)
            # per frame, the median over the lights of the error of their predicted displacement
            err = np.array([np.median(np.hypot(*(got[f](p0) - p0 - d).T))
                            for f, p0, d, _ in truth if f in got and len(p0)])
            whole = np.array([np.median(np.hypot(*(got[f](p0) - p0 - d).T))
                              for f, p0, _, d in truth if f in got and len(p0)])
            result[shake] = {"turn": score(err), "lights": score(whole)}
    except InputError as e:
        print(f"shift_truth: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        for shake, both in result.items():
            for what, r in both.items():
                if not r["frames"]:   # no truth light seen in two frames the receiver ran
                    print(f"{shake:>11} vs {what:>6}: no frame to score")
                    continue
                print(f"{shake:>11} vs {what:>6}: {r['frames']} frames, median {r['median_px']:.2f} px, "
                      f"p95 {r['p95_px']:.2f} px, {r['over_2px']} frames over {BAD_PX:g} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
