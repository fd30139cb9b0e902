"""Synthetic camera output: determinism, recording files round-trip through
receiver.io, `occloc synth` command line, and the render-speed benchmark."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from tools.synth.recording import write_recording
from tools.synth.render import FrameRenderer, render_frames
from tools.synth.scenes import make_scene

ROOT = Path(__file__).resolve().parents[2]
RECORDING_FILES = ("video.avi", "camera.yaml", "map.json", "truth.jsonl")
FEW_FRAMES = 3


def render_all(name, scene_seed, noise_seed, n=2):
    return list(render_frames(make_scene(name, seed=scene_seed), n_frames=n, seed=noise_seed))


def test_render_same_seed_identical_bytes():
    a = render_all("indoor-static", 2, 7)
    b = render_all("indoor-static", 2, 7)
    for (ia, ta), (ib, tb) in zip(a, b):
        assert ia.tobytes() == ib.tobytes()
        assert json.dumps(ta) == json.dumps(tb)


def test_render_frames_independent_of_order():
    """Each frame has its own RNG stream: frame 1 alone equals frame 1 after frame 0."""
    scene = make_scene("indoor-static", seed=2)
    both = list(render_frames(scene, n_frames=2, seed=7))
    alone = FrameRenderer(scene, seed=7).render(1)
    assert alone[0].tobytes() == both[1][0].tobytes()


def test_different_seeds_differ():
    base = render_all("indoor-static", 2, 7)
    noise = render_all("indoor-static", 2, 8)
    assert base[0][0].tobytes() != noise[0][0].tobytes()  # sensor noise differs
    # The scene does not (a still camera: only the frame-time jitter, drawn from the noise seed, moves t).
    assert [(d["id"], d["cx"], d["cy"]) for d in base[0][1]["leds"]] == \
        [(d["id"], d["cx"], d["cy"]) for d in noise[0][1]["leds"]]
    other = make_scene("indoor-static", seed=3)
    assert sorted(other.led_map.leds) != sorted(make_scene("indoor-static", seed=2).led_map.leds)  # IDs


@pytest.mark.parametrize("codec", ["ffv1", "mjpeg"])
def test_write_recording_bit_exact(tmp_path, codec):
    outs = []
    for name in ("a", "b"):
        write_recording(make_scene("indoor-static", seed=4), str(tmp_path / name), seed=4, codec=codec,
                        n_frames=FEW_FRAMES, progress=False)
        outs.append({f: (tmp_path / name / f).read_bytes() for f in RECORDING_FILES})
    assert outs[0] == outs[1]
    assert len((tmp_path / "a" / "truth.jsonl").read_text().splitlines()) == FEW_FRAMES
    write_recording(make_scene("indoor-static", seed=4), str(tmp_path / "c"), seed=5, codec=codec,
                    n_frames=FEW_FRAMES, progress=False)
    assert (tmp_path / "c" / "video.avi").read_bytes() != outs[0]["video.avi"]


def test_ffv1_video_is_lossless(tmp_path):
    import cv2

    scene = make_scene("indoor-static", seed=4)
    video = write_recording(scene, str(tmp_path), seed=4, n_frames=2, progress=False)
    cap = cv2.VideoCapture(video)
    for img, _ in render_frames(scene, n_frames=2, seed=4):
        ok, frame = cap.read()
        assert ok
        gray = frame if frame.ndim == 2 else frame[:, :, 0]
        assert np.array_equal(gray, img)
    cap.release()


@pytest.mark.parametrize("name", ["indoor-static", "vehicle"])
def test_camera_and_map_round_trip(tmp_path, name):
    scene = make_scene(name, seed=1)
    write_recording(scene, str(tmp_path), seed=1, n_frames=1, progress=False)
    cam, ref = load_camera(str(tmp_path / "camera.yaml")), scene.camera
    assert (cam.width, cam.height) == (ref.width, ref.height)
    np.testing.assert_allclose(cam.K, ref.K, rtol=1e-12)
    np.testing.assert_allclose(np.ravel(cam.dist)[:5], np.ravel(ref.dist)[:5], atol=1e-12)
    for key in ("row_readout_us", "exposure_us", "fps", "pixel_size_um", "focal_length_mm"):
        assert getattr(cam, key) == pytest.approx(getattr(ref, key), rel=1e-12), key
    assert cam.focal_px == pytest.approx(ref.K[0, 0])  # thesis eq. 18: f / rho = fx
    led_map = load_map(str(tmp_path / "map.json"))
    assert led_map.to_json() == scene.led_map.to_json()
    assert sorted(led_map.leds) == sorted(scene.led_map.leds)
    for light in scene.lights:
        led = led_map.lookup(light.id)
        if light.carrier is not None:  # forward vehicles are not in the map (they are found, not looked up)
            assert led is None
            continue
        np.testing.assert_allclose(led.xyz, light.offset, atol=1e-9)
        assert led.mode == light.mode
        assert led.area_m2 == pytest.approx(light.emitters[0].area_m2)
    if name == "vehicle":
        assert led_map.taillight["baseline_m"] == pytest.approx(1.4)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "receiver.cli", "synth", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_cli_writes_recording(tmp_path):
    out = tmp_path / "rec"
    p = run_cli("indoor-static", "--out", out, "--frames", FEW_FRAMES)
    assert p.returncode == 0, p.stderr
    for f in RECORDING_FILES:
        assert (out / f).stat().st_size > 0, f
    lines = (out / "truth.jsonl").read_text().splitlines()
    assert [json.loads(line)["frame"] for line in lines] == list(range(FEW_FRAMES))
    assert f"frame {FEW_FRAMES}/{FEW_FRAMES}" in p.stderr  # progress on stderr
    assert p.stdout == ""


@pytest.mark.parametrize("args,needle", [
    (("nosuch-scene",), "invalid choice"),
    (("indoor-static", "--set", "nosuch=1"), "no parameter 'nosuch'"),
    (("indoor-static", "--set", "fps=abc"), "bad --set value"),
    (("indoor-static", "--set", "fps"), "KEY=VALUE"),
    (("indoor-static", "--frames", "0"), "--frames"),
    (("vehicle-road", "--set", "light_spacing_m=0"), "light_spacing_m must be positive"),
    (("vehicle-random", "--set", "head_spacing_m=0"), "head_spacing_m must be positive"),
    (("vehicle-random", "--set", "head_half_width_m=-0.2"), "head_half_width_m must be positive"),
    (("vehicle-random", "--set", "head_style=fused"), "head_style must be split or merged"),
    (("vehicle-random", "--set", "head_sep_m=0.1", "--set", "head_half_width_m=0.3"), "overlap"),
    (("vehicle-random", "--set", "bloom_len_px=0"), "bloom_len_px must be positive"),
    (("vehicle-road", "--set", "taillight_brightness=-2"), "taillight_brightness must not be negative"),
    (("vehicle-random", "--set", "wander_hz=-1"), "wander_hz must not be negative"),
    (("vehicle-road", "--set", "lane_change_start_s=-5"), "lane_change_start_s must not be negative"),
])
def test_cli_bad_input_one_line_exit_2(tmp_path, args, needle):
    out = tmp_path / "rec"
    p = run_cli(*args, "--out", out, "--frames", 2) if "--frames" not in args else run_cli(*args, "--out", out)
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    err = [line for line in p.stderr.splitlines() if "error" in line or line.startswith("occloc:")]
    assert len(err) == 1 and needle in err[0], p.stderr
    if args[0] != "nosuch-scene":  # our own errors: exactly one line, nothing else
        assert len(p.stderr.splitlines()) == 1
    assert not (out / "video.avi").exists()


def test_benchmark_render_indoor_walk_frame(benchmark):
    """One 1280x720 indoor-walk frame (target: >= 30 frames/s on one core)."""
    scene = make_scene("indoor-walk", seed=1)
    renderer = FrameRenderer(scene, seed=1)
    img, truth = benchmark(renderer.render, 17)
    assert img.shape == (720, 1280)
    assert len(truth["leds"]) >= 4  # the scene's promise: >= 4 panels fully in view
