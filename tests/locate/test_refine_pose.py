"""The centroid + range pose refinement (receiver/locate/_pnp.pyx through `pose.refine_pose`,
`solve_fix`): its residuals the model's (reprojection as OpenCV projects) and its Jacobian
their derivative, known poses recovered from noise-free scenes with every robust loss and prior,
angles-only fixes equal to OpenCV's `solvePnP` on the same points, the right P3P candidate
picked, unknown losses and bad arrays refused with a one-line error."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from receiver.locate import pose
from receiver.locate.pose import KERNEL_LOSSES, refine_pose, solve_fix, ypr_to_rotation

CEILING_M = 3.0


def _scene(seed: int, n: int, *, collinear=False, missing=(), px_noise=0.0, range_noise=0.0):
    """n ceiling LEDs seen from a random pose below them: (L, uv, d, sigma_d, R, C)."""
    rng = np.random.default_rng(seed)
    if collinear:
        L = np.column_stack([np.full(n, 1.0), np.linspace(0.0, 0.5 * (n - 1), n), np.full(n, CEILING_M)])
    else:
        L = np.column_stack([rng.uniform(0, 3, n), rng.uniform(0, 3, n), np.full(n, CEILING_M)])
    C = np.array([1.2, 1.3, 1.2]) + rng.normal(0, 0.3, 3)
    R = ypr_to_rotation(rng.uniform(-180, 180), 82 + rng.uniform(-6, 6), rng.uniform(-6, 6))
    X = (L - C) @ R.T
    uv = X[:, :2] / X[:, 2:] + rng.normal(0, px_noise, (n, 2))
    d = np.linalg.norm(L - C, axis=1) + rng.normal(0, range_noise, n)
    d[list(missing)] = np.nan
    return L, uv, d, np.full(n, 0.01), R, C


def _start(R, C, seed, turn_rad=0.05, shift_m=0.1):
    rng = np.random.default_rng(100 + seed)
    return cv2.Rodrigues(rng.normal(0, turn_rad, 3))[0] @ R, C + rng.normal(0, shift_m, 3)


def _expected_residuals(p, L, uv, sigma_uv, d, sd, up, up_sigma, C_prior, W):
    """The whitened residuals at pose p from their definition: reprojection by OpenCV's
    `projectPoints` (identity camera: normalised units), the finite ranges, the tilt prior (world
    up seen from the camera) and the position prior."""
    R = cv2.Rodrigues(p[:3])[0]
    tvec = -R @ p[3:]
    proj = cv2.projectPoints(L.reshape(-1, 1, 3), p[:3], tvec, np.eye(3), None)[0].reshape(-1, 2)
    parts = [((proj - uv) / sigma_uv).ravel()]
    has = np.isfinite(d)
    parts.append((np.linalg.norm(L[has] - p[3:], axis=1) - d[has]) / sd[has])
    if up is not None:
        parts.append((R[:, 2] - up) / up_sigma)
    if C_prior is not None:
        parts.append(W @ (p[3:] - C_prior))
    return np.concatenate(parts)


@pytest.mark.parametrize("prior", ["none", "tilt", "tilt+position"])
def test_kernel_residuals_are_the_model_and_the_jacobian_its_derivative(prior):
    """The kernel's residuals are the model's (reprojection as cv2.projectPoints, ranges, priors)
    to rounding, and its analytic Jacobian equals their central differences."""
    from receiver.locate.lsq import _jacobian
    L, uv, d, sd, R, C = _scene(3, 5, missing=(2,), px_noise=3e-4)
    up = np.array([0.0, 0.1, 0.99]) if prior != "none" else None
    C_prior, cov = (C + 0.1, np.diag([0.01, 0.02, 0.04]) + 0.001) if prior == "tilt+position" else (None, None)
    W = None if cov is None else np.linalg.cholesky(np.linalg.inv(cov)).T   # W^T W = cov^-1
    rv = cv2.Rodrigues(R)[0].ravel()
    P = np.array([np.concatenate([rv + 0.05, C + 0.03]), np.concatenate([rv, C]), np.concatenate([-rv, C - 0.1])])
    args = pose._kernel_args(L, uv, 3e-4, d, sd, up, 0.2, C_prior, cov)
    r, J = pose._evaluate_native(args, P, jacobian=True)

    def fun(q):
        return pose._evaluate_native(args, q)[0][0]
    for k, p in enumerate(P):
        want = _expected_residuals(p, L, uv, 3e-4, d, sd, up, 0.2, C_prior, W)
        assert r[k].shape == want.shape and J[k].shape == (len(want), 6)
        assert np.abs(r[k] - want).max() <= 1e-9 * max(1.0, np.abs(want).max())
        Jn = _jacobian(fun, p)
        assert np.abs(J[k] - Jn).max() <= 1e-6 * np.abs(Jn).max()


@pytest.mark.parametrize("loss", sorted(KERNEL_LOSSES))
@pytest.mark.parametrize("seed", range(6))
def test_known_pose_is_recovered(loss, seed):
    """Noise-free angles and ranges (one range missing on some seeds), the tilt prior at the
    true up direction: the refinement lands on the true pose with zero residuals."""
    L, uv, d, sd, R, C = _scene(seed, 3 + seed % 4, missing=(0,) if seed % 3 == 0 else ())
    R0, C0 = _start(R, C, seed)
    R1, C1, cov, chi2, dof = refine_pose(L, uv, 3e-4, d, sd, R0, C0, loss=loss, R_prior=R,
                                         tilt_sigma_rad=math.radians(10))
    assert np.abs(C1 - C).max() < 1e-7 and np.abs(R1 - R).max() < 1e-7
    assert chi2 < 1e-8 and dof == 2 * len(L) + int(np.isfinite(d).sum()) + 3 - 6
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_far_starts_converge():
    """Starts 0.3 rad and 0.4 m off (the damping must grow): still the true pose."""
    for seed in range(8):
        L, uv, d, sd, R, C = _scene(seed, 4 + seed % 3, missing=(1,))
        R0, C0 = _start(R, C, seed, turn_rad=0.3, shift_m=0.4)
        R1, C1, *_ = refine_pose(L, uv, 3e-4, d, sd, R0, C0, R_prior=R, tilt_sigma_rad=math.radians(10))
        assert np.abs(C1 - C).max() < 1e-6, seed


@pytest.mark.parametrize("seed", range(5))
def test_angles_only_fix_equals_opencv_solvepnp(seed):
    """Noisy image points, no ranges, no prior, linear loss: the least-squares reprojection fit
    OpenCV's iterative solvePnP makes (K = I: normalized units) from the same start, within the
    two solvers' stopping tolerances (10 um against a fix 1-sigma of millimetres) and at a cost
    no higher than OpenCV's."""
    L, uv, _, sd, R, C = _scene(seed, 6, px_noise=3e-4)
    d = np.full(len(L), np.nan)
    R0, C0 = _start(R, C, seed)
    R1, C1, *_ = refine_pose(L, uv, 3e-4, d, sd, R0, C0, loss="linear")
    rvec0, tvec0 = cv2.Rodrigues(R0)[0], (-R0 @ C0).reshape(3, 1)
    ok, rvec, tvec = cv2.solvePnP(L, uv, np.eye(3), None, rvec0, tvec0, useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    assert ok
    R_cv = cv2.Rodrigues(rvec)[0]
    C_cv = -R_cv.T @ tvec.ravel()
    assert np.abs(C1 - C_cv).max() < 1e-5 and np.abs(R1 - R_cv).max() < 1e-5

    def cost(R_, C_):
        X = (L - C_) @ R_.T
        return float(np.sum((X[:, :2] / X[:, 2:] - uv) ** 2))
    assert cost(R1, C1) <= cost(R_cv, C_cv) * (1 + 1e-6)


def test_two_collinear_leds_with_position_prior():
    """`solve_fix`'s collinear path (2-3 LEDs on a line from `init_two`, tilt prior, the tracked
    position as a prior): the true pose from noise-free data."""
    for seed in range(4):
        L, uv, d, sd, R, C = _scene(seed, 2 + seed % 2, collinear=True)
        fix = solve_fix(L, uv, d, sd, sigma_uv=3e-4, R_prior=R, C_prior=C, C_prior_cov=np.eye(3) * 0.01,
                        tilt_prior_R=R)
        assert fix is not None and fix.method == "range+angle"
        assert np.abs(fix.C - C).max() < 1e-6 and np.abs(fix.R_cw - R).max() < 1e-6


@pytest.mark.parametrize("solver", ["auto", "pnp"])
def test_solve_fix_from_pnp_candidates(solver):
    """n >= 3 LEDs: the P3P / SQPnP candidates scored and refined to the true pose."""
    for seed in range(8):
        L, uv, d, sd, R, C = _scene(seed, 3 + seed % 4, missing=(0,) if seed % 2 else ())
        fix = solve_fix(L, uv, d, sd, sigma_uv=3e-4, solver=solver, tilt_prior_R=R, C_prior=C)
        assert fix is not None and fix.method == ("range+angle" if solver == "auto" else "pnp")
        assert np.abs(fix.C - C).max() < 1e-6, (seed, solver)


def test_best_candidate_is_the_true_pose():
    L, uv, d, sd, R, C = _scene(11, 3)
    cands = pose.pnp_candidates(L, uv)
    assert len(cands) >= 2
    for prior in (None, C + 0.3):
        _, C_best = pose._best_candidate(cands, L, uv, 3e-4, d, sd, None, 1.0, prior)
        assert np.abs(C_best - C).max() < 1e-6


def test_unknown_loss_is_refused():
    L, uv, d, sd, R, C = _scene(2, 5)
    with pytest.raises(ValueError, match="unknown loss 'arctan'"):
        refine_pose(L, uv, 3e-4, d, sd, R, C, loss="arctan")


def test_bad_arrays_are_refused():
    L, uv, d, sd, R, C = _scene(1, 4)
    args = list(pose._kernel_args(L, uv, 3e-4, d, sd, None, 1.0))
    p = np.zeros(6)
    m = 2 * 4 + 4                                  # 2 per LED, 4 ranges, no prior
    r, J = np.empty(m), np.empty((m, 6))
    assert pose._pnp.refine(*args, p.copy(), 1, 3.0, 50, 1e-8, 1e-8, r, J)[0] == m
    with pytest.raises(ValueError, match="inconsistent pose arrays"):
        bad = list(args)
        bad[1] = np.ascontiguousarray(uv[:3])
        pose._pnp.refine(*bad, p, 1, 3.0, 50, 1e-8, 1e-8, r, J)
    with pytest.raises(ValueError, match="inconsistent pose arrays"):
        bad = list(args)
        bad[5] = np.zeros(2)                       # a tilt prior must be 3 numbers (or none)
        pose._pnp.refine(*bad, p, 1, 3.0, 50, 1e-8, 1e-8, r, J)
    with pytest.raises(ValueError, match="inconsistent pose output arrays"):
        pose._pnp.refine(*args, p, 1, 3.0, 50, 1e-8, 1e-8, np.empty(m - 1), J)
    with pytest.raises(ValueError, match="inconsistent pose output arrays"):
        pose._pnp.evaluate(*args, np.zeros((2, 6)), np.empty((1, m)), np.empty((0, 0, 6)))
