"""Where the map's lights should appear next (receiver.locate.map_prior): the predicted pixels
against OpenCV's projection, the gate, and the positioner's prior from a tracked walk."""

import math

import cv2
import numpy as np

from receiver.locate import map_prior
from receiver.locate.indoor import Positioner
from receiver.locate.pose import ypr_to_rotation

from test_locate import CEILING_M, make_camera, make_map, observe


def test_predicted_pixels_are_opencv_s_projection_with_the_lens_distortion():
    cam = make_camera()
    rng = np.random.default_rng(3)
    for _ in range(5):
        R = ypr_to_rotation(*(np.array([0, 90, 0]) + rng.uniform(-20, 20, 3)))  # looking up
        C = np.array([*rng.uniform(0, 2.4, 2), 1.2])
        L = np.column_stack([rng.uniform(-1, 3.5, (30, 2)), np.full(30, CEILING_M)])
        prior = map_prior.predict(cam, np.arange(30), L, np.full(30, 0.05), R, C, np.eye(3) * 1e-4,
                                  math.radians(1.0), 0.0)
        rvec = cv2.Rodrigues(R)[0]
        want = cv2.projectPoints(L, rvec, -R @ C, cam.K, cam.dist)[0].reshape(-1, 2)
        front = (L - C) @ R.T
        assert np.array_equal(prior.ids, np.flatnonzero(front[:, 2] > 0))
        assert np.allclose(prior.px, want[prior.ids], atol=1e-6)


def test_the_sigma_grows_with_the_pose_s_uncertainty_and_the_gate_with_it():
    cam = make_camera()
    R = ypr_to_rotation(0, 90, 0)  # looking straight up
    C = np.array([1.2, 1.2, 1.0])
    L = np.array([[1.2, 1.2, CEILING_M], [2.0, 1.2, CEILING_M], [1.2, 2.0, CEILING_M]])
    tight = map_prior.predict(cam, np.array([7, 8, 9]), L, np.full(3, 0.1), R, C, np.eye(3) * 1e-6, 0.0, 0.0)
    # the half size alone: 0.1 m at 2 m is 0.05 rad, 30 px at 600 px focal
    assert np.allclose(tight.sigma_px[0], 600 * math.hypot(0.05, 1e-3 / 2), rtol=1e-6)
    cx, cy = tight.px[0]
    assert map_prior.near_ids(tight, cx + 20, cy) == (7,)
    loose = map_prior.predict(cam, np.array([7, 8, 9]), L, np.full(3, 0.1), R, C, np.eye(3) * 0.25, 0.0, 0.0)
    assert np.all(loose.sigma_px > tight.sigma_px)
    assert map_prior.near_ids(loose, cx + 20, cy)[0] == 7 and len(map_prior.near_ids(loose, cx + 20, cy)) == 3
    assert map_prior.near_ids(None, cx, cy) == ()


def test_a_tracked_positioner_predicts_each_light_where_it_is_seen_next():
    """Frames of a camera moving at 0.5 m/s under the 3 x 3 map: from the second fix on, the
    prior for the next frame puts each seen light's own ID first within its gate, and no other
    ID of the map (1.2 m apart) in it."""
    cam = make_camera()
    led_map = make_map()
    pos = Positioner(cam, led_map, handedness="right")
    R = ypr_to_rotation(0, 90, 0)
    checked = 0
    for k in range(12):
        t = k / 30.0
        C = np.array([0.9 + 0.5 * t, 1.0, 1.2])
        obs = observe(cam, led_map, C, R)
        if k >= 2:
            prior = pos.map_prior(t)
            assert prior is not None
            for o in obs:
                assert map_prior.near_ids(prior, o.cx, o.cy) == (o.id,)
                checked += 1
        pos.step(t, obs)
    assert checked >= 20
