"""Shared fixtures of the receiver tests: the real photos' folder and a small synthetic recording."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.cli.benchscene import bench_camera, bench_map, bench_scene, render_bench_frame
from receiver.io.camera import save_camera

# Real phone photos (../shared/real/luxapose beside the clone, see its README). OCCLOC_SHARED
# names another shared folder (the one holding real/); without the photos those tests skip.
SHARED = Path(os.environ.get("OCCLOC_SHARED") or Path(__file__).resolve().parents[2] / "shared")
REAL = SHARED / "real"
LUXAPOSE = REAL / "luxapose"

# The synthetic recording: the bench scene with LEDs big enough (radius 40 px = 32 chips of
# 20 kHz at 20 us/row) that the OOK decoder sees most of a packet per frame.
REC_RADIUS_PX = 40.0
REC_LEDS = 8
REC_FRAMES = 10


def real_dir(sub: str = "") -> Path:
    """The shared real-photo folder (or its subfolder `sub`); skips the calling test when it
    is absent (a clone without ../shared beside it, or OCCLOC_SHARED pointing elsewhere)."""
    path = REAL / sub if sub else REAL
    if not path.is_dir():
        pytest.skip(f"{path} not found: real-photo tests need the shared folder (../shared/real) "
                    "beside the repository, or OCCLOC_SHARED=DIR holding real/")
    return path


@pytest.fixture(scope="session")
def real() -> Path:
    """../shared/real (skip when absent)."""
    return real_dir()


@pytest.fixture(scope="session")
def luxapose() -> Path:
    """../shared/real/luxapose, the Luxapose photos (skip when absent)."""
    return real_dir("luxapose")


@pytest.fixture(scope="session")
def synth_recording(tmp_path_factory) -> dict:
    """A recording folder (lossless FFV1 video.mkv, camera.yaml, map.json) of the bench scene.
    Returns {"path", "ids", "leds", "frames" (list of (H, W) uint8)}."""
    folder = tmp_path_factory.mktemp("rec")
    leds = bench_scene(n_leds=REC_LEDS, radius_px=REC_RADIUS_PX, seed=3)
    cam = bench_camera()
    rng = np.random.default_rng(3)
    frames = [render_bench_frame(leds, k, rng=rng) for k in range(REC_FRAMES)]
    vw = cv2.VideoWriter(str(folder / "video.mkv"), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"),
                         cam.fps, (cam.width, cam.height), isColor=False)
    assert vw.isOpened()
    for f in frames:
        vw.write(f)
    vw.release()
    save_camera(str(folder / "camera.yaml"), cam)
    (folder / "map.json").write_text(json.dumps(bench_map(leds).to_json()))
    return {"path": folder, "ids": [led.led_id for led in leds], "leds": leds, "frames": frames}
