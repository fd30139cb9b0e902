"""The compiled outline solve (receiver/locate/_outline.pyx) against its numpy reference
(`outline_pose._solve_numpy`, run with the module's `_k` set to None): the same fix -- position,
orientation, chi^2, covariance -- to rounding (the kernel sums in another order), on real warm
starts of the bundled recordings (rects, squares + circles + rects), on synthetic circles with a
position prior, with every robust loss, from a far start, and with a circle seen edge-on."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from receiver.locate import outline_pose
from tests.locate.test_outline_speed import STATIC, WALK, _circle_targets, _warm_problem

pytestmark = pytest.mark.skipif(outline_pose._k is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")


def _both(monkeypatch, *args, **kw):
    native = outline_pose.solve_outline_pose(*args, **kw)
    with monkeypatch.context() as m:
        m.setattr(outline_pose, "_k", None)
        pure = outline_pose.solve_outline_pose(*args, **kw)
    return native, pure


def _assert_same(native, pure, pos_tol=1e-9):
    assert (native is None) == (pure is None)
    if pure is None:
        return
    assert np.abs(native.C - pure.C).max() <= pos_tol
    assert np.abs(native.R_cw - pure.R_cw).max() <= 1e-8
    assert native.dof == pure.dof and native.n_leds == pure.n_leds and native.method == pure.method
    assert math.isclose(native.chi2, pure.chi2, rel_tol=1e-7, abs_tol=1e-9)
    assert np.allclose(native.cov, pure.cov, rtol=1e-6, atol=1e-6 * np.abs(pure.cov).max())


@pytest.fixture(scope="module", params=[(WALK, 20), (WALK, 40), (STATIC, 10)], ids=["walk20", "walk40", "static10"])
def warm(request):
    return _warm_problem(*request.param)


@pytest.mark.parametrize("loss", ["soft_l1", "linear", "huber", "cauchy"])
def test_native_equals_numpy_on_recorded_frames(monkeypatch, warm, loss):
    targets, R0, C0, kw = warm
    kw = dict(kw, loss=loss)
    native, pure = _both(monkeypatch, targets, R0, C0, **kw)
    assert pure is not None
    _assert_same(native, pure)


def test_native_edge_offset_gram_equals_numpy(warm):
    """The kernel's edge-offset gram (from its per-edge sums at the final pose) is
    `_edge_offset_gram` of the same labels and pose, and it moves the covariance (not zero)."""
    targets, R0, C0, kw = warm
    frame = outline_pose.OutlineFrame.from_targets(targets)
    args = (np.concatenate([cv2.Rodrigues(R0)[0].ravel(), C0]), kw["focal_px"], kw["centroid_sigma_px"] / kw["focal_px"],
            kw["up_prior"], kw["tilt_sigma_rad"], None, None, kw["loss"], kw["f_scale"], 2, outline_pose.MAX_ITER)
    p, _, _, _, _, lab, G = outline_pose._solve_native(frame, *args)
    ref = outline_pose._edge_offset_gram(targets, p, kw["focal_px"], lab)
    assert np.abs(ref).max() > 0.0
    assert np.allclose(G, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    assert np.array_equal(G, G.T)


def test_native_equals_numpy_from_a_far_start(monkeypatch, warm):
    """More iterations, a second assignment round and damping changes: still the same path."""
    targets, R0, C0, kw = warm
    native, pure = _both(monkeypatch, targets, R0, C0 + np.array([0.02, -0.015, 0.01]), **kw)
    assert pure is not None
    _assert_same(native, pure, pos_tol=1e-8)


def test_native_equals_numpy_with_a_position_prior_and_one_circle(monkeypatch):
    rng = np.random.default_rng(3)
    targets = _circle_targets(rng, n=4)
    C_true = np.array([0.05, -0.02, 1.0])
    R0 = np.eye(3)
    kw = {"focal_px": 1000.0, "up_prior": np.array([0.0, 0.0, 1.0])}
    prior = {"C_prior": C_true + 0.01, "C_prior_cov": np.diag([1e-4, 2e-4, 3e-4])}
    native, pure = _both(monkeypatch, targets, R0, C_true, **kw, **prior)
    assert pure is not None
    _assert_same(native, pure)
    # One circle: its rotation about the normal is left to the prior.
    native, pure = _both(monkeypatch, targets[:1], R0, C_true, **kw, **prior)
    assert pure is not None
    _assert_same(native, pure)
    # ... and without the prior no fix at all, on both paths.
    assert _both(monkeypatch, targets[:1], R0, C_true, **kw) == (None, None)


def test_native_equals_numpy_with_a_circle_seen_edge_on():
    """A circle at the camera's own height gets residuals of 1e3 and no gradient on both paths
    (compared before `solve_outline_pose` drops such a pose: the kernel's raw outputs)."""
    rng = np.random.default_rng(1)
    targets = _circle_targets(rng)
    flat = outline_pose.OutlineTarget(np.array([0.5, 0.0, 1.0]), "circle", (0.1, 0.1), targets[0].pts,
                                      targets[0].sigma)
    p0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])       # at the flat circle's height: a degenerate conic
    targets = [flat] + targets[1:]
    args = (p0, 1000.0, 1.5e-3, np.array([0.0, 0.0, 1.0]), 0.17, None, None, "soft_l1", 3.0, 1, 1)
    p_n, R_n, chi2_n, n_n, JtJ_n, _, _ = outline_pose._solve_native(outline_pose.OutlineFrame.from_targets(targets), *args)
    p_p, R_p, chi2_p, n_p, JtJ_p, _, _ = outline_pose._solve_numpy(targets, *args)
    assert n_n == n_p == sum(len(t.pts) for t in targets) + 3
    assert chi2_p > len(targets[0].pts) * 1e6 * 0.99                  # the 1e3 residuals are in
    assert math.isclose(chi2_n, chi2_p, rel_tol=1e-9)
    assert np.abs(p_n - p_p).max() <= 1e-9 and np.abs(R_n - R_p).max() <= 1e-9
    assert np.allclose(JtJ_n, JtJ_p, rtol=1e-7, atol=1e-9 * np.abs(JtJ_p).max())


def test_cholesky_covariance_equals_the_pseudo_inverse():
    """`_covariance6` inverts a well-conditioned J^T J by Cholesky in the kernel (equal to
    np.linalg.pinv to rounding) and hands a singular or ill-conditioned one (a lone circle's free
    rotation) to np.linalg.pinv itself."""
    rng = np.random.default_rng(5)
    for scale in (1.0, 1e-4, 1e6):
        J = rng.normal(size=(40, 6)) * np.array([1.0, 2.0, 0.5, 30.0, 10.0, 3.0]) * scale
        A = J.T @ J
        out = np.empty((6, 6))
        assert outline_pose._k.spd_inverse(A, out, outline_pose.SPD_MIN_PIVOT_RATIO)
        ref = np.linalg.pinv(A)
        assert np.allclose(out, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
        assert np.array_equal(out, out.T)
    J = rng.normal(size=(40, 6))
    J[:, 2] = 0.0                                         # a direction the data leave free
    A = J.T @ J
    out = np.full((6, 6), 7.0)
    assert not outline_pose._k.spd_inverse(A, out, outline_pose.SPD_MIN_PIVOT_RATIO)
    assert np.all(out == 7.0)
    assert np.array_equal(outline_pose._covariance6(A), np.linalg.pinv(A))
    A[2, 2] = 1e-14 * A[0, 0]                             # nearly singular: also the pseudo-inverse
    assert np.array_equal(outline_pose._covariance6(A), np.linalg.pinv(A))
    bad = np.full((6, 6), np.nan)
    assert not outline_pose._k.spd_inverse(bad, out, outline_pose.SPD_MIN_PIVOT_RATIO)
