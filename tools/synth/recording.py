"""Write a rendered scene as a recording folder (INTERFACES.md).

    DIR/video.avi: FFV1 (lossless) or MJPEG (as a USB webcam delivers it)
    DIR/camera.yaml, DIR/map.json, DIR/truth.jsonl (one object per frame)

Deterministic: the same scene, seed and codec give the same bytes (FFV1 is lossless and the
encoder is fed identical frames; per-frame RNG streams come from `render_frames`).
"""

from __future__ import annotations

import json
import os
import sys

import cv2

from receiver.io.camera import save_camera
from receiver.io.ledmap import save_map
from receiver.core.errors import InputError
from tools.synth.model import Scene
from tools.synth.render import render_frames

# FFV1 goes into AVI: OpenCV's Matroska muxer writes a random segment UID, which would break
# bit-exact regeneration; the AVI muxer is deterministic. Both codecs are lossless-readable by FFmpeg.
CODECS = {"ffv1": ("FFV1", "video.avi"), "mjpeg": ("MJPG", "video.avi")}


def write_recording(scene: Scene, out_dir: str, seed: int = 0, codec: str = "ffv1",
                    n_frames: int | None = None, progress=True) -> str:
    """Render `scene` into `out_dir`; returns the video path. Progress on stderr."""
    if codec not in CODECS:
        raise InputError(f"unknown codec '{codec}' (choose from {', '.join(CODECS)})")
    os.makedirs(out_dir, exist_ok=True)
    for name in os.listdir(out_dir):  # a stale video of the other codec would shadow this one
        if name.startswith("video."):
            os.remove(os.path.join(out_dir, name))
    fourcc, name = CODECS[codec]
    cam = scene.camera
    fps = cam.fps or 30.0
    video = os.path.join(out_dir, name)
    writer = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*fourcc), fps, (cam.width, cam.height),
                             isColor=False)
    if not writer.isOpened():
        raise InputError(f"cannot write {video}: OpenCV has no {fourcc} encoder")
    n = scene.n_frames if n_frames is None else int(n_frames)
    try:
        with open(os.path.join(out_dir, "truth.jsonl"), "w", encoding="utf-8") as truth_file:
            for img, truth in render_frames(scene, n_frames=n, seed=seed):
                writer.write(img)
                truth_file.write(json.dumps(truth, separators=(",", ":")) + "\n")
                k = truth["frame"] + 1
                if progress and (k % 10 == 0 or k == n):
                    print(f"synth {scene.name}: frame {k}/{n}", file=sys.stderr)
    finally:
        writer.release()
    save_camera(os.path.join(out_dir, "camera.yaml"), cam)
    save_map(os.path.join(out_dir, "map.json"), scene.led_map)
    return video
