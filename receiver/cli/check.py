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


def main(args) -> int:
    from receiver.calibrate.check import check_frames, render_text
    from receiver.core.errors import InputError
    from receiver.io.camera import fit_camera, load_camera
    from receiver.io.ledmap import load_map
    from receiver.io.sources import find_recording_files, open_source, parse_size

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
        if cam is not None and src.size is not None:
            cam, _rot = fit_camera(cam, src.size)
        findings = check_frames(src, cam, led_map, fps=src.fps, max_frames=args.max_frames,
                                source_counts={"dropped": src.dropped, "skipped": src.skipped})
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
