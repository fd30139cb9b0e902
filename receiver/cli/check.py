"""`occloc check SOURCE [--camera FILE] [--map FILE] [--json]`: a one-screen verdict on whether
this camera and these settings can receive (receiver.calibrate.check). Exit status 0 when it can
work, 1 when a problem is found, 2 on bad input."""

from __future__ import annotations

import json
import os
import sys

from receiver.cli.args import MAX_FRAMES, whole_in

HELP = "check a camera/recording can receive (stripes, exposure, drift, banding, drops, focus); exit 1 on a problem"


def add_arguments(p) -> None:
    p.description = (HELP + ". Exit status: 0 = it can work, 1 = a problem was found (each with what "
                     "to change), 2 = bad input.")
    p.add_argument("source", metavar="SOURCE", help="recording folder, video file, images or /dev/videoN")
    p.add_argument("--camera", metavar="FILE", help="camera.yaml (default: the recording's)")
    p.add_argument("--map", metavar="FILE", help="LED map.json (default: the recording's)")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of the text verdict")
    p.add_argument("--max-frames", type=whole_in(1, MAX_FRAMES), default=90, metavar="N", help="frames to look at (90)")
    p.add_argument("--size", metavar="WxH", help="frame size to request from a camera")


def _photos(src, camera):
    """Each photo turned to sensor orientation as `occloc run` turns it (`_fit_photo`); a photo
    of another aspect ratio is skipped and named."""
    from receiver.cli.run import _fit_photo
    from receiver.core.errors import InputError
    from receiver.core.records import Frame
    for f in src.photos():
        try:
            _, gray = _fit_photo(camera, f.gray)
        except InputError as e:
            print(f"occloc: warning: {os.path.basename(src.files[f.index])}: {e}: skipped", file=sys.stderr)
            continue
        yield Frame(f.index, f.t_s, gray)


def main(args) -> int:
    from receiver.calibrate.check import check_frames, render_text
    from receiver.core.errors import InputError
    from receiver.io.camera import fit_camera, load_camera
    from receiver.io.ledmap import load_map
    from receiver.io.sources import find_recording_files, open_source, parse_size
    import numpy as np
    from receiver.cli.run import _fit_photo, _rotated

    spec = args.source
    if not spec.startswith("/dev/video") and not os.path.exists(spec):
        raise InputError(f"no such file or folder: {spec}")
    rec = find_recording_files(spec) if os.path.isdir(spec) else {}
    cam_path = args.camera or rec.get("camera")
    map_path = args.map or rec.get("map")
    cam = load_camera(cam_path) if cam_path else None
    led_map = load_map(map_path) if map_path else None
    src = open_source(spec, size=parse_size(args.size), camera=cam)
    try:
        frames = src
        if cam is not None and src.kind == "images":
            frames = _photos(src, cam)
            cam, _ = _fit_photo(cam, np.zeros(src.size[::-1], np.uint8)) if src.size else (cam, False)
        elif cam is not None and src.size is not None:
            cam, rotate = fit_camera(cam, src.size)
            frames = _rotated(src) if rotate else src
        stated = None
        if src.kind == "images":
            from receiver.io.imagefile import exif_exposure_us
            times = [exif_exposure_us(p) for p in src.files[:args.max_frames]]
            stated = max(times) if times and all(t is not None for t in times) else None
        findings = check_frames(frames, cam, led_map, fps=src.fps, max_frames=args.max_frames,
                                source_counts={"dropped": src.dropped, "skipped": src.skipped},
                                source_kind=src.kind, stated_exposure_us=stated)
    finally:
        src.close()
    ok = all(f.ok for f in findings)
    if args.json:
        print(json.dumps({"ok": ok, "source": spec, "findings": [f.to_json() for f in findings]}))
    else:
        print(render_text(findings))
    if cam is None:
        print("occloc: note: no camera file: exposure not checked", file=sys.stderr)
    return 0 if ok else 1
