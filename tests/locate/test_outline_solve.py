"""The outline solve (receiver/locate/_outline.pyx through `outline_pose.solve_outline_pose`):
known poses recovered from noise-free circles with a position prior, the recorded warm starts
fitted alike with every robust loss, a circle seen edge-on kept out of the fit, the covariance's
Cholesky inverse equal to numpy's pseudo-inverse, unknown losses refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from receiver.locate import outline_pose
from tests.locate.test_outline_speed import STATIC, WALK, _warm_problem

C_TRUE = np.array([0.0, 0.0, 1.0])      # below a 3 m ceiling, looking straight up (R_cw = I)


def _exact_circles(rng, n):
    """n circles on the 3 m ceiling and their edge points as the camera at C_TRUE sees them
    (normalized units, no noise, sigma 1e-3)."""
    out = []
    for _ in range(n):
        xyz = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 3.0])
        r = rng.uniform(0.05, 0.15)
        a = rng.uniform(0, 2 * np.pi, 40)
        pts = (xyz[:2] - C_TRUE[:2] + r * np.column_stack([np.cos(a), np.sin(a)])) / (xyz[2] - C_TRUE[2])
        out.append(outline_pose.OutlineTarget(xyz, "circle", (r, r), pts, np.full(40, 1e-3)))
    return out


@pytest.mark.parametrize("n", [1, 4])
def test_circles_with_a_position_prior_give_the_true_pose(n):
    """From a start 1 cm and ~1 degree off, with the tracked position as a prior (a lone circle
    leaves its turn about the normal to it): the true camera centre within the solve's few
    iterations (10 um), residuals near zero."""
    rng = np.random.default_rng(3)
    targets = _exact_circles(rng, n)
    R0 = cv2.Rodrigues(np.array([0.01, -0.015, 0.02]))[0]
    fix = outline_pose.solve_outline_pose(targets, R0, C_TRUE + 0.01, focal_px=1000.0,
                                          up_prior=np.array([0.0, 0.0, 1.0]), C_prior=C_TRUE,
                                          C_prior_cov=np.diag([1e-4, 2e-4, 3e-4]))
    assert fix is not None and fix.method == "outline" and fix.n_leds == n
    assert np.abs(fix.C - C_TRUE).max() < 1e-5 and fix.chi2 < 1e-5
    if n > 1:
        assert np.abs(fix.R_cw - np.eye(3)).max() < 1e-5
    # A lone circle without the prior: no fix.
    assert outline_pose.solve_outline_pose(targets[:1], R0, C_TRUE, focal_px=1000.0) is None


@pytest.fixture(scope="module", params=[(WALK, 20), (WALK, 40), (STATIC, 10)], ids=["walk20", "walk40", "static10"])
def warm(request):
    return _warm_problem(*request.param)


def test_every_loss_fits_the_recorded_frames_alike(warm):
    """The bundled recordings' warm starts (rects; squares + circles + rects) fitted with each
    robust loss: each a good fit (chi^2 per dof below 4), all within 2 mm of each other."""
    targets, R0, C0, kw = warm
    fixes = []
    for loss in sorted(outline_pose.LOSS_CODES):
        fix = outline_pose.solve_outline_pose(targets, R0, C0, **dict(kw, loss=loss))
        assert fix is not None and fix.chi2 / fix.dof < 4.0, loss
        assert np.all(np.linalg.eigvalsh(fix.cov) > 0)
        fixes.append(fix.C)
    assert np.ptp(np.array(fixes), axis=0).max() < 2e-3


def test_a_circle_seen_edge_on_adds_fixed_residuals_and_no_gradient():
    """A circle at the camera's own height (a degenerate conic) gets residuals of 1e3 in the
    kernel's raw outputs, and the pose stays finite."""
    rng = np.random.default_rng(1)
    targets = _exact_circles(rng, 5)
    flat = outline_pose.OutlineTarget(np.array([0.5, 0.0, 1.0]), "circle", (0.1, 0.1), targets[0].pts,
                                      targets[0].sigma)
    targets = [flat] + targets[1:]
    p0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    args = (p0, 1000.0, 1.5e-3, np.array([0.0, 0.0, 1.0]), 0.17, None, None, "soft_l1", 3.0, 1, 1)
    p, R, chi2, n_res, JtJ, _ = outline_pose._solve_native(outline_pose.OutlineFrame.from_targets(targets), *args)
    assert n_res == sum(len(t.pts) for t in targets) + 3
    assert chi2 > len(targets[0].pts) * 1e6 * 0.99
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(R)) and np.all(np.isfinite(JtJ))


def test_cholesky_covariance_equals_the_pseudo_inverse():
    """`_covariance6` inverts a well-conditioned J^T J by Cholesky in the kernel (equal to
    np.linalg.pinv to rounding) and hands a singular or ill-conditioned one (a lone circle's free
    rotation) to np.linalg.pinv itself."""
    k = outline_pose._outline
    rng = np.random.default_rng(5)
    for scale in (1.0, 1e-4, 1e6):
        J = rng.normal(size=(40, 6)) * np.array([1.0, 2.0, 0.5, 30.0, 10.0, 3.0]) * scale
        A = J.T @ J
        out = np.empty((6, 6))
        assert k.spd_inverse(A, out, outline_pose.SPD_MIN_PIVOT_RATIO)
        ref = np.linalg.pinv(A)
        assert np.allclose(out, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
        assert np.array_equal(out, out.T)
    J = rng.normal(size=(40, 6))
    J[:, 2] = 0.0                                         # a direction the data leave free
    A = J.T @ J
    out = np.full((6, 6), 7.0)
    assert not k.spd_inverse(A, out, outline_pose.SPD_MIN_PIVOT_RATIO)
    assert np.all(out == 7.0)
    assert np.array_equal(outline_pose._covariance6(A), np.linalg.pinv(A))
    A[2, 2] = 1e-14 * A[0, 0]                             # nearly singular: also the pseudo-inverse
    assert np.array_equal(outline_pose._covariance6(A), np.linalg.pinv(A))
    bad = np.full((6, 6), np.nan)
    assert not k.spd_inverse(bad, out, outline_pose.SPD_MIN_PIVOT_RATIO)


def test_unknown_loss_is_refused():
    targets = _exact_circles(np.random.default_rng(0), 3)
    with pytest.raises(ValueError, match="unknown loss 'arctan'"):
        outline_pose.solve_outline_pose(targets, np.eye(3), C_TRUE, focal_px=1000.0, loss="arctan",
                                        C_prior=C_TRUE, C_prior_cov=np.eye(3) * 1e-4)
