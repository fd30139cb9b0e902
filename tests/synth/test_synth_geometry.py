"""Synthetic camera geometry: rendered blob centroid == truth centroid, and truth ==
an independent cv2.projectPoints of the LED outline.

The scenes here are built by hand: one steady circular LED (a firmware tone schedule with
`off_level=1.0`, i.e. the drive is 1.0 whether the pin is high or low, so every row sees the
same light), noise off, default PSF, seen head-on or obliquely through a distorting lens.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from firmware_tx.schedule import make_schedule
from receiver.io.ledmap import LedMap
from tools.synth.camera import Pose, make_camera
from tools.synth.model import Emitter, Light, RenderParams, Scene
from tools.synth.render import FrameRenderer
from tools.synth.waveform import LedDrive

CENTROID_TOL_PX = 0.1  # sub-pixel
# Truth is rounded to 4 decimals, and the renderer's circle is a 96-gon while the test's
# reference outline is a 2048-gon: the two polygons' centroids differ by far less than 1e-3 px.
PROJECT_TOL_PX = 2e-3
STEADY_TONE_HZ = 1000
DIAMETER_M = 0.12
BARREL_DIST = (-0.12, 0.03, 0.0015, -0.001, 0.0)  # k1 k2 p1 p2 k3: strong, with tangential terms

# (pose, LED centre, LED normal, lens distortion). Poses use the convention of tools.synth.camera.
CASES = {
    "head-on": (Pose(0.0, 0.0, 1.0, yaw=0.0, pitch=90.0, roll=0.0), (0.0513, -0.0827, 3.0), (0.0, 0.0, -1.0),
                (0.0, 0.0, 0.0, 0.0, 0.0)),
    "oblique-distorted": (Pose(0.0, 0.0, 1.0, yaw=25.0, pitch=50.0, roll=8.0), (1.1, 0.9, 3.0), (0.0, 0.0, -1.0),
                          BARREL_DIST),
    "tilted-led-distorted": (Pose(0.0, 0.0, 1.2, yaw=-10.0, pitch=20.0, roll=-5.0), (2.0, -0.9, 1.9),
                             (-0.6, 0.3, -0.5), BARREL_DIST),
}


def steady_scene(pose: Pose, centre, normal, dist, diameter_m=DIAMETER_M, **params) -> Scene:
    """One steady circular LED (id 1) and a still camera; noise off unless `params` say otherwise."""
    cam = make_camera(dist=dist)
    # off_level=1.0: the LED gives full light whether the firmware's pin is high or low.
    drive = LedDrive(make_schedule("tone", 1, STEADY_TONE_HZ), off_level=1.0)
    e = Emitter(np.asarray(centre, float), np.asarray(normal, float), np.array([0.0, 1.0, 0.0]), "circle",
                (diameter_m,), drive)
    kw = dict(read_noise_dn=0.0, shot_noise_alpha=0.0, frame_jitter_us=0.0)
    kw.update(params)
    return Scene(name="steady", camera=cam, lights=[Light(1, "tone", [e])], trajectory=lambda t: pose,
                 led_map=LedMap(addressing="map", leds={}), params=RenderParams(**kw), n_frames=1)


def weighted_centroid(img: np.ndarray):
    v, u = np.indices(img.shape, dtype=np.float64)
    w = img.astype(np.float64)
    return float((w * u).sum() / w.sum()), float((w * v).sum() / w.sum())


def reference_outline(centre, normal, diameter_m, n=2048) -> np.ndarray:
    """Dense circle outline (n, 3) in the world frame, built independently of tools.synth.model."""
    nrm = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(nrm, [1.0, 0.0, 0.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(nrm, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(nrm, a)
    th = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    r = diameter_m / 2
    return np.asarray(centre, float) + r * np.cos(th)[:, None] * a + r * np.sin(th)[:, None] * b


def camera_axes_world(pose: Pose) -> np.ndarray:
    """3x3 with columns = OpenCV camera x (right), y (down), z (optical axis) in world coordinates,
    derived from the documented convention (not from tools.synth.camera's rotation code):
    optical axis from yaw (about world z) and pitch (elevation); at roll 0 image right is
    horizontal, to the right of the view direction; roll turns right towards down."""
    y, p, r = (math.radians(v) for v in (pose.yaw, pose.pitch, pose.roll))
    z = np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), math.sin(p)])
    x0 = np.array([math.sin(y), -math.cos(y), 0.0])
    y0 = np.cross(z, x0)
    x = math.cos(r) * x0 + math.sin(r) * y0
    return np.stack([x, np.cross(z, x), z], axis=1)


@pytest.mark.parametrize("case", sorted(CASES))
def test_rendered_centroid_equals_truth(case):
    pose, centre, normal, dist = CASES[case]
    img, truth = FrameRenderer(steady_scene(pose, centre, normal, dist), seed=5).render(0)
    (led,) = truth["leds"]
    assert led["visible"]
    assert 800 < led["area_px"] < 20000  # a large blob, well inside the image
    assert img.max() < 255  # not saturated, so intensities are linear in coverage
    u, v = weighted_centroid(img)
    assert abs(u - led["cx"]) < CENTROID_TOL_PX, (u, led["cx"])
    assert abs(v - led["cy"]) < CENTROID_TOL_PX, (v, led["cy"])


def test_centroid_check_detects_offset():
    """The centroid test can fail: moving the LED by 2 mm moves the blob by a measurable amount."""
    pose, centre, normal, dist = CASES["head-on"]
    img0, t0 = FrameRenderer(steady_scene(pose, centre, normal, dist), seed=5).render(0)
    moved = (centre[0] + 0.002, centre[1], centre[2])
    img1, t1 = FrameRenderer(steady_scene(pose, moved, normal, dist), seed=5).render(0)
    du = weighted_centroid(img1)[0] - weighted_centroid(img0)[0]
    dv = weighted_centroid(img1)[1] - weighted_centroid(img0)[1]
    # World +x is image down at yaw 0, pitch 90: 2 mm at 2 m with f = 1000 px is 1 px down.
    assert abs(dv - 1.0) < CENTROID_TOL_PX and abs(du) < CENTROID_TOL_PX
    assert abs((t1["leds"][0]["cy"] - t0["leds"][0]["cy"]) - 1.0) < 1e-3


@pytest.mark.parametrize("case", sorted(CASES))
def test_truth_equals_cv2_projection_of_outline(case):
    pose, centre, normal, dist = CASES[case]
    scene = steady_scene(pose, centre, normal, dist)
    _, truth = FrameRenderer(scene, seed=5).render(0)
    (led,) = truth["leds"]
    R_wc = camera_axes_world(pose)
    rvec, _ = cv2.Rodrigues(R_wc.T)
    tvec = -R_wc.T @ pose.position
    outline = reference_outline(centre, normal, DIAMETER_M)
    img_pts, _ = cv2.projectPoints(outline.reshape(-1, 1, 3), rvec, tvec, scene.camera.K,
                                   np.asarray(dist, float))
    m = cv2.moments(img_pts.reshape(-1, 1, 2).astype(np.float32))  # polygon (Green's theorem) moments
    cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    assert abs(cx - led["cx"]) < PROJECT_TOL_PX, (cx, led["cx"])
    assert abs(cy - led["cy"]) < PROJECT_TOL_PX, (cy, led["cy"])
    assert abs(abs(m["m00"]) - led["area_px"]) / led["area_px"] < 2e-3
    d = float(np.linalg.norm(np.asarray(centre) - pose.position))
    assert abs(led["distance_m"] - d) < 1e-4
