"""A frame's outline fit with a few stray edge points (a glare speck, a codec block at a stripe's
end) is judged without them (`outline_pose._without_outliers`), while points that belong to
another pose (a wrong ID: a whole panel elsewhere) still reject the fit."""

import numpy as np

from receiver.locate import outline_pose
from receiver.locate.outline_pose import OutlineTarget, solve_outline_pose
from receiver.locate.pose import ypr_to_rotation

FOCAL = 1100.0
HALF = 0.125
CEILING = 2.8
TRUE_R = ypr_to_rotation(200.0, 90.0 - 25.0, 2.0)
TRUE_C = np.array([0.4, -0.5, 1.15])
SIGMA_PX = 0.3


def _square(L, C=TRUE_C, R=TRUE_R, seed=0):
    """The square panel at L seen from (R, C): 160 normalized edge points (noise 0.1 px), their
    sigma and the centroid."""
    s = np.linspace(0.08, 0.92, 40)
    c = L + np.array([[HALF, HALF, 0], [-HALF, HALF, 0], [-HALF, -HALF, 0], [HALF, -HALF, 0]])
    X = np.concatenate([c[i] + s[:, None] * (c[(i + 1) % 4] - c[i]) for i in range(4)])
    Xc = (X - C) @ R.T
    uv = Xc[:, :2] / Xc[:, 2:3] + np.random.default_rng(seed).normal(0, 0.1 / FOCAL, (len(X), 2))
    Lc = R @ (L - C)
    return uv, np.full(len(uv), SIGMA_PX / FOCAL), Lc[:2] / Lc[2]


def _targets(stray=0, wrong_id=False):
    A, B = np.array([0.0, 0.0, CEILING]), np.array([1.1, 0.0, CEILING])
    out = []
    for k, L in enumerate((A, B)):
        pts, sig, uv = _square(L, seed=k)
        if k == 0 and stray:
            # stray points 15 px off the panel's first edge, across it (50 sigma each)
            along = pts[39] - pts[0]
            normal = np.array([-along[1], along[0]]) / np.hypot(*along)
            pts = pts.copy()
            pts[5:5 + stray] += normal * 15.0 / FOCAL
        xyz = L + np.array([0.0, 1.1, 0.0]) if (wrong_id and k == 1) else L
        out.append(OutlineTarget(xyz, "square", (HALF, HALF), pts, sig, uv))
    return out


def _solve(targets):
    R0 = ypr_to_rotation(200.5, 90.0 - 25.0, 2.0)
    return solve_outline_pose(targets, R0, TRUE_C + [0.01, -0.01, 0.005], focal_px=FOCAL)


def test_a_few_stray_points_do_not_reject_the_fit(monkeypatch):
    clean = _solve(_targets())
    assert clean is not None and np.linalg.norm(clean.C - TRUE_C) < 0.003
    fix = _solve(_targets(stray=8))
    assert fix is not None and np.linalg.norm(fix.C - TRUE_C) < 0.003
    assert fix.chi2 / fix.dof < 5.0
    # the covariance says how well: the error within 4 sigma along every axis
    assert np.all(np.abs(fix.C - TRUE_C) < 4 * np.sqrt(np.diag(fix.cov)) + 1e-4)
    # without the second judgement the eight points alone reject the frame
    monkeypatch.setattr(outline_pose, "MAX_OUTLIER_FRACTION", 0.0)
    assert _solve(_targets(stray=8)) is None


def test_a_wrong_id_still_rejects_the_fit():
    assert _solve(_targets(wrong_id=True)) is None
