"""The outline fix's covariance says how well: with each edge of two tilted panels seen offset as
a whole (0.5 px 1-sigma, the `EDGE_OFFSET_SIGMA_PX` the covariance assumes) on top of 0.3 px
point noise, the Mahalanobis^2 of the fix's error against its covariance is distributed as
chi^2 with 3 dof (median 2.37); from the point noise alone the covariance would be several
times too confident."""

import numpy as np

from receiver.locate import outline_pose
from receiver.locate.outline_pose import OutlineTarget, solve_outline_pose
from receiver.locate.pose import ypr_to_rotation

FOCAL = 1100.0
HALF = 0.125
CEILING = 2.8
TRUE_R = ypr_to_rotation(200.0, 90.0 - 25.0, 2.0)
TRUE_C = np.array([0.4, -0.5, 1.15])
NOISE_PX = 0.3


def _targets(rng, offset_px):
    out = []
    for L in (np.array([0.0, 0.0, CEILING]), np.array([1.1, 0.0, CEILING])):
        s = np.linspace(0.08, 0.92, 40)
        c = L + np.array([[HALF, HALF, 0], [-HALF, HALF, 0], [-HALF, -HALF, 0], [HALF, -HALF, 0]])
        pts = []
        for i in range(4):
            X = c[i] + s[:, None] * (c[(i + 1) % 4] - c[i])
            Xc = (X - TRUE_C) @ TRUE_R.T
            uv = Xc[:, :2] / Xc[:, 2:3]
            along = uv[-1] - uv[0]
            normal = np.array([-along[1], along[0]]) / np.hypot(*along)
            # the whole edge offset across itself, then each point's own noise
            uv = uv + normal * rng.normal(0, offset_px) / FOCAL + rng.normal(0, NOISE_PX, uv.shape) / FOCAL
            pts.append(uv)
        pts = np.concatenate(pts)
        Lc = TRUE_R @ (L - TRUE_C)
        out.append(OutlineTarget(L, "square", (HALF, HALF), pts, np.full(len(pts), NOISE_PX / FOCAL), Lc[:2] / Lc[2]))
    return out


def _nees(offset_px, n=40):
    """Mahalanobis^2 of n fixes' errors, each frame's edges offset with `offset_px` 1-sigma."""
    rng = np.random.default_rng(11)
    R0 = ypr_to_rotation(200.5, 90.0 - 25.0, 2.0)
    out = []
    for _ in range(n):
        fix = solve_outline_pose(_targets(rng, offset_px), R0, TRUE_C + [0.01, -0.01, 0.005], focal_px=FOCAL)
        assert fix is not None
        e = fix.C - TRUE_C
        out.append(float(e @ np.linalg.solve(fix.cov, e)))
    return np.array(out)


def test_the_covariance_covers_edges_offset_as_a_whole(monkeypatch):
    offset_px = outline_pose.EDGE_OFFSET_SIGMA_PX
    nees = _nees(offset_px)
    assert 1.0 < np.median(nees) < 5.0
    assert np.mean(nees < 7.8) > 0.8        # chi^2 3 dof: 95 % below 7.8
    # the same frames judged by their point noise alone: far too confident
    monkeypatch.setattr(outline_pose, "EDGE_OFFSET_SIGMA_PX", 0.0)
    assert np.median(_nees(offset_px)) > 3 * np.median(nees)
