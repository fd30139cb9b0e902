"""Synthetic camera against known truth: projection, centroids, stripes, S2-PSK XOR, seeds."""

import math

import cv2
import numpy as np

from firmware_tx.schedule import Schedule, make_schedule
from receiver.io.ledmap import LedMap, load_map, save_map
from receiver.io.camera import load_camera, save_camera
from tools.synth import make_scene, render_frames
from tools.synth.camera import Pose, make_camera, project_camera_points, rotation_cam_to_world, world_to_camera
from tools.synth.model import Emitter, Light, RenderParams, Scene
from tools.synth.waveform import LedDrive, led_drive

QUIET = RenderParams(read_noise_dn=0.0, shot_noise_alpha=0.0, psf_sigma_px=0.0, frame_jitter_us=0.0)
UP = Pose(0.0, 0.0, 1.0, yaw=0.0, pitch=90.0, roll=0.0)


def steady_drive():
    return LedDrive(Schedule("steady", 1000, bytearray(b"\x01"), 1, bytearray(b"\x01"), 1))


def one_led_scene(drive, shape="square", size=(0.3, 0.3), xyz=(0.1, -0.2, 3.0), params=QUIET, **cam_kw):
    cam = make_camera(**{"width": 320, "height": 240, "focal_px": 300.0, "dist": (-0.05, 0.01, 0.001, -0.001, 0.0),
                         **cam_kw})
    e = Emitter(np.array(xyz, float), np.array([0.0, 0.0, -1.0]), np.array([0.3, 1.0, 0.0]), shape, size, drive)
    return Scene("test", cam, [Light(1, "ook", [e])], lambda t: UP, LedMap(), params=params, n_frames=1)


def test_pose_convention_pitch_90_looks_up_with_image_down_along_world_x():
    R = rotation_cam_to_world(0.0, 90.0, 0.0)
    np.testing.assert_allclose(R[:, 2], [0, 0, 1], atol=1e-12)  # optical axis up
    np.testing.assert_allclose(R[:, 1], [1, 0, 0], atol=1e-12)  # image down = world +x
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)  # image right = world -y
    np.testing.assert_allclose(rotation_cam_to_world(90.0, 0.0, 0.0)[:, 2], [0, 1, 0], atol=1e-12)


def test_projection_equals_cv2_projectPoints():
    cam = make_camera(dist=(-0.1, 0.03, 0.002, -0.001, 0.005))
    pose = Pose(1.0, 2.0, 1.0, yaw=20.0, pitch=80.0, roll=-4.0)
    rng = np.random.default_rng(0)
    pw = np.column_stack([rng.uniform(0, 3, 50), rng.uniform(1, 4, 50), np.full(50, 3.0)])
    pc = world_to_camera(pw, pose)
    ours = project_camera_points(pc, cam)
    ref, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-9)


def test_rendered_centroid_equals_truth_centroid_subpixel():
    for shape, size in (("square", (0.3, 0.3)), ("circle", (0.25,)), ("rect", (0.2, 0.4))):
        img, truth = next(render_frames(one_led_scene(steady_drive(), shape, size), 1, seed=0))
        led = truth["leds"][0]
        assert led["visible"]
        w = img.astype(np.float64)
        v, u = np.mgrid[:img.shape[0], :img.shape[1]]
        cx, cy = (w * u).sum() / w.sum(), (w * v).sum() / w.sum()
        assert abs(cx - led["cx"]) < 0.05 and abs(cy - led["cy"]) < 0.05, (shape, cx, cy, led)
        # The rendered light also matches the true projected area: pixels of 180 DN * cos^4(psi).
        cos_psi = 2.0 / math.sqrt(0.1 ** 2 + 0.2 ** 2 + 2.0 ** 2)
        assert abs(w.sum() / (180.0 * cos_psi ** 4) - led["area_px"]) < 0.005 * led["area_px"]


def test_stripe_period_equals_one_over_rate_times_row_time():
    freq_hz, row_us = 4000, 10.0  # 25 rows per period, ~10 periods over the LED
    scene = one_led_scene(led_drive("tone", 0, freq_hz), "square", (1.6, 1.6), xyz=(0.0, 0.0, 3.0), height=480,
                          row_readout_us=row_us, exposure_us=20.0, dist=(0, 0, 0, 0, 0))
    img, truth = next(render_frames(scene, 1, seed=0))
    col = img[:, int(truth["leds"][0]["cx"])].astype(np.float64)
    rows = col[col.nonzero()[0].min() + 2:col.nonzero()[0].max() - 2]  # inside the LED (dark stripes included)
    spec = np.abs(np.fft.rfft((rows - rows.mean()) * np.hanning(len(rows)), n=8192))
    peak = np.argmax(spec[1:]) + 1
    period = 8192 / peak
    assert abs(period - 1.0 / (freq_hz * row_us * 1e-6)) < 0.3, period


def test_ook_rows_follow_the_firmware_chip_stream():
    # Global shutter, 1 us exposure: the LED's level is the firmware's chip at the frame time.
    drive = led_drive("ook", 0xBEEF, 20000, phase_s=0.0)
    scene = one_led_scene(drive, row_readout_us=0.0, exposure_us=1.0)
    sched = make_schedule("ook", 0xBEEF, 20000)
    for img, truth in render_frames(scene, 6, seed=0):
        led = truth["leds"][0]
        level = img[int(round(led["cy"])), int(round(led["cx"]))]
        chip = sched.levels[int(math.floor((truth["t"] + 0.5e-6) * 20000)) % len(sched.levels)]
        assert (level > 90) == bool(chip)


def test_s2psk_xor_of_the_two_emitters_is_the_symbol_stream():
    clk, symclk, led_id = 200, 4, 0x2A
    # 29.97 fps: not commensurate with the 5 ms clock, so frames sample every clock phase.
    cam_kw = dict(width=320, height=240, focal_px=300.0, row_readout_us=15.0, exposure_us=100.0, fps=29.97)
    cam = make_camera(**cam_kw)
    a = led_drive("s2psk", led_id, clk, symclk, pin=0, phase_s=0.0123)
    b = led_drive("s2psk", led_id, clk, symclk, pin=1, phase_s=0.0123)
    ems = [Emitter(np.array([0.0, y, 3.0]), np.array([0, 0, -1.0]), np.array([0, 1.0, 0]), "square", (0.3, 0.3), d)
           for y, d in ((0.3, a), (-0.3, b))]
    scene = Scene("pair", cam, [Light(led_id, "s2psk", ems)], lambda t: UP, LedMap(), params=QUIET, n_frames=40)
    symbols = make_schedule("s2psk", led_id, clk, symclk).units
    checked = 0
    for img, truth in render_frames(scene, 40, seed=3):
        ea, eb = truth["leds"][0]["emitters"]
        row = int(round(ea["cy"]))
        va, vb = img[row, int(round(ea["cx"]))], img[row, int(round(eb["cx"]))]
        if min(abs(int(va) - 90), abs(int(vb) - 90)) < 60:
            continue  # exposure straddles a clock edge: no clean level
        tau = a.led_time(truth["t"] + row * 15e-6 + 50e-6)
        expect = symbols[int(tau * 2 * clk // (2 * symclk)) % len(symbols)]
        assert ((va > 90) ^ (vb > 90)) == bool(expect)
        checked += 1
    assert checked >= 30


def test_same_seed_same_bytes_other_seed_other_noise():
    scene = make_scene("indoor-static", seed=4, n_frames=2, width=320, height=180, focal_px=250.0)
    one = [img for img, _ in render_frames(scene, 2, seed=9)]
    two = [img for img, _ in render_frames(make_scene("indoor-static", seed=4, n_frames=2, width=320, height=180,
                                                      focal_px=250.0), 2, seed=9)]
    other = [img for img, _ in render_frames(scene, 2, seed=10)]
    assert all(np.array_equal(x, y) for x, y in zip(one, two))
    assert not np.array_equal(one[0], other[0])


def test_camera_and_map_round_trip_through_receiver_loaders(tmp_path):
    for name in ("indoor-static", "vehicle"):
        scene = make_scene(name, seed=1, n_frames=1)
        save_camera(str(tmp_path / "camera.yaml"), scene.camera)
        save_map(str(tmp_path / "map.json"), scene.led_map)
        cam = load_camera(str(tmp_path / "camera.yaml"))
        np.testing.assert_allclose(cam.K, scene.camera.K)
        np.testing.assert_allclose(cam.dist, scene.camera.dist)
        assert cam.row_readout_us == scene.camera.row_readout_us and cam.exposure_us == scene.camera.exposure_us
        m = load_map(str(tmp_path / "map.json"))
        assert set(m.leds) == {lt.id for lt in scene.lights if lt.carrier is None}
        for lt in scene.lights:
            if lt.carrier is None:
                np.testing.assert_allclose(m.lookup(lt.id).xyz, lt.offset)
                assert abs(m.lookup(lt.id).area_m2 - lt.emitters[0].area_m2) < 1e-12


def test_render_speed_1280x720_16_leds(benchmark):
    scene = make_scene("indoor-static", seed=2, n_frames=1)
    extra = make_scene("indoor-static", seed=3, n_frames=1, camera_xyz=(2.3, 2.0, 1.0))
    scene.lights = scene.lights + extra.lights  # 16 LEDs of 3 cm .. 30 cm
    from tools.synth.render import FrameRenderer
    r = FrameRenderer(scene, seed=0)
    img, truth = benchmark(r.render, 0)
    assert img.shape == (720, 1280) and len(truth["leds"]) == 16
