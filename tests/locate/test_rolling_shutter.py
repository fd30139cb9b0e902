"""The camera's turn and travel while a rolling-shutter frame is read: its angular rate from the
tracked orientations (`PoseFilter.angular_rate`) and the points moved to the frame's first row's
view (`receiver.locate.indoor.derotate_rows`, `detranslate_rows`), against a camera turned and
moved at known rates."""

import cv2
import numpy as np

from receiver.locate.indoor import derotate_rows, detranslate_rows
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


def test_detranslated_points_are_the_first_rows_view():
    """A camera turning and walking while its rows are read: derotated, then detranslated with its
    velocity, each ceiling point is where the first row's camera saw it; a ray that misses the
    ceiling plane gives a non-finite point (the caller keeps the points as they were)."""
    rng = np.random.default_rng(4)
    C = np.array([1.0, 2.0, 1.2])
    v = np.array([0.9, -0.5, 0.1])                      # m/s: a brisk walk
    X = np.column_stack([rng.uniform(0, 2, 40), rng.uniform(1, 3, 40), np.full(40, 2.8)])
    row_s, f, cy = 10e-6, 1100.0, 360.0

    def seen(R, c):
        Xc = (X - c) @ R.T
        return Xc[:, :2] / Xc[:, 2:3]

    uv = seen(R0, C)
    for _ in range(6):
        rows = uv[:, 1] * f + cy
        uv = np.array([seen(_R(r * row_s), C + v * r * row_s)[i] for i, r in enumerate(rows)])
    rows = uv[:, 1] * f + cy
    turned = derotate_rows(uv, rows, W_CAM, row_s, 0.0)
    assert np.abs(turned - seen(R0, C)).max() * f > 1.0          # the travel alone is pixels ...
    back = detranslate_rows(turned, rows, X[:, 2], R0, C, v, row_s, 0.0)
    assert np.abs(back - seen(R0, C)).max() * f < 1e-6           # ... and gone
    assert np.abs(detranslate_rows(turned, rows, X[:, 2], R0, C, 0.0 * v, row_s, 0.0) - turned).max() < 1e-14
    sideways = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])   # optical axis along the ceiling
    edge_on = detranslate_rows(np.array([[0.0, 0.0]]), np.array([100.0]), np.array([2.8]), sideways, C, v, row_s, 0.0)
    assert not np.isfinite(edge_on).all()
