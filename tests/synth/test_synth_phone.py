"""The synthetic phone camera (tools.synth.phone): its effects drawn per seed within their
ranges, the lens distortion written into camera.yaml, bloom along columns, the tone curve and
pedestal, and the in-frame motion of a turning phone against the projection at each row's time."""

import numpy as np

from tools.synth.camera import project_camera_points, rotation_cam_to_world
from tools.synth.model import RenderParams
from tools.synth.phone import PHONE_RANGES, column_bloom, draw_phone, finish_frame
from tools.synth.render import FrameRenderer
from tools.synth.scenes import make_scene


def test_each_seed_draws_a_phone_within_the_ranges():
    phones = [draw_phone(np.random.default_rng([s, 1])) for s in range(5)]
    for cam, par in phones:
        k1, k2, p1, p2, k3 = cam["dist"]
        assert PHONE_RANGES["k1"][0] <= k1 <= PHONE_RANGES["k1"][1] and k3 == 0.0
        for key, value in par.items():
            if key in PHONE_RANGES:
                lo, hi = PHONE_RANGES[key]
                assert lo <= value <= hi, key
        assert RenderParams(**par).phone
    assert len({cam["dist"] for cam, _ in phones}) == 5


def test_phone_scene_has_its_lens_in_the_camera_and_overrides_win():
    a, b = make_scene("indoor-phone", seed=1), make_scene("indoor-phone", seed=2)
    assert a.camera.dist[0] < -0.05 and not np.array_equal(a.camera.dist, b.camera.dist)
    assert make_scene("indoor-phone", seed=1, tone_gamma=1.0).params.tone_gamma == 1.0
    plain = make_scene("indoor-phone", seed=1, phone=0)
    assert not plain.params.phone and not plain.camera.dist.any()
    assert make_scene("indoor-sparse", seed=1, phone=1).params.phone


def test_bloom_runs_along_the_column_and_keeps_the_charge():
    ex = np.zeros((60, 9), np.float32)
    ex[30, 4] = 100.0
    out = column_bloom(ex, 4.0)
    assert abs(float(out.sum()) - 100.0) < 1e-3
    assert out[:, 4].sum() > 99.9 and out[30, 4] == 0.0 and out[26, 4] > out[20, 4] > 0


def test_dark_frame_is_the_pedestal_and_the_tone_curve_is_monotone():
    p = RenderParams(black_level_dn=10.0, tone_gamma=2.0, read_noise_dn=0.0, shot_noise_alpha=0.0,
                     ambient_dn=0.0, vignetting=0.3)
    rng = np.random.default_rng(0)
    ramp = np.tile(np.linspace(0, 300, 64, dtype=np.float32), (4, 1))
    img = finish_frame(ramp, np.zeros_like(ramp), p, rng, None)
    assert img[0, 0] == 10 and img[0, -1] == 255
    assert np.all(np.diff(img[0].astype(int)) >= 0)
    # A linear 1/4 of full scale lands at half (gamma 2) of the range above the pedestal.
    k = int(np.argmin(np.abs(ramp[0] - 255 / 4)))
    assert abs(img[0, k] - (10 + 0.5 * 245 * np.sqrt(ramp[0, k] / 63.75))) <= 1.5


def _edge_errors_px(rs_band_rows):
    """Rendered minus projected left ends of the lit rows of a phone turning at ~100 deg/s, the
    projection taken with each row's own read time."""
    scene = make_scene("indoor-phone", seed=3, phone=0, rs_band_rows=rs_band_rows, psf_sigma_px=0.0,
                       read_noise_dn=0.0, shot_noise_alpha=0.0, turn_rad=0.6, turn_rate_rad_s=3.0)
    r = FrameRenderer(scene, seed=0)
    k = 12
    img, truth = r.render(k)
    t_k = truth["t"]
    row_s = scene.camera.row_readout_us * 1e-6
    errors = []
    for light in scene.lights:
        e = light.emitters[0]
        for y in range(0, scene.camera.height, 2):
            t = t_k + y * row_s + 0.5 * scene.camera.exposure_us * 1e-6
            pose = scene.trajectory(t)
            R = rotation_cam_to_world(pose.yaw, pose.pitch, pose.roll)
            pc = (e.outline_local() - pose.position) @ R
            if pc[:, 2].min() <= 0.1:
                continue
            poly = project_camera_points(pc, scene.camera)
            # The outline's left end on this row's centre line (a convex polygon).
            xs, steep = [], []
            for a, b in zip(poly, np.roll(poly, -1, axis=0)):
                if (a[1] - y) * (b[1] - y) < 0:
                    xs.append(a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]))
                    # a steep edge away from its corners: the row's pixels see that edge only
                    steep.append(abs(b[0] - a[0]) < abs(b[1] - a[1]) and min(abs(a[1] - y), abs(b[1] - y)) > 3)
            if len(xs) != 2 or not steep[int(np.argmin(xs))] or min(xs) < 5 or max(xs) > scene.camera.width - 5 or max(xs) - min(xs) < 20:
                continue
            lo, hi = int(np.floor(min(xs))) - 2, int(np.ceil(min(xs))) + 3
            row = img[y, lo:hi].astype(float)
            if row.max() < 60:
                continue      # an OFF chip's row: nothing lit to measure
            lit = row.max()
            # Coverage of the left end's pixel is the lit fraction: its edge to 0.2 px.
            j = int(np.argmax(row > 0.02 * lit))
            edge = lo + j + 0.5 - row[j] / lit
            errors.append(edge - min(xs))
    return np.array(errors)


def test_in_frame_motion_draws_each_band_at_its_read_time():
    banded, one_pose = _edge_errors_px(2), _edge_errors_px(0)
    assert len(banded) > 10 and np.abs(banded).max() < 0.25
    assert np.abs(one_pose).max() > 0.3       # one pose per light: its far rows miss
