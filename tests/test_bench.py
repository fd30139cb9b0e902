"""`occloc bench` and the whole-frame budget benchmark (pytest-benchmark)."""

from __future__ import annotations

import cv2
import numpy as np

from receiver.cli.bench import bench_frames, bench_ids, bench_scene
from receiver.core.budget import one_core
from receiver.cli import main as cli
from receiver.pipeline import Receiver


def test_bench_command_prints_stage_table(capsys):
    assert cli(["bench", "--frames", "4"]) == 0
    out = capsys.readouterr().out
    assert "4 frames 1280x720" in out and "frames/s" in out
    for stage in ("detect", "track", "decode", "output", "total"):
        assert any(line.startswith(stage) for line in out.splitlines())


def test_one_core_sets_opencv_to_one_thread_and_restores_it():
    before = cv2.getNumThreads()
    with one_core():
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before


def test_bench_command_on_a_photo(luxapose, capsys):
    assert cli(["bench", str(luxapose / "small_blob.jpg"), "--camera", str(luxapose / "camera_lumia1020.yaml"),
                "--map", str(luxapose / "map_test_rig.json"), "--repeat", "2"]) == 0
    assert "2 frames 7712x4352" in capsys.readouterr().out


def test_bench_scene_is_what_it_claims():
    leds = bench_scene()
    assert len(leds) == 16 and len(set(bench_ids())) == 16
    xy = np.array([(led.cx, led.cy) for led in leds])
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) + np.eye(16) * 1e9
    assert d.min() > 2.5 * leds[0].radius_px  # separate lights


def test_bench_whole_frame_budget(benchmark):
    """Issue 4 budget case: 1280x720, 16 LEDs, steady state (IDs decoded), one frame, one core."""
    cam, led_map, frames = bench_frames(12)
    rx = Receiver(cam, led_map)
    for f in frames[:-1]:
        rx.process(f)
    with one_core():
        res = benchmark(rx.process, frames[-1])
    assert len(res.leds) == 16 and sum(o.id is not None for o in res.leds) >= 14
