"""Positioning: decoded LEDs -> camera position (and orientation), then Kalman tracking.

Frames and conventions
* World: metres, x, y on the floor, z up; LEDs hang on the ceiling facing down.
* Camera: OpenCV (x right, y down, z along the optical axis). ``R_cw`` is the world-to-camera
  rotation, ``X_cam = R_cw @ (X_world - C)``; ``C`` the camera centre in the world (the output
  position). ``R_cw`` is a proper rotation (det = +1).
* Image points given to the solvers are undistorted *normalized* coordinates (x/z, y/z).

Solvers (`solve_fix`, chosen by the number of usable LEDs n and ranges k):
* ``"multilateration"`` (ranges only, thesis eqs. 26-34): the linear system of eq. 27,
  ``[1, -2x_L, -2y_L, -2z_L] [|C|^2, x, y, z]^T = d^2 - |L|^2``. With LEDs off one plane it has
  full rank and eq. 34 solves it; LEDs on one ceiling leave a one-dimensional null space, so
  ``x = x_p + eps x_h`` (eq. 29) and the constraint ``x_0 = x_1^2 + x_2^2 + x_3^2`` gives the two
  roots of eqs. 30-31: the mirror image above the ceiling is rejected. Then a robust nonlinear
  refinement (`scipy.optimize.least_squares`) of the range residuals weighted by 1/sigma_d.
* ``"pnp"`` (angles of arrival only, n >= 3): ``cv2.solvePnPGeneric`` (AP3P for 3 points, SQPNP
  and, for >= 4 coplanar LEDs, IPPE), solutions with the camera above the LEDs dropped, the best
  one refined with ``cv2.solvePnPRefineLM``.
* ``"range+angle"``: joint least squares over reprojection residuals (sigma `pixel_sigma`) and
  range residuals (sigma_d) of the full pose; initialized by PnP (n >= 3) or, with 2 LEDs, by the
  closed form of `init_two` from the prior tilt (2 ranges + 4 angles fix all 6 unknowns).
* collinear LEDs (one row of ceiling panels -- on the bundled walk usually the only row whose
  panels are whole in the frame -- or 2 LEDs): ranges and angles fix the camera on a circle about
  the LED line, blind to a rotation of the rig about it; "range+angle" with a weak tilt prior
  (a phone held up at the ceiling, `DEFAULT_TILT_SIGMA_DEG`) picks the point, and the fix
  covariance is large along the blind direction so the Kalman filter leans on its prediction.
  The prior is the phone's tilt, not the previous frame's orientation (chaining that would let
  the tilt random-walk), and blobs cut by the image edge are flagged `border` and not ranged
  (their area gives ranges off by 10-25 %).
* one LED: range only -- no position fix (`LocateResult.position` then comes from the Kalman
  filter coasting, method ``"kalman-coast"``, or is None).

The refinement (`refine_pose`: residuals, analytic Jacobian, loss weights, damping and stopping
rule of `lsq.lm_batch`) and the scoring of `solve_fix`'s PnP candidates are receiver/locate/_pnp.pyx,
one kernel call each (tests/locate/test_refine_pose.py: known poses recovered, angles-only fixes
equal to OpenCV's `solvePnP`). When the stream is tracked, the outline solve
(receiver.locate.indoor) runs instead: on the bundled walks these are the cold starts of the
first frames (and the handedness check's mirror solve).

Fix covariance: ``cov = s^2 (J^T J)^-1`` from the whitened residual Jacobian at the solution,
``s^2 = max(1, chi^2/dof)`` (the sigma model, inflated when the residuals say it is optimistic);
the position block feeds the Kalman filter as its measurement noise.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from receiver.locate.ranging import ray_unit
from receiver.locate import _pnp
from receiver.locate.lsq import (DEFAULT_F_SCALE, DEFAULT_LOSS, LM_FTOL, LM_XTOL, covariance_at, covariance_batch,
                                 lm_batch)
from receiver.locate.multilat import multilaterate
from receiver.locate.lsq import BELOW_CEILING_M, Fix

# The robust losses of the refinement (`receiver.locate.lsq._LOSSES`), by the kernel's codes.
KERNEL_LOSSES = {"linear": 0, "soft_l1": 1, "cauchy": 2, "huber": 3}
# The refinement's iteration limit (Levenberg-Marquardt iterations of `refine_pose`'s kernel).
REFINE_MAX_ITER = 50
_NO_PRIOR3 = np.empty(0)
_NO_W = np.empty((0, 3))

SOLVERS = ("auto", "multilateration", "pnp")
# With 2 LEDs the tilt comes from the prior orientation (previous frame, else "looking up"):
# a hand-held phone held up at the ceiling is within about 10 degrees of vertical.
DEFAULT_TILT_SIGMA_DEG = 10.0
# LEDs whose RMS distance from their best-fit line is below this (m) are collinear: ranges and
# angles are then blind to a rotation of the whole rig about that line (a row of ceiling panels).
COLLINEAR_RMS_M = 0.05
# A warm-started fix (`solve_warm_batch`: from the device's previous pose) is kept when its chi^2
# per degree of freedom is at most this (whitened residuals within 3 sigma RMS); otherwise the
# frame is solved from scratch (`solve_fix`: PnP candidates).
WARM_MAX_CHI2_DOF = 9.0
# ... and stops before a step smaller than this (its norm over rotation rad and centre m: 1 um;
# the relative cost decrease rule LM_FTOL stays): the fix is then within ~1 um of the minimum,
# as close as `solve_fix`'s own stopping rule leaves its fixes (tests: within 2 um of
# `refine_pose`'s), and sooner (3.6 solver evaluations per fix instead of 4.1 on loadgen's walk).
WARM_XTOL = 1e-6
# ... and starts with this damping (relative to the normal matrix' diagonal): a warm start is near
# the minimum, and a few LEDs seen from afar leave tilt and shift nearly interchangeable -- a
# direction that a larger damping (LM_LAMBDA0 = 1e-3) slows down for several rounds.
WARM_LAMBDA0 = 1e-9


# ---------------------------------------------------------------- angles of arrival (PnP)

def _pose_from_cv(rvec, tvec) -> tuple[np.ndarray, np.ndarray]:
    R, _ = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))
    return R, -R.T @ np.asarray(tvec, float).reshape(3)


def _is_coplanar(L: np.ndarray, tol_m: float = 1e-3) -> bool:
    if len(L) < 4:
        return True
    s = np.linalg.svd(L - L.mean(axis=0), compute_uv=False)
    return bool(s[2] < tol_m)


def is_collinear(L: np.ndarray, tol_rms_m: float = COLLINEAR_RMS_M) -> bool:
    """True when the points L (N, 3) lie within `tol_rms_m` (RMS) of one line (always for N <= 2)."""
    L = np.asarray(L, float).reshape(-1, 3)
    if len(L) <= 2:
        return True
    s = np.linalg.svd(L - L.mean(axis=0), compute_uv=False)
    return bool(math.hypot(s[1], s[2]) / math.sqrt(len(L)) < tol_rms_m)


def pnp_candidates(L: np.ndarray, uv: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pose candidates (R_cw, C) from n >= 3 LEDs: L (N, 3) world, uv (N, 2) normalized. Camera
    centres above the lowest LED (mirror solutions) are dropped."""
    L = np.ascontiguousarray(L, dtype=np.float64)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    K = np.eye(3)
    sols = []
    flags = [cv2.SOLVEPNP_AP3P] if len(L) == 3 else [cv2.SOLVEPNP_SQPNP]
    if len(L) >= 4 and _is_coplanar_cached(L.tobytes()):
        flags.append(cv2.SOLVEPNP_IPPE)
    for flag in flags:
        try:
            if flag == cv2.SOLVEPNP_AP3P:
                n, rvecs, tvecs = cv2.solveP3P(L, uv, K, None, flags=flag)
            else:
                n, rvecs, tvecs, _ = cv2.solvePnPGeneric(L, uv, K, None, flags=flag)
        except cv2.error:
            continue
        for rv, tv in zip(rvecs[:n], tvecs[:n]):
            sols.append(_pose_from_cv(rv, tv))
    z_ceiling = float(L[:, 2].min())
    return [(R, C) for R, C in sols if C[2] < z_ceiling - BELOW_CEILING_M]


def init_two(L: np.ndarray, uv: np.ndarray, d: np.ndarray, R_prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form pose guess from 2 LEDs with ranges: keep the prior tilt `R_prior`, solve the
    yaw that turns the camera-frame LED baseline onto the world one, then the centre."""
    v = ray_unit(uv) * np.asarray(d, float)[:, None]        # camera-frame LED vectors
    w = v @ R_prior                                          # = R_prior^T v, world-aligned up to yaw
    a = w[0, :2] - w[1, :2]
    b = L[0, :2] - L[1, :2]
    psi = math.atan2(a[0] * b[1] - a[1] * b[0], a @ b)
    c, s = math.cos(psi), math.sin(psi)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    R_cw = R_prior @ Rz.T
    C = np.mean(L - w @ Rz.T, axis=0)
    return R_cw, C


def _farthest_pair(L: np.ndarray, usable: np.ndarray) -> tuple[int, int]:
    """Indices of the two usable points of L (N, 3) farthest apart (the best baseline)."""
    idx = np.flatnonzero(usable)
    D = np.linalg.norm(L[idx, None, :] - L[None, idx, :], axis=2)
    a, b = np.unravel_index(int(np.argmax(D)), D.shape)
    return int(idx[a]), int(idx[b])


def align_rays(rays_cam: np.ndarray, dirs_world: np.ndarray) -> np.ndarray:
    """Rotation R_cw (det +1) that best turns world directions (N, 3) onto camera rays (N, 3)
    (Kabsch / Wahba); orientation for ranges-only fixes. Needs 2+ non-parallel directions."""
    a = np.asarray(rays_cam, float)
    b = np.asarray(dirs_world, float)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(a.T @ b)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _whitening(C_prior_cov) -> np.ndarray:
    """Whitening of a position prior: r = W (C - C_prior) with W^T W = cov^-1."""
    return np.linalg.cholesky(np.linalg.inv(C_prior_cov)).T


def _kernel_args(L, uv, sigma_uv, d, sigma_d, up, up_sigma, C_prior=None, C_prior_cov=None) -> tuple:
    """The refinement's problem as the kernel's leading arguments (contiguous float64 arrays)."""
    f = np.ascontiguousarray
    if C_prior is None:
        W, Cp = _NO_W, _NO_PRIOR3
    else:
        W, Cp = f(_whitening(C_prior_cov), dtype=float), f(C_prior, dtype=float).reshape(3)
    up = _NO_PRIOR3 if up is None else f(up, dtype=float).reshape(3)
    return (f(L, dtype=float).reshape(-1, 3), f(uv, dtype=float).reshape(-1, 2), float(sigma_uv),
            f(d, dtype=float).reshape(-1), f(sigma_d, dtype=float).reshape(-1), up, float(up_sigma), W, Cp)


def _refine_native(args: tuple, p0: np.ndarray, loss: str, f_scale: float):
    """The robust Levenberg-Marquardt refinement of the problem `args` from p0: (p, r, J) at the
    solution."""
    m_max = 3 * len(args[0]) + 6                  # 2 per LED, 1 per range, 3 per prior
    p = np.array(p0, float)
    r, J = np.empty(m_max), np.empty((m_max, 6))
    m, _ = _pnp.refine(*args, p, KERNEL_LOSSES[loss], float(f_scale), REFINE_MAX_ITER, LM_XTOL, LM_FTOL, r, J)
    return p, r[:m], J[:m]


def _evaluate_native(args: tuple, P: np.ndarray, jacobian: bool = False):
    """The residuals of the problem `args` at each pose P[k] (6,): r (K, m) and, with `jacobian`,
    J (K, m, 6)."""
    m_max = 3 * len(args[0]) + 6
    P = np.ascontiguousarray(P, dtype=float).reshape(-1, 6)
    r = np.empty((len(P), m_max))
    J = np.empty((len(P), m_max, 6) if jacobian else (0, 0, 6))
    m = _pnp.evaluate(*args, P, r, J)
    return r[:, :m], J[:, :m]


def refine_pose(L, uv, sigma_uv: float, d, sigma_d, R0, C0, *, loss=DEFAULT_LOSS,
                f_scale=DEFAULT_F_SCALE, R_prior=None, tilt_sigma_rad: float = 1.0,
                C_prior=None, C_prior_cov=None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """Joint least squares over reprojection residuals (normalized units, sigma `sigma_uv`) and
    the finite ranges of d (sigma_d), plus a tilt prior (the world up direction of `R_prior`,
    sigma `tilt_sigma_rad`) when R_prior is given, plus a position prior `C_prior` (3,) of
    covariance `C_prior_cov` (3, 3) m^2 when given. Returns (R_cw, C, cov (3, 3) of C, chi2, dof).

    The returned covariance leaves the position prior out (it is the prediction of the filter the
    fix is fed to: counting it twice would make the filter overconfident); the weak tilt prior
    stays in, so a direction the LEDs cannot see gets a large but finite variance.
    `loss`: one of `KERNEL_LOSSES` (else ValueError)."""
    if loss not in KERNEL_LOSSES:
        raise ValueError(f"unknown loss {loss!r}: one of {', '.join(KERNEL_LOSSES)}")
    up = None if R_prior is None else np.asarray(R_prior, float)[:, 2]
    rvec, _ = cv2.Rodrigues(np.asarray(R0, float))
    p0 = np.concatenate([rvec.ravel(), np.asarray(C0, float)])
    x, r, J = _refine_native(_kernel_args(L, uv, sigma_uv, d, sigma_d, up, tilt_sigma_rad, C_prior, C_prior_cov),
                             p0, loss, f_scale)
    R, _ = cv2.Rodrigues(x[:3].reshape(3, 1))
    if C_prior is not None:
        r0, J0 = _evaluate_native(_kernel_args(L, uv, sigma_uv, d, sigma_d, up, tilt_sigma_rad), x, jacobian=True)
        cov6, chi2, dof = covariance_at(r0[0], J0[0], len(x))
    else:   # the solver's own residuals and Jacobian at x
        cov6, chi2, dof = covariance_at(r, J, len(x))
    return R, x[3:].copy(), cov6[3:, 3:], chi2, dof


# ---------------------------------------------------------------- many warm-started fixes at once

@dataclass(frozen=True)
class WarmProblem:
    """One frame's warm-started joint refinement (`refine_warm_batch`): L (n, 3) world m, uv
    (n, 2) normalized image points of sigma `sigma_uv`, d / sigma_d (n,) ranges and their 1-sigma
    m (d NaN: no range), the tilt prior's world-up direction `up` (3,) seen from the camera
    (None: no tilt prior) of sigma `up_sigma` rad, and the start R0 (3, 3) world-to-camera, C0 (3,)."""

    L: np.ndarray
    uv: np.ndarray
    sigma_uv: float
    d: np.ndarray
    sigma_d: np.ndarray
    up: np.ndarray | None
    up_sigma: float
    R0: np.ndarray
    C0: np.ndarray

    @property
    def has_ranges(self) -> bool:
        return bool(np.isfinite(self.d).any())


# Cross-product matrices as a linear map: (w @ _CROSS).reshape(3, 3) = [w]x.
_CROSS = np.zeros((3, 9))
_CROSS[2, 1], _CROSS[1, 2], _CROSS[0, 5] = -1.0, 1.0, -1.0
_CROSS[2, 3], _CROSS[1, 6], _CROSS[0, 7] = 1.0, -1.0, 1.0
_NEG_CROSS = -_CROSS


_RODRIGUES_LOOP_MAX = 8


def _rotation_steps(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (B, 3, 3) exp([w]x) of rotation vectors w (B, 3) (Rodrigues' formula:
    cos t I + sin t / t [w]x + (1 - cos t) / t^2 w w^T); a few by cv2.Rodrigues, whose one call
    costs less than the formula's numpy calls."""
    if len(w) <= _RODRIGUES_LOOP_MAX:
        return np.stack([cv2.Rodrigues(wi)[0] for wi in w])
    th2 = np.einsum("bi,bi->b", w, w)
    th = np.sqrt(th2)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)[:, None, None]
    b = np.where(small, 0.5, (1.0 - np.cos(ths)) / (ths * ths))[:, None, None]
    return (np.cos(th)[:, None, None] * np.eye(3) + a * (w @ _CROSS).reshape(-1, 3, 3)
            + b * (w[:, :, None] * w[:, None, :]))


def refine_warm_batch(problems: list[WarmProblem], *, loss: str = DEFAULT_LOSS, f_scale: float = DEFAULT_F_SCALE):
    """`refine_pose` (without a position prior) of many frames at once, each from its own start:
    the same whitened residuals -- reprojection (2 per LED), finite ranges, tilt prior -- and
    robust cost, minimised by `receiver.locate.lsq.lm_batch` over all frames together (padded to
    the largest LED count with zero-weight rows), so numpy's per-call overhead is paid once per
    solver round instead of once per frame. The orientation is updated multiplicatively,
    R <- exp([w]x) R, so the Jacobian is closed form: d(u, v)/dw is the image Jacobian
    (-uv, 1 + u^2, -v; -1 - v^2, uv, u), d(u, v)/dC = (-R_0 + u R_2, -R_1 + v R_2) / z,
    d range/dC = -(L - C)/range, d(R e_z)/dw = -[R e_z]x (thesis eqs. 26-34 with the angles of
    arrival). The minimum is `refine_pose`'s; its position covariance is the same (the centre
    block of (J^T J)^-1 does not depend on how the rotation is parametrised).
    Returns (R (B, 3, 3), C (B, 3), cov (B, 3, 3) of C, chi2 (B,), dof (B,), ok (B,)); ok False
    where the solver did not converge or a number is not finite."""
    fun_jac, step, p_norm, (R0, C0), n_res = warm_batch_functions(problems)
    (R, C), r, J, ok = lm_batch(fun_jac, step, (R0, C0), p_norm, loss=loss, f_scale=f_scale, xtol=WARM_XTOL,
                                lam0=WARM_LAMBDA0)
    dof = n_res - 6
    cov6, chi2 = covariance_batch(r, J, dof)
    ok = ok & np.isfinite(C).all(axis=1) & np.isfinite(cov6).all(axis=(1, 2)) & np.isfinite(R).all(axis=(1, 2))
    return R, C, cov6[:, 3:, 3:], chi2, dof, ok


def warm_batch_functions(problems: list[WarmProblem]):
    """`refine_warm_batch`'s problem for `receiver.locate.lsq.lm_batch`: (fun_jac, step, p_norm,
    start state (R0 (B, 3, 3), C0 (B, 3)), residuals per problem (B,) without padding)."""
    B = len(problems)
    ns = [len(q.L) for q in problems]
    N = max(ns)

    def stacked(arrays, pad_with_first=False):
        """(B, N, ...) of per-problem (n, ...) arrays, padded past n with zeros (or the first row)."""
        if min(ns) == N:
            return np.stack(arrays)
        pads = [np.repeat(a[:1] if pad_with_first else np.zeros_like(a[:1]), N - len(a), 0) for a in arrays]
        return np.stack([np.concatenate([a, pad]) for a, pad in zip(arrays, pads)])

    L = stacked([q.L for q in problems], pad_with_first=True)
    uv = stacked([q.uv for q in problems])
    real = np.arange(N)[None, :] < np.array(ns)[:, None]          # (B, N) a real LED, not padding
    wa = real / np.array([q.sigma_uv for q in problems])[:, None]  # 1 / sigma_uv, 0 for padding
    d_raw = stacked([q.d for q in problems])
    has_d = real & np.isfinite(d_raw)
    d = np.where(has_d, d_raw, 0.0)
    wr = np.where(has_d, 1.0 / np.where(has_d, stacked([q.sigma_d for q in problems]), 1.0), 0.0)  # 1 / sigma_d
    has_up = np.array([q.up is not None for q in problems])
    up = np.array([q.up if q.up is not None else np.zeros(3) for q in problems])
    wt = np.where(has_up, 1.0 / np.array([q.up_sigma for q in problems]), 0.0)   # 1 / up_sigma, 0 without
    R0 = np.stack([q.R0 for q in problems])
    C0 = np.stack([q.C0 for q in problems])
    n_res = 2 * np.array(ns) + has_d.sum(axis=1) + 3 * has_up
    wa2 = wa[:, :, None, None]
    zeros_rng = np.zeros((B, N, 3))
    zeros_up = np.zeros((B, 3, 3))

    def fun_jac(state):
        R, C = state
        Y = L - C[:, None, :]
        X = np.matmul(Y, R.transpose(0, 2, 1))               # camera frame
        iz = 1.0 / np.maximum(X[:, :, 2], 1e-6)              # behind the camera: huge residual
        proj = X[:, :, :2] * iz[:, :, None]                  # (u, v)
        rng = np.sqrt(np.einsum("bni,bni->bn", Y, Y))
        cz = R[:, :, 2]                                      # world up seen from the camera
        r = np.concatenate([((proj - uv) * wa[:, :, None]).reshape(B, 2 * N), (rng - d) * wr,
                            (cz - up) * wt[:, None]], axis=1)
        # dX/d(w, C) = [-[X]x, -R]; d(u, v) = (dX_xy - (u, v) dX_z) / z
        dX = np.concatenate([(X @ _NEG_CROSS).reshape(B, N, 3, 3),
                             np.broadcast_to(-R[:, None], (B, N, 3, 3))], axis=3)
        J_ang = (dX[:, :, :2] - proj[:, :, :, None] * dX[:, :, 2:]) * (iz[:, :, None, None] * wa2)
        J_rng = np.concatenate([zeros_rng, Y * (-wr / np.maximum(rng, 1e-12))[:, :, None]], axis=2)
        J_up = np.concatenate([(cz @ _CROSS).reshape(B, 3, 3) * -wt[:, None, None], zeros_up], axis=2)
        return r, np.concatenate([J_ang.reshape(B, 2 * N, 6), J_rng, J_up], axis=1)

    def step(state, dp):
        R, C = state
        return np.matmul(_rotation_steps(dp[:, :3]), R), C + dp[:, 3:]

    def p_norm(state):          # the step test is absolute: 1 um / 1 urad (WARM_XTOL)
        return np.zeros(B)

    return fun_jac, step, p_norm, (R0, C0), n_res


@functools.lru_cache(maxsize=4096)
def _is_collinear_cached(L_bytes: bytes) -> bool:
    """`is_collinear` of the (N, 3) float64 points in L_bytes: a device sees the same few map LEDs
    frame after frame."""
    return is_collinear(np.frombuffer(L_bytes).reshape(-1, 3))


@functools.lru_cache(maxsize=4096)
def _is_coplanar_cached(L_bytes: bytes) -> bool:
    """`_is_coplanar` of the (N, 3) float64 points in L_bytes (as `_is_collinear_cached`)."""
    return _is_coplanar(np.frombuffer(L_bytes).reshape(-1, 3))


def warm_problem(L: np.ndarray, uv: np.ndarray | None, d: np.ndarray, sigma_d: np.ndarray, R0: np.ndarray,
                 C0: np.ndarray, *, sigma_uv: float, solver: str = "auto",
                 tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG,
                 tilt_prior_R: np.ndarray | None = None) -> WarmProblem | None:
    """The refinement `solve_fix` ends with for n >= 3 LEDs off one line (arguments as there),
    started from the pose (R0, C0) instead of the PnP candidates; None where `solve_fix` takes
    another path (ranges only, collinear or fewer LEDs)."""
    if solver == "multilateration" or uv is None:
        return None
    L = np.asarray(L, float).reshape(-1, 3)
    if len(L) < 3 or _is_collinear_cached(L.tobytes()):
        return None
    d = np.asarray(d, float).reshape(-1)
    sigma_d = np.asarray(sigma_d, float).reshape(-1)
    has_d = np.isfinite(d) & np.isfinite(sigma_d) & (sigma_d > 0)
    use_ranges = solver == "auto" and bool(has_d.any())
    dd = np.where(has_d, d, np.nan) if use_ranges else np.full(len(L), np.nan)
    up = None if tilt_prior_R is None else np.asarray(tilt_prior_R, float)[:, 2]
    return WarmProblem(L, np.asarray(uv, float).reshape(-1, 2), sigma_uv, dd, np.where(has_d, sigma_d, 1.0),
                       up, math.radians(tilt_sigma_deg), np.asarray(R0, float), np.asarray(C0, float))


def solve_warm_batch(problems: list[WarmProblem], *, loss: str = DEFAULT_LOSS,
                     f_scale: float = DEFAULT_F_SCALE) -> list[Fix | None]:
    """Fixes of many warm-started frames (`refine_warm_batch`), each kept when it explains its
    frame: converged, chi^2 / dof <= `WARM_MAX_CHI2_DOF`, camera below the LEDs; else None (the
    caller then solves that frame from scratch with `solve_fix`)."""
    if not problems:
        return []
    R, C, cov, chi2, dof, ok = refine_warm_batch(problems, loss=loss, f_scale=f_scale)
    z_ceiling = np.array([q.L[:, 2].min() for q in problems])
    good = ok & (chi2 <= WARM_MAX_CHI2_DOF * np.maximum(dof, 1)) & (C[:, 2] <= z_ceiling - BELOW_CEILING_M)
    return [Fix(Cb, covb, Rb, "range+angle" if q.has_ranges else "pnp", len(q.L), chi2b, dofb) if g else None
            for q, g, Cb, covb, Rb, chi2b, dofb in zip(problems, good.tolist(), C, cov, R, chi2.tolist(), dof.tolist())]


def _best_candidate(cands, L, uv, sigma_uv, d, sigma_d, up, up_sigma, C_prior):
    """The PnP candidate (R, C) that explains angles (and ranges: `refine_pose`'s residuals) best;
    ties broken by the prior position C_prior (None: none)."""
    P = [np.concatenate([cv2.Rodrigues(R)[0].ravel(), C]) for R, C in cands]
    rows = _evaluate_native(_kernel_args(L, uv, sigma_uv, d, sigma_d, up, up_sigma), np.array(P))[0]

    def score(i):
        r = rows[i]
        C = cands[i][1]
        prior = 0.0 if C_prior is None else 1e-6 * float(np.sum((C - C_prior) ** 2))
        return float(r @ r) + prior
    return cands[min(range(len(cands)), key=score)]


def solve_fix(L: np.ndarray, uv: np.ndarray | None, d: np.ndarray, sigma_d: np.ndarray, *,
              sigma_uv: float, solver: str = "auto", R_prior: np.ndarray | None = None,
              C_prior: np.ndarray | None = None, loss: str = DEFAULT_LOSS,
              f_scale: float = DEFAULT_F_SCALE,
              tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG,
              C_prior_cov: np.ndarray | None = None,
              tilt_prior_R: np.ndarray | None = None) -> Fix | None:
    """One frame's camera position from N LEDs.

    L (N, 3) world m; uv (N, 2) undistorted normalized image points or None (ranges only);
    d (N,) ranges m (NaN where the LED size is unknown); sigma_d (N,) their 1-sigma, m;
    sigma_uv: image point 1-sigma in normalized units (pixels / focal_px). `R_prior` (3, 3)
    orientation guess for 2 LEDs (default: looking straight up), trusted to `tilt_sigma_deg`
    in tilt: 2 ranges fix the camera on a circle about the LED baseline and the 4 angles add only
    one more constraint, so the rotation about the baseline needs the prior. `C_prior` (3,):
    position guess; with `C_prior_cov` (3, 3) m^2 (the tracking filter's prediction) it is also a
    prior for collinear LEDs (a single row of panels, or 2 LEDs), whose ranges and angles leave
    the rotation of the camera about the LED line free: the prior pins that one direction and
    is left out of the fix covariance (`refine_pose`), so the filter sees it as unmeasured.
    `tilt_prior_R` (3, 3): the tilt prior's orientation (only its world-up direction counts) when
    it should differ from `R_prior`, e.g. "looking straight up"; it also weighs in on n >= 3
    (choice among the P3P poses and the refinement), sigma `tilt_sigma_deg`.
    A frame near a known pose can skip the PnP start: `warm_problem` / `solve_warm_batch`.
    Returns None when the LEDs do not determine a position.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}")
    L = np.asarray(L, float).reshape(-1, 3)
    d = np.asarray(d, float).reshape(-1)
    sigma_d = np.asarray(sigma_d, float).reshape(-1)
    n = len(L)
    has_d = np.isfinite(d) & np.isfinite(sigma_d) & (sigma_d > 0)
    d = np.where(has_d, d, np.nan)
    k = int(has_d.sum())
    if solver == "multilateration" or (uv is None and solver == "auto"):
        if k < 3:
            return None
        return multilaterate(L[has_d], d[has_d], sigma_d[has_d], loss=loss, f_scale=f_scale, C0=C_prior)
    if uv is None:
        return None
    uv = np.asarray(uv, float).reshape(-1, 2)
    use_ranges = solver == "auto" and k > 0
    dd = d if use_ranges else np.full(n, np.nan)
    if n >= 2 and _is_collinear_cached(L.tobytes()):
        # Collinear LEDs: PnP is degenerate; 2+ ranges and the angles fix the camera on a circle
        # about the LED line, the prior tilt (and the predicted position) pick the point on it.
        if not use_ranges or k < 2:
            return None
        i, j = _farthest_pair(L, has_d)
        Rp = R_prior if R_prior is not None else np.eye(3)
        R0, C0 = init_two(L[[i, j]], uv[[i, j]], d[[i, j]], Rp)
        use_c = C_prior is not None and C_prior_cov is not None
        R, C, cov, chi2, dof = refine_pose(L, uv, sigma_uv, dd, sigma_d, R0, C0, loss=loss, f_scale=f_scale,
                                           R_prior=Rp if tilt_prior_R is None else tilt_prior_R,
                                           tilt_sigma_rad=math.radians(tilt_sigma_deg),
                                           C_prior=C_prior if use_c else None,
                                           C_prior_cov=C_prior_cov if use_c else None)
        method = "range+angle"
    elif n >= 3:
        # The tilt prior (when given) also picks among P3P's up to 4 poses and keeps few-LED
        # fixes from flipping to a pose no hand holds the phone in; it is weak (10 degrees), so
        # well-determined fixes are not pulled by it.
        up_t = None if tilt_prior_R is None else np.asarray(tilt_prior_R, float)[:, 2]
        tilt_rad = math.radians(tilt_sigma_deg)
        method = "range+angle" if use_ranges else "pnp"
        cands = pnp_candidates(L, uv)
        if not cands:
            return None
        R0, C0 = _best_candidate(cands, L, uv, sigma_uv, dd, sigma_d, up_t, tilt_rad, C_prior)
        if not use_ranges:
            rvec, _ = cv2.Rodrigues(R0)
            tvec = -R0 @ C0
            rvec, tvec = cv2.solvePnPRefineLM(L, uv, np.eye(3), None, rvec, tvec.reshape(3, 1))
            R0, C0 = _pose_from_cv(rvec, tvec)
        R, C, cov, chi2, dof = refine_pose(L, uv, sigma_uv, dd, sigma_d, R0, C0, loss=loss, f_scale=f_scale,
                                           R_prior=tilt_prior_R, tilt_sigma_rad=tilt_rad)
    else:
        return None
    if C[2] > float(L[:, 2].min()) - BELOW_CEILING_M or not np.all(np.isfinite(C)):
        return None
    return Fix(C, cov, R, method, n, chi2, dof)


# ---------------------------------------------------------------- first-call costs

_PRELOADED = False


def preload() -> None:
    """Solve a made-up frame by each `solve_fix` path once per process (4 coplanar LEDs: SQPNP and
    IPPE; 3: P3P; 2 with ranges: `init_two`, the refinement, the covariance's SVD): OpenCV's PnP
    solvers and numpy.linalg pay a one-time cost on their first call (~0.5 ms together), which a
    stream's first cold-start frames would otherwise carry (`PoseFilter` calls this before its
    first frame, as the receiver preloads scipy). Pure functions and caches only: no state."""
    global _PRELOADED
    if _PRELOADED:
        return
    _PRELOADED = True
    L = np.array([[0.0, 0.0, 3.0], [1.0, 0.0, 3.0], [0.0, 1.0, 3.0], [1.0, 1.0, 3.0]])
    C = np.array([0.4, 0.3, 1.5])
    R = ypr_to_rotation(10.0, 85.0, 2.0)
    X = (L - C) @ R.T
    uv, d = X[:, :2] / X[:, 2:], np.linalg.norm(L - C, axis=1)
    for n in (4, 3, 2):
        solve_fix(L[:n], uv[:n], d[:n], np.full(n, 0.01), sigma_uv=1e-3, C_prior=C, tilt_prior_R=np.eye(3))


# ---------------------------------------------------------------- orientation as angles

# OpenCV camera axes in the body frame (x forward, y left, z up) -- tools/synth/camera.py.
CAM_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rotation_to_ypr_deg(R_cw: np.ndarray) -> tuple[float, float, float]:
    """Camera orientation as (yaw, pitch, roll) degrees in the truth.jsonl convention of
    tools/synth/camera.py: camera-to-world ``R_cw^T = Rz(yaw) Ry(-pitch) Rx(roll) B``, B the
    OpenCV-camera-to-body axes; pitch = +90 looks straight up. At pitch = +-90 (gimbal lock)
    only yaw -/+ roll is defined and roll is reported as 0."""
    M = (np.asarray(R_cw, float).T @ CAM_TO_BODY.T).tolist()     # Python floats: scalar maths
    theta = math.asin(max(-1.0, min(1.0, -M[2][0])))
    if abs(math.cos(theta)) < 1e-6:
        yaw, roll = math.atan2(-M[0][1], M[1][1]), 0.0
    else:
        yaw, roll = math.atan2(M[1][0], M[0][0]), math.atan2(M[2][1], M[2][2])
    return math.degrees(yaw), -math.degrees(theta), math.degrees(roll)


def ypr_to_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Inverse of `rotation_to_ypr_deg`: the world-to-camera rotation R_cw."""
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    cz, sz, cy, sy, cx, sx = math.cos(y), math.sin(y), math.cos(-p), math.sin(-p), math.cos(r), math.sin(r)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
    Ry = np.array([[cy, 0, sy], [0, 1.0, 0], [-sy, 0, cy]])
    Rx = np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return (Rz @ Ry @ Rx @ CAM_TO_BODY).T
