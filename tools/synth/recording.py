"""Write a rendered scene as a recording folder (INTERFACES.md).

    DIR/video.avi: FFV1 (lossless) or MJPEG (as a USB webcam delivers it)
    DIR/video.mp4: H.264 at `H264_BITRATE` (as a phone records), by an `ffmpeg` found on PATH
    DIR/camera.yaml, DIR/map.json, DIR/truth.jsonl (one object per frame)

Deterministic (FFV1, MJPEG): the same scene, seed and codec give the same bytes (FFV1 is lossless and the
encoder is fed identical frames; per-frame RNG streams come from `render_frames`).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import cv2

from receiver.io.camera import save_camera
from receiver.io.ledmap import save_map
from receiver.core.errors import InputError
from receiver.io.files import dumps
from tools.synth.model import Scene
from tools.synth.render import render_frames

# FFV1 goes into AVI: OpenCV's Matroska muxer writes a random segment UID, which would break
# bit-exact regeneration; the AVI muxer is deterministic. Both codecs are lossless-readable by FFmpeg.
CODECS = {"ffv1": ("FFV1", "video.avi"), "mjpeg": ("MJPG", "video.avi"), "h264": ("H264", "video.mp4")}
# A phone's 720p video bit rate.
H264_BITRATE = "8M"


class _FfmpegWriter:
    """cv2.VideoWriter's write / release / isOpened over an `ffmpeg` process encoding H.264
    (OpenCV's own FFmpeg has no H.264 encoder)."""

    def __init__(self, path: str, fps: float, size: tuple[int, int]):
        exe = shutil.which("ffmpeg")
        if exe is None:
            raise InputError("codec h264 needs the ffmpeg program on PATH (apt-get install ffmpeg)")
        w, h = size
        self.proc = subprocess.Popen(
            [exe, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "gray", "-s", f"{w}x{h}", "-r", f"{fps:g}",
             "-i", "-", "-c:v", "libx264", "-b:v", H264_BITRATE, "-pix_fmt", "yuv420p", "-f", "mp4", path],
            stdin=subprocess.PIPE)

    def isOpened(self) -> bool:
        return self.proc.poll() is None

    def write(self, img) -> None:
        self.proc.stdin.write(img.tobytes())

    def release(self) -> None:
        if self.proc.stdin and not self.proc.stdin.closed:
            self.proc.stdin.close()
        if self.proc.wait() != 0:
            raise OSError("ffmpeg failed to encode the video")


RECORDING_FILES = ("camera.yaml", "map.json", "truth.jsonl")


def check_out_dir(out_dir: str, force: bool = False) -> None:
    """InputError unless `out_dir` can take a recording: a new folder, an empty one, or (with
    `force`) an existing one whose recording files are then replaced."""
    if os.path.lexists(out_dir) and not os.path.isdir(out_dir):
        raise InputError(f"--out {out_dir} exists and is not a folder")
    if os.path.isdir(out_dir) and os.listdir(out_dir) and not force:
        raise InputError(f"--out {out_dir} is a folder that is not empty: refusing to overwrite it "
                         f"(give --force to replace its recording)")


def write_recording(scene: Scene, out_dir: str, seed: int = 0, codec: str = "ffv1",
                    n_frames: int | None = None, progress=True) -> str:
    """Render `scene` into `out_dir`; returns the video path. Progress on stderr.

    Every file is written under a temporary name in `out_dir` and renamed into place when the
    whole recording is written: an interrupted render leaves the old files (or none), never half."""
    if codec not in CODECS:
        raise InputError(f"unknown codec '{codec}' (choose from {', '.join(CODECS)})")
    if os.path.lexists(out_dir) and not os.path.isdir(out_dir):
        raise InputError(f"cannot write {out_dir}: it exists and is not a folder")
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot write {out_dir}: {e.strerror or e}") from None
    fourcc, name = CODECS[codec]
    cam = scene.camera
    fps = cam.fps or 30.0
    video = os.path.join(out_dir, name)
    tmp = {n: os.path.join(out_dir, f".{n}.tmp-{os.getpid()}") for n in (name,) + RECORDING_FILES}
    # the temporary video keeps its extension: OpenCV picks the container from it
    tmp[name] = os.path.join(out_dir, f".tmp-{os.getpid()}-{name}")
    if codec == "h264":
        writer = _FfmpegWriter(tmp[name], fps, (cam.width, cam.height))
    else:
        writer = cv2.VideoWriter(tmp[name], cv2.VideoWriter_fourcc(*fourcc), fps, (cam.width, cam.height),
                                 isColor=False)
    if not writer.isOpened():
        raise InputError(f"cannot write {video}: OpenCV has no {fourcc} encoder")
    n = scene.n_frames if n_frames is None else int(n_frames)
    done = False
    try:
        try:
            with open(tmp["truth.jsonl"], "w", encoding="utf-8") as truth_file:
                for img, truth in render_frames(scene, n_frames=n, seed=seed):
                    writer.write(img)
                    truth_file.write(dumps(truth, separators=(",", ":")) + "\n")
                    k = truth["frame"] + 1
                    if progress and (k % 10 == 0 or k == n):
                        print(f"synth {scene.name}: frame {k}/{n}", file=sys.stderr)
        finally:
            writer.release()
        save_camera(tmp["camera.yaml"], cam)
        save_map(tmp["map.json"], scene.led_map)
        for stale in os.listdir(out_dir):  # a stale video of the other codec would shadow this one
            if stale.startswith("video.") and stale != name:
                os.remove(os.path.join(out_dir, stale))
        for final, t in tmp.items():
            os.replace(t, os.path.join(out_dir, final))
        done = True
    except OSError as e:
        raise InputError(f"cannot write {out_dir}: {e.strerror or e}") from None
    finally:
        if not done:
            for t in tmp.values():
                if os.path.exists(t):
                    os.remove(t)
    return video
