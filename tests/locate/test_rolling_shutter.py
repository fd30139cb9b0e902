"""The camera's turn while a rolling-shutter frame is read: its angular rate from the tracked
orientations (`PoseFilter.angular_rate`) and the points moved to the frame's first row's instant
(`receiver.locate.indoor.derotate_rows`), against a camera turned by a known rate."""

import cv2
import numpy as np

from receiver.locate.indoor import derotate_rows
from receiver.locate.posefilter import PoseFilter

W_CAM = np.array([0.2, -0.45, 0.3])        # rad/s: a phone turning at ~33 deg/s
R0 = cv2.Rodrigues(np.array([[2.9], [0.3], [-0.2]]))[0]


def _R(t):
    return cv2.Rodrigues((W_CAM * t).reshape(3, 1))[0] @ R0


def test_angular_rate_from_tracked_orientations():
    pf = PoseFilter(sigma_uv=1e-3)
    assert pf.angular_rate(0.0) is None
    for k in range(4):
        pf.keep_orientation(k / 30, _R(k / 30))
    assert np.allclose(pf.angular_rate(3 / 30), W_CAM, atol=1e-9)
    # Stale: no rate long after the last orientation, nor across a gap in the fixes.
    assert pf.angular_rate(3 / 30 + 1.0) is None
    pf.keep_orientation(2.0, _R(2.0))
    assert pf.angular_rate(2.0) is None


def test_an_orientation_jump_starts_the_rate_afresh():
    """A lone rect seen from below fits turned by 180 degrees as well: a track whose orientation
    flips between two frames has no rate across the flip (it would derotate the next frames'
    points by radians), and the rate after it comes from the orientations after the flip."""
    flip = cv2.Rodrigues(np.array([[0.0], [0.0], [np.pi]]))[0]   # half a turn about the optical axis
    pf = PoseFilter(sigma_uv=1e-3)
    for k in range(3):
        pf.keep_orientation(k / 30, _R(k / 30))
    assert np.allclose(pf.angular_rate(2 / 30), W_CAM, atol=1e-9)
    pf.keep_orientation(3 / 30, flip @ _R(3 / 30))
    assert pf.angular_rate(3 / 30) is None
    pf.keep_orientation(4 / 30, flip @ _R(4 / 30))
    w = pf.angular_rate(4 / 30)
    assert w is not None and np.linalg.norm(w) < 1.0   # the flipped track's own rate (~0.6 rad/s), not ~90

def test_derotated_points_are_the_first_rows_view():
    rng = np.random.default_rng(3)
    C = np.array([1.0, 2.0, 1.2])
    X = np.column_stack([rng.uniform(0, 2, 40), rng.uniform(1, 3, 40), np.full(40, 2.8)])
    row_s, f, cy = 10e-6, 1100.0, 360.0

    def seen(R):
        Xc = (X - C) @ R.T
        return Xc[:, :2] / Xc[:, 2:3]

    # Each point read at its own row: the orientation of that row's instant (a fixed point).
    uv = seen(R0)
    for _ in range(5):
        rows = uv[:, 1] * f + cy
        uv = np.array([seen(_R(r * row_s))[i] for i, r in enumerate(rows)])
    rows = uv[:, 1] * f + cy
    moved = np.abs(uv - seen(R0)).max() * f
    back = derotate_rows(uv, rows, W_CAM, row_s, 0.0)
    assert moved > 1.0                                   # the shear is pixels ...
    assert np.abs(back - seen(R0)).max() * f < 1e-6     # ... and gone
