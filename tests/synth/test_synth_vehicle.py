"""Vehicle scene realism: down-facing street-light panels (sub-pixel tall when far), exact
coverage, forward-vehicle bodies that occlude, the host's lane change, camera shake, length.

Hand-built scenes use a steady drive (a firmware tone schedule with `off_level=1.0`: full
light whether the pin is high or low) and no noise, so pixel values are coverage x radiance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_tx.schedule import make_schedule
from receiver.io.ledmap import LedMap
from tools.synth.camera import Pose, make_camera
from tools.synth.model import Body, Emitter, Light, RenderParams, Scene
from tools.synth.raster import coverage, coverage_exact, polygon_area_centroid
from tools.synth.render import FrameRenderer
from tools.synth.scenes import make_scene
from tools.synth.waveform import LedDrive

F_PX = 1200.0
PEAK_DN = 200.0


def steady():
    return LedDrive(make_schedule("tone", 1, 1000), off_level=1.0)


def quiet_params(**kw):
    base = dict(read_noise_dn=0.0, shot_noise_alpha=0.0, frame_jitter_us=0.0, psf_sigma_px=0.0,
                led_peak_dn=PEAK_DN)
    base.update(kw)
    return RenderParams(**base)


def panel_area_px(d_m, h_m, length_m, width_m, f_px=F_PX):
    """Analytic image area of a horizontal rect seen by a level pinhole camera (no distortion):
    the panel spans x1..x2 = d -+ length/2 ahead and h above the camera, so its image is a
    trapezoid with rows f h / x and widths f w / x: area = f^2 h w (1/x1^2 - 1/x2^2) / 2."""
    x1, x2 = d_m - length_m / 2, d_m + length_m / 2
    return f_px * f_px * h_m * width_m * (1 / x1 ** 2 - 1 / x2 ** 2) / 2


@pytest.mark.parametrize("d_m", [25.0, 60.0, 140.0])
def test_down_facing_panel_flux_and_truth_area_equal_the_projected_area(d_m):
    """A 0.4 x 0.3 m street-light half facing straight down, 5.8 m above a level camera: at 140 m
    it is ~0.1 px tall. Rendered flux / radiance and truth area_px both equal the analytic area."""
    h, width, length = 5.8, 0.4, 0.3
    cam = make_camera(focal_px=F_PX, exposure_us=100.0)
    e = Emitter(np.array([d_m, 0.137, h]), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0]), "rect",
                (width, length), steady())
    scene = Scene(name="panel", camera=cam, lights=[Light(1, "tone", [e])], trajectory=lambda t: Pose(0, 0, 0),
                  led_map=LedMap(addressing="map", leds={}), params=quiet_params(), n_frames=1)
    img, truth = FrameRenderer(scene).render(0)
    (led,) = truth["leds"]
    expect = panel_area_px(d_m, h, length, width)
    assert led["area_px"] == pytest.approx(expect, rel=2e-3)
    # Per-pixel level = PEAK * cos^(m-1)(phi) * cos^4(psi) (m = 1): divide it out of the flux.
    cos_psi = d_m / math.sqrt(d_m ** 2 + h ** 2 + 0.137 ** 2)
    flux = img.astype(np.float64).sum() / (PEAK_DN * cos_psi ** 4)
    n_lit = int((img > 0).sum())
    assert abs(flux - expect) <= 0.5 * n_lit / PEAK_DN + 1e-3 * expect  # 8-bit rounding per pixel


def test_exact_coverage_conserves_area_where_sampling_does_not():
    rng = np.random.default_rng(3)
    sampled_err = []
    for _ in range(20):
        a = np.sort(rng.uniform(0, 2 * math.pi, 9))
        poly = np.stack([30 + rng.uniform(2, 9) * np.cos(a), 6.3 + rng.uniform(0.05, 0.9) * np.sin(a)], axis=1)
        area = polygon_area_centroid(poly)[0]
        assert coverage_exact(poly, 0, 14, 0, 60).sum() == pytest.approx(area, rel=1e-5, abs=1e-6)
        assert coverage_exact(poly[::-1], 0, 14, 0, 60).sum() == pytest.approx(area, rel=1e-5, abs=1e-6)
        sampled_err.append(abs(coverage(poly, 0, 14, 0, 60, 4).sum() - area) / area)
    assert max(sampled_err) > 0.2  # why the exact path exists: 4 sample lines miss thin shapes


def test_exact_coverage_of_a_square_is_its_pixel_overlap():
    sq = np.array([[0.2, 0.3], [3.7, 0.3], [3.7, 2.1], [0.2, 2.1]])
    cov = coverage_exact(sq, 0, 3, 0, 5)
    expect = np.outer([0.2, 1.0, 0.6], [0.3, 1.0, 1.0, 1.0, 0.2])
    np.testing.assert_allclose(cov, expect, atol=1e-6)


# -- occlusion by forward-vehicle bodies --------------------------------------------------------

def taillight_pair(led_id, carrier):
    """Two steady 0.15 x 0.10 m rear lights 1.4 m apart, 1 m high, on `carrier`'s rear face."""
    ems = [Emitter(np.array([0.0, dy, 1.0]), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), "rect",
                   (0.15, 0.10), steady()) for dy in (0.7, -0.7)]
    return Light(led_id, "s2psk", ems, carrier=carrier)


def two_car_scene(near_y_m):
    """Camera 1.2 m high looking down the road; a car 15 m ahead at lateral `near_y_m` and a car
    35 m ahead in the camera's lane, each with a body and taillights."""
    cars = {"near": lambda t: (np.array([15.0, near_y_m, 0.0]), 0.0),
            "far": lambda t: (np.array([35.0, 0.0, 0.0]), 0.0)}
    return Scene(name="cars", camera=make_camera(focal_px=F_PX, exposure_us=100.0),
                 lights=[taillight_pair(0x81, "near"), taillight_pair(0x82, "far")],
                 trajectory=lambda t: Pose(0.0, 0.0, 1.2), led_map=LedMap(addressing="map", leds={}),
                 params=quiet_params(psf_sigma_px=0.7), n_frames=1, carriers=cars,
                 bodies=[Body("near"), Body("far")])


def lit(img, em):
    u, v = int(round(em["cx"])), int(round(em["cy"]))
    return float(img[v - 1:v + 2, u - 1:u + 2].max())


def test_taillights_behind_a_nearer_body_are_dark_and_not_visible():
    img, truth = FrameRenderer(two_car_scene(0.0)).render(0)
    by_id = {d["id"]: d for d in truth["leds"]}
    near, far = by_id[0x81], by_id[0x82]
    assert near["visible"] and near["occluded_frac"] == 0.0  # its own body never hides it
    assert all(lit(img, em) > 0.5 * PEAK_DN for em in near["emitters"])
    assert not far["visible"] and far["occluded_frac"] == 1.0
    for em in far["emitters"]:
        assert not em["visible"] and em["occluded_frac"] == 1.0
        assert lit(img, em) == 0.0  # fully behind the body: no light at all


def test_partly_hidden_pair_one_taillight_dark():
    # Near car 1 m to the right: its rear face (y in -1.9..-0.1 at 15 m) hides, at 35 m, the
    # lateral band -4.4..-0.23 m: the far car's right light (y = -0.7) but not its left (+0.7).
    img, truth = FrameRenderer(two_car_scene(-1.0)).render(0)
    far = {d["id"]: d for d in truth["leds"]}[0x82]
    a, b = far["emitters"]
    assert a["visible"] and a["occluded_frac"] == 0.0 and lit(img, a) > 0.5 * PEAK_DN
    assert not b["visible"] and b["occluded_frac"] == 1.0 and lit(img, b) == 0.0
    assert not far["visible"]


def test_no_occlusion_when_the_near_car_is_in_another_lane():
    img, truth = FrameRenderer(two_car_scene(3.5)).render(0)
    far = {d["id"]: d for d in truth["leds"]}[0x82]
    assert far["visible"] and far["occluded_frac"] == 0.0
    assert all(lit(img, em) > 0.5 * PEAK_DN for em in far["emitters"])


# -- the vehicle scene ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def veh():
    return make_scene("vehicle-road", seed=1)


def test_scene_length_and_speed_range(veh):
    assert veh.n_frames / veh.camera.fps >= 8.0  # several 2.4 s packets of every street light
    for t in np.linspace(0.0, veh.n_frames / veh.camera.fps, 50):
        hv = veh.extra_truth(float(t))["vehicle"]["hv"]
        assert 0.0 <= hv["speed_mps"] <= 80.0 / 3.6  # thesis Table 2: 0-80 km/h


def test_street_lights_face_straight_down(veh):
    heads = [lt for lt in veh.lights if lt.carrier is None]
    assert len(heads) > 20
    for lt in heads:
        for e in lt.emitters:
            np.testing.assert_allclose(e.normal, [0.0, 0.0, -1.0])


def test_lane_change_moves_the_host_3p5_m_left_with_the_camera_yaw_following(veh):
    t_end = veh.n_frames / veh.camera.fps
    hv0 = veh.extra_truth(0.0)["vehicle"]["hv"]
    hv1 = veh.extra_truth(t_end)["vehicle"]["hv"]
    assert hv1["y"] - hv0["y"] == pytest.approx(3.5, abs=0.02)
    headings = [veh.extra_truth(float(t))["vehicle"]["hv"]["heading_deg"] for t in np.linspace(0, t_end, 91)]
    assert max(headings) > 3.0 and min(headings) > -1e-6  # turns left, then straightens
    assert abs(headings[0]) < 1e-6 and abs(headings[-1]) < 0.5


def test_shake_in_pitch_and_yaw_is_bounded_and_seeded(veh):
    ts = np.arange(0.0, 8.0, 0.002)
    yaw_err, pitch_err = [], []
    for t in ts:
        pose = veh.trajectory(float(t))
        heading = veh.extra_truth(float(t))["vehicle"]["hv"]["heading_deg"]
        yaw_err.append(pose.yaw - heading)
        pitch_err.append(pose.pitch - 8.0 - 0.2 * math.sin(2 * math.pi * 1.3 * t))
    yaw_err, pitch_err = np.array(yaw_err), np.array(pitch_err)
    for err in (yaw_err, pitch_err):
        assert np.abs(err).max() <= 0.3 + 1e-4  # shake_deg (heading is rounded to 1e-5 deg)
        assert err.std() > 0.05  # present, a few tenths of a degree
    other = make_scene("vehicle-road", seed=2)
    assert other.trajectory(1.234).yaw != veh.trajectory(1.234).yaw
    assert make_scene("vehicle-road", seed=1).trajectory(1.234) == veh.trajectory(1.234)


def test_forward_vehicle_occluded_in_a_rendered_frame(veh):
    """Frame 150 (5 s): FV2 has cut in front of FV1 (truth says hidden); FV1's taillights are dark
    in the image, FV2's are lit."""
    img, truth = FrameRenderer(veh, seed=1).render(150)
    fvs = truth["vehicle"]["fv"]
    assert len(fvs) == 3
    for f in fvs:
        assert {"id", "x", "y", "distance_m", "angle_deg", "world_x", "world_y", "yaw_deg", "visible",
                "rel_speed_mps"} <= set(f)
        assert f["distance_m"] == pytest.approx(math.sqrt(f["x"] ** 2 + f["y"] ** 2 + 0.2 ** 2), abs=0.02)
    hidden = [f for f in fvs if not f["visible"]]
    assert hidden and hidden[0]["occluded_frac"] == 1.0
    by_id = {d["id"]: d for d in truth["leds"]}
    rec = by_id[hidden[0]["id"]]
    assert not rec["visible"] and all(lit(img, em) < 0.1 * PEAK_DN for em in rec["emitters"])
    shown = [by_id[f["id"]] for f in fvs if f["visible"]]
    assert shown and all(r["visible"] for r in shown)


def test_curved_road_option():
    sc = make_scene("vehicle-road", seed=1, curve_radius_m=400.0)
    heads = [lt for lt in sc.lights if lt.carrier is None]
    xy = np.array([lt.offset[:2] for lt in heads[0::2][:8]])  # the builder alternates left, right
    # Left-row lights on a circle of radius 400 - 6 m about (0, 400): not on a straight line.
    np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1] - 400.0), 394.0, atol=1e-6)
    hv = sc.extra_truth(2.0)["vehicle"]["hv"]
    assert hv["heading_deg"] == pytest.approx(math.degrees(hv["s_m"] / 400.0), abs=0.01)
    assert math.hypot(hv["x"], hv["y"] - 400.0) == pytest.approx(400.0, abs=1e-3)
    assert set(sc.led_map.leds) == set(make_scene("vehicle-road", seed=1).led_map.leds)
