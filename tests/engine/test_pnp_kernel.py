"""The compiled centroid + range pose refinement (receiver/locate/_pnp.pyx) against its numpy
reference (`pose._joint_fun` + `lsq.robust_lm_rj`, run with `pose._k` set to None): the same
residuals and Jacobian, the same solution, residuals and covariance to rounding (the kernel sums
the normal equations in another order), with every robust loss, every prior, missing ranges, 2
collinear LEDs from `init_two`'s start, far starts that need damping changes; `solve_fix` and the
`PoseFilter` cold start (PnP candidates scored by the kernel) give the same fixes; bad arrays are
refused with a one-line error."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from receiver.locate import pose
from receiver.locate.lsq import robust_lm_rj
from receiver.locate.pose import _joint_fun, refine_pose, solve_fix, ypr_to_rotation

pytestmark = pytest.mark.skipif(pose._k is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")

CEILING_M = 3.0
LOSSES = ["soft_l1", "linear", "huber", "cauchy"]


def _scene(seed: int, n: int, *, collinear=False, missing=(), px_noise=3e-4, range_noise=0.01):
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


def _pure(monkeypatch, fn, *args, **kw):
    with monkeypatch.context() as m:
        m.setattr(pose, "_k", None)
        return fn(*args, **kw)


def _assert_same_refine(native, pure, tol=1e-9):
    (R1, C1, cov1, chi1, dof1), (R2, C2, cov2, chi2, dof2) = native, pure
    assert np.abs(C1 - C2).max() <= tol and np.abs(R1 - R2).max() <= tol
    assert dof1 == dof2
    assert math.isclose(chi1, chi2, rel_tol=1e-8, abs_tol=1e-10)
    assert np.allclose(cov1, cov2, rtol=1e-7, atol=1e-9 * np.abs(cov2).max())


@pytest.mark.parametrize("prior", ["none", "tilt", "tilt+position"])
def test_residuals_and_jacobian_equal_joint_fun(prior):
    L, uv, d, sd, R, C = _scene(3, 5, missing=(2,))
    up = np.array([0.0, 0.1, 0.99]) if prior != "none" else None
    kw = dict(C_prior=C + 0.1, C_prior_cov=np.diag([0.01, 0.02, 0.04]) + 0.001) if prior == "tilt+position" else {}
    fun = _joint_fun(L, uv, 3e-4, d, sd, up, 0.2, **kw)
    rv = cv2.Rodrigues(R)[0].ravel()
    P = np.array([np.concatenate([rv + 0.05, C + 0.03]), np.concatenate([rv, C]), np.concatenate([-rv, C - 0.1])])
    args = pose._kernel_args(L, uv, 3e-4, d, sd, up, 0.2, kw.get("C_prior"), kw.get("C_prior_cov"))
    r, J = pose._evaluate_native(args, P, jacobian=True)
    for k, p in enumerate(P):
        r_ref, J_ref = fun(p), fun.jac(p)
        assert r[k].shape == r_ref.shape and J[k].shape == J_ref.shape
        assert np.abs(r[k] - r_ref).max() <= 1e-12 * max(1.0, np.abs(r_ref).max())
        assert np.abs(J[k] - J_ref).max() <= 1e-12 * np.abs(J_ref).max()


@pytest.mark.parametrize("loss", LOSSES)
@pytest.mark.parametrize("seed", range(6))
def test_refine_pose_equals_numpy(monkeypatch, loss, seed):
    n = 3 + seed % 4
    L, uv, d, sd, R, C = _scene(seed, n, missing=(0,) if seed % 3 == 0 else ())
    rng = np.random.default_rng(100 + seed)
    R0, C0 = cv2.Rodrigues(rng.normal(0, 0.05, 3))[0] @ R, C + rng.normal(0, 0.1, 3)
    kw = dict(loss=loss, R_prior=np.eye(3), tilt_sigma_rad=math.radians(10))
    native = refine_pose(L, uv, 3e-4, d, sd, R0, C0, **kw)
    pure = _pure(monkeypatch, refine_pose, L, uv, 3e-4, d, sd, R0, C0, **kw)
    _assert_same_refine(native, pure)
    assert np.abs(native[1] - C).max() < 0.1      # and it is a fix of the scene, not a common failure


def test_lm_path_equals_robust_lm_rj_from_far_starts():
    """Starts far enough for rejected steps (the damping grows) and many iterations: the kernel's
    solution, residuals and Jacobian equal `robust_lm_rj` on `_joint_fun` to rounding."""
    for seed in range(8):
        L, uv, d, sd, R, C = _scene(seed, 4 + seed % 3, missing=(1,))
        up = np.array([0.0, 0.0, 1.0])
        fun = _joint_fun(L, uv, 3e-4, d, sd, up, math.radians(10))
        rng = np.random.default_rng(seed)
        p0 = np.concatenate([cv2.Rodrigues(R)[0].ravel() + rng.normal(0, 0.3, 3), C + rng.normal(0, 0.4, 3)])
        x_ref, r_ref, J_ref = robust_lm_rj(fun, fun.jac, p0)
        x, r, J = pose._refine_native(pose._kernel_args(L, uv, 3e-4, d, sd, up, math.radians(10)), p0, "soft_l1", 3.0)
        assert np.abs(x - x_ref).max() <= 1e-9
        assert np.abs(r - r_ref).max() <= 1e-6 * max(1.0, np.abs(r_ref).max())
        assert np.abs(J - J_ref).max() <= 1e-9 * np.abs(J_ref).max()


def test_two_collinear_leds_with_position_prior(monkeypatch):
    """The collinear path of `solve_fix`: 2 LEDs from `init_two`, tilt prior, the tracked position
    as a prior (left out of the covariance, which the kernel evaluates without it)."""
    for seed in range(4):
        L, uv, d, sd, R, C = _scene(seed, 2 + seed % 2, collinear=True)
        kw = dict(sigma_uv=3e-4, R_prior=np.eye(3), C_prior=C + 0.02, C_prior_cov=np.eye(3) * 0.01,
                  tilt_prior_R=np.eye(3))
        native = solve_fix(L, uv, d, sd, **kw)
        pure = _pure(monkeypatch, solve_fix, L, uv, d, sd, **kw)
        assert native is not None and pure is not None
        assert native.method == pure.method == "range+angle" and native.dof == pure.dof
        assert np.abs(native.C - pure.C).max() <= 1e-9 and np.abs(native.R_cw - pure.R_cw).max() <= 1e-9
        assert np.allclose(native.cov, pure.cov, rtol=1e-7, atol=1e-9 * np.abs(pure.cov).max())
        assert math.isclose(native.chi2, pure.chi2, rel_tol=1e-8, abs_tol=1e-10)


@pytest.mark.parametrize("solver", ["auto", "pnp"])
def test_solve_fix_candidates_and_refinement_equal_numpy(monkeypatch, solver):
    """n >= 3 LEDs: PnP candidates scored (kernel residuals) and refined: the same fixes."""
    for seed in range(8):
        L, uv, d, sd, R, C = _scene(seed, 3 + seed % 4, missing=(0,) if seed % 2 else ())
        kw = dict(sigma_uv=3e-4, solver=solver, tilt_prior_R=np.eye(3), C_prior=C + 0.05)
        native = solve_fix(L, uv, d, sd, **kw)
        pure = _pure(monkeypatch, solve_fix, L, uv, d, sd, **kw)
        assert (native is None) == (pure is None)
        if pure is None:
            continue
        assert native.method == pure.method and native.dof == pure.dof and native.n_leds == pure.n_leds
        assert np.abs(native.C - pure.C).max() <= 1e-9 and np.abs(native.R_cw - pure.R_cw).max() <= 1e-9
        assert math.isclose(native.chi2, pure.chi2, rel_tol=1e-8, abs_tol=1e-10)


def test_best_candidate_equals_numpy(monkeypatch):
    """With several P3P poses to choose from, the kernel-scored choice is the numpy one."""
    L, uv, d, sd, R, C = _scene(11, 3, px_noise=0.0)
    cands = pose.pnp_candidates(L, uv)
    assert len(cands) >= 2
    for prior in (None, C + 0.3):
        a = pose._best_candidate(cands, L, uv, 3e-4, d, sd, None, 1.0, prior)
        b = _pure(monkeypatch, pose._best_candidate, cands, L, uv, 3e-4, d, sd, None, 1.0, prior)
        assert a is b


def test_poor_starts_fail_the_same_way(monkeypatch):
    """Every LED behind the camera (the clamp at z = 1e-6): both paths stop with the same pose."""
    L, uv, d, sd, R, C = _scene(5, 4)
    R0 = np.diag([1.0, -1.0, -1.0]) @ R
    kw = dict(R_prior=np.eye(3), tilt_sigma_rad=math.radians(10))
    native = refine_pose(L, uv, 3e-4, d, sd, R0, C, **kw)
    pure = _pure(monkeypatch, refine_pose, L, uv, 3e-4, d, sd, R0, C, **kw)
    assert np.abs(native[1] - pure[1]).max() <= 1e-8 and native[4] == pure[4]


def _recorded_solves(folder, n_frames):
    """`solve_fix`'s calls (args, kwargs) in the first frames of a bundled recording: the cold
    starts before the outline tracking takes over (2 and 4 collinear LEDs, 3 and 4 LEDs by PnP,
    the handedness check's mirror solve)."""
    from receiver.io.camera import load_camera
    from receiver.io.ledmap import load_map
    from receiver.io.sources import open_source
    from receiver.locate import posefilter
    from receiver.locate.indoor import Positioner
    from receiver.pipeline import Receiver
    cam, led_map = load_camera(str(folder / "camera.yaml")), load_map(str(folder / "map.json"))
    rx = Receiver(cam, led_map, positioner=Positioner(cam, led_map))
    calls = []
    real = posefilter.solve_fix

    def spy(*args, **kw):
        calls.append((args, kw))
        return real(*args, **kw)

    posefilter.solve_fix = spy
    try:
        for i, f in enumerate(open_source(str(folder))):
            rx.process(f)
            if i + 1 == n_frames:
                break
    finally:
        posefilter.solve_fix = real
    return calls


@pytest.mark.parametrize("name, n_frames", [("indoor-walk", 5), ("indoor-sparse", 7)])
def test_recorded_cold_starts_equal_numpy(monkeypatch, name, n_frames):
    from pathlib import Path
    folder = Path(__file__).resolve().parents[2] / "recordings" / name
    calls = _recorded_solves(folder, n_frames)
    assert len(calls) >= 4
    n_fixes = 0
    for args, kw in calls:
        native = solve_fix(*args, **kw)
        pure = _pure(monkeypatch, solve_fix, *args, **kw)
        assert (native is None) == (pure is None)
        if pure is None:
            continue
        n_fixes += 1
        assert native.method == pure.method and native.dof == pure.dof
        assert np.abs(native.C - pure.C).max() <= 1e-9 and np.abs(native.R_cw - pure.R_cw).max() <= 1e-9
        assert np.allclose(native.cov, pure.cov, rtol=1e-7, atol=1e-9 * np.abs(pure.cov).max())
        assert math.isclose(native.chi2, pure.chi2, rel_tol=1e-8, abs_tol=1e-10)
    assert n_fixes >= 4


def test_other_losses_fall_back_to_scipy(monkeypatch):
    """A loss the kernel does not implement (scipy's "arctan") takes least_squares on both paths."""
    L, uv, d, sd, R, C = _scene(2, 5)
    R0 = cv2.Rodrigues(np.array([0.02, -0.01, 0.03]))[0] @ R
    native = refine_pose(L, uv, 3e-4, d, sd, R0, C + 0.05, loss="arctan")
    pure = _pure(monkeypatch, refine_pose, L, uv, 3e-4, d, sd, R0, C + 0.05, loss="arctan")
    assert np.array_equal(native[1], pure[1]) and np.abs(native[1] - C).max() < 0.05


def test_bad_arrays_are_refused():
    L, uv, d, sd, R, C = _scene(1, 4)
    args = list(pose._kernel_args(L, uv, 3e-4, d, sd, None, 1.0))
    p = np.zeros(6)
    m = 2 * 4 + 4                                  # 2 per LED, 4 ranges, no prior
    r, J = np.empty(m), np.empty((m, 6))
    assert pose._k.refine(*args, p.copy(), 1, 3.0, 50, 1e-8, 1e-8, r, J)[0] == m
    with pytest.raises(ValueError, match="inconsistent pose arrays"):
        bad = list(args)
        bad[1] = np.ascontiguousarray(uv[:3])
        pose._k.refine(*bad, p, 1, 3.0, 50, 1e-8, 1e-8, r, J)
    with pytest.raises(ValueError, match="inconsistent pose arrays"):
        bad = list(args)
        bad[5] = np.zeros(2)                       # a tilt prior must be 3 numbers (or none)
        pose._k.refine(*bad, p, 1, 3.0, 50, 1e-8, 1e-8, r, J)
    with pytest.raises(ValueError, match="inconsistent pose output arrays"):
        pose._k.refine(*args, p, 1, 3.0, 50, 1e-8, 1e-8, np.empty(m - 1), J)
    with pytest.raises(ValueError, match="inconsistent pose output arrays"):
        pose._k.evaluate(*args, np.zeros((2, 6)), np.empty((1, m)), np.empty((0, 0, 6)))
