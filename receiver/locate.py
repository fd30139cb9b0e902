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
  This, not the image-point convention, was the ~0.5 m error of the first version: it chained
  the previous frame's orientation as the prior (a random walk of the tilt) and used blobs cut
  by the image edge whose `border` flag was not set (their area gives ranges off by 10-25 %).
* one LED: range only -- no position fix (`LocateResult.position` then comes from the Kalman
  filter coasting, method ``"kalman-coast"``, or is None).

Fix covariance: ``cov = s^2 (J^T J)^-1`` from the whitened residual Jacobian at the solution,
``s^2 = max(1, chi^2/dof)`` (the sigma model, inflated when the residuals say it is optimistic);
the position block feeds the Kalman filter as its measurement noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from receiver.config import CameraModel, LedMap
from receiver.kalman import (DEFAULT_ACCEL_PSD, DEFAULT_MAX_COAST_S, PositionKalman,
                             position_std)
from receiver.ranging import (DEFAULT_EDGE_OFFSET_PX, ESTIMATORS, R_LOOKING_UP, contour_geometry,
                              distance_eq18, distance_oblique, range_sigma_m, ray_unit, undistort_points)
from receiver.records import LedObservation, LocateResult

SOLVERS = ("auto", "multilateration", "pnp")
# Robust loss of the nonlinear refinements; residuals are whitened, so f_scale is in sigmas.
DEFAULT_LOSS = "soft_l1"
DEFAULT_F_SCALE = 3.0
# Relative singular value below which eq. 27's matrix counts as rank deficient.
RANK_TOL = 1e-6
# A camera centre must be at least this far below the lowest LED (m) -- mirror rejection.
BELOW_CEILING_M = 0.01
# With 2 LEDs the tilt comes from the prior orientation (previous frame, else "looking up"):
# a hand-held phone held up at the ceiling is within about 10 degrees of vertical.
DEFAULT_TILT_SIGMA_DEG = 10.0
# LEDs whose RMS distance from their best-fit line is below this (m) are collinear: ranges and
# angles are then blind to a rotation of the whole rig about that line (a row of ceiling panels).
COLLINEAR_RMS_M = 0.05
# A blob whose envelope comes this close (px) to the image edge is cut by it: its area and
# centroid are biased (the detector's `border` flag misses envelopes extrapolated past the edge).
# Rolling-shutter envelopes end at the last lit stripe, so a blob cut by the edge can end up to a
# dark run (several rows) short of it: the margin covers that.
DEFAULT_BORDER_MARGIN_PX = 10.0


@dataclass(frozen=True)
class Fix:
    """One frame's unfiltered solution. `C` (3,) world m; `cov` (3, 3) m^2; `R_cw` (3, 3) or None
    when the solver yields no orientation; `chi2` of the whitened residuals and its `dof`."""

    C: np.ndarray
    cov: np.ndarray
    R_cw: np.ndarray | None
    method: str
    n_leds: int
    chi2: float = 0.0
    dof: int = 0


def _jacobian(fun, p: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of fun at p (unmodified by any robust loss)."""
    f0 = fun(p)
    J = np.empty((len(f0), len(p)))
    for i in range(len(p)):
        dp = np.zeros_like(p)
        dp[i] = step
        J[:, i] = (fun(p + dp) - fun(p - dp)) / (2 * step)
    return J


# Robust losses the small solver below implements: rho(z) with z = (r / f_scale)^2 and its
# derivative, the IRLS weight (scipy.optimize.least_squares' definitions).
_LOSSES = {
    "linear": (lambda z: z, lambda z: np.ones_like(z)),
    "soft_l1": (lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0), lambda z: 1.0 / np.sqrt(1.0 + z)),
    "cauchy": (np.log1p, lambda z: 1.0 / (1.0 + z)),
    "huber": (lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0),
              lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))),
}
# Levenberg-Marquardt damping bounds and stopping rule of `robust_lm`.
LM_LAMBDA0, LM_LAMBDA_MAX = 1e-3, 1e8
LM_XTOL = 1e-8     # relative step
LM_FTOL = 1e-8     # relative cost decrease (scipy's ftol)


def robust_lm(fun, jac, p0: np.ndarray, *, loss: str = DEFAULT_LOSS, f_scale: float = DEFAULT_F_SCALE,
              max_iter: int = 50) -> np.ndarray:
    """Minimise sum rho((r/f_scale)^2) of the residual vector fun(p) (the cost of
    scipy.optimize.least_squares with the same loss) by Levenberg-Marquardt on iteratively
    reweighted normal equations, with the Jacobian `jac(p)` of the residuals.
    Why not least_squares itself: for these 3-6 parameter problems its per-iteration overhead
    (~0.5 ms) dominated the frame time; this converges to the same minimum in a fraction of it.
    Losses other than those in _LOSSES fall back to least_squares."""
    if loss not in _LOSSES:
        return least_squares(fun, p0, jac=jac, loss=loss, f_scale=f_scale, method="trf").x
    rho, wfun = _LOSSES[loss]

    def cost_w(r):
        z = (r / f_scale) ** 2
        return 0.5 * f_scale ** 2 * float(np.sum(rho(z))), wfun(z)

    p = np.asarray(p0, float).copy()
    r = fun(p)
    c, w = cost_w(r)
    lam = LM_LAMBDA0
    for _ in range(max_iter):
        J = jac(p)
        Jw = J * w[:, None]
        A = J.T @ Jw
        g = Jw.T @ r
        D = np.diag(np.maximum(np.diag(A), 1e-12))
        while True:
            try:
                dp = np.linalg.solve(A + lam * D, -g)
            except np.linalg.LinAlgError:
                dp = np.zeros_like(p)
            p_new = p + dp
            r_new = fun(p_new)
            c_new, w_new = cost_w(r_new)
            if c_new <= c:
                break
            lam *= 10.0
            if lam > LM_LAMBDA_MAX:
                return p
        done = np.linalg.norm(dp) <= LM_XTOL * (1.0 + np.linalg.norm(p)) or c - c_new <= LM_FTOL * c
        p, r, c, w = p_new, r_new, c_new, w_new
        lam = max(lam / 10.0, 1e-12)
        if done:
            break
    return p


def _covariance(fun, p: np.ndarray) -> tuple[np.ndarray, float, int]:
    r = fun(p)
    J = fun.jac(p) if hasattr(fun, "jac") else _jacobian(fun, p)
    dof = len(r) - len(p)
    chi2 = float(r @ r)
    s2 = max(1.0, chi2 / dof) if dof > 0 else 1.0
    return np.linalg.pinv(J.T @ J) * s2, chi2, dof


# ---------------------------------------------------------------- multilateration, eqs. 26-34

def multilaterate_linear(L: np.ndarray, d: np.ndarray) -> list[np.ndarray]:
    """Candidate camera centres (3,) from LED positions L (N, 3) and ranges d (N,), eqs. 27-34.
    Rank 4: the single least-squares solution (eq. 34). Rank 3 (LEDs on one plane): the two roots
    of eqs. 30-31. Fewer (collinear LEDs, eq. 32 leaves a free parameter): no candidates."""
    L = np.asarray(L, float)
    d = np.asarray(d, float)
    Z0 = np.column_stack([np.ones(len(L)), -2 * L])                 # eq. 27 / 28
    q0 = d ** 2 - np.sum(L ** 2, axis=1)
    _, s, Vt = np.linalg.svd(Z0)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    if rank >= 4 and len(L) >= 4:
        x = np.linalg.lstsq(Z0, q0, rcond=None)[0]                  # eq. 34
        return [x[1:]]
    if rank != 3:
        return []
    xp = np.linalg.pinv(Z0, rcond=RANK_TOL) @ q0                    # particular solution
    xh = Vt[3]                                                      # homogeneous solution
    # x = xp + eps xh (eq. 29) must satisfy x0 = x1^2 + x2^2 + x3^2.
    a = float(xh[1:] @ xh[1:])
    b = float(2 * xp[1:] @ xh[1:] - xh[0])
    c = float(xp[1:] @ xp[1:] - xp[0])
    if a < 1e-15:
        return []
    disc = b * b - 4 * a * c
    # Noisy ranges can make the roots complex: the closest real point is the double root.
    roots = [(-b - math.sqrt(disc)) / (2 * a), (-b + math.sqrt(disc)) / (2 * a)] if disc > 0 else [-b / (2 * a)]
    return [(xp + e * xh)[1:] for e in roots]                       # eqs. 30-31


def multilaterate(L: np.ndarray, d: np.ndarray, sigma_d: np.ndarray, *, loss: str = DEFAULT_LOSS,
                  f_scale: float = DEFAULT_F_SCALE, C0: np.ndarray | None = None) -> Fix | None:
    """Ranges-only camera centre: eqs. 27-34 then robust weighted refinement, camera below the
    LEDs. `C0` (3,) optional prior used when the linear system has no solution."""
    L = np.asarray(L, float)
    d = np.asarray(d, float)
    w = 1.0 / np.asarray(sigma_d, float)
    if len(L) < 3:
        return None
    z_ceiling = float(L[:, 2].min())
    cands = multilaterate_linear(L, d)
    if C0 is not None:
        cands.append(np.asarray(C0, float))
    if not cands:
        return None

    def fun(C):
        return (np.linalg.norm(L - C, axis=1) - d) * w

    best = None
    for C in cands:
        if C[2] > z_ceiling:                        # start from the mirror image's twin
            C = C.copy()
            C[2] = 2 * z_ceiling - C[2]
        if C[2] > z_ceiling - BELOW_CEILING_M:
            C = C.copy()
            C[2] = z_ceiling - float(np.median(d))
        res = least_squares(fun, C, loss=loss, f_scale=f_scale, method="trf")
        Cr = res.x
        if Cr[2] > z_ceiling - BELOW_CEILING_M:     # mirror solution above the ceiling: rejected
            continue
        if best is None or res.cost < best[1]:
            best = (Cr, res.cost)
    if best is None:
        return None
    cov, chi2, dof = _covariance(fun, best[0])
    return Fix(best[0], cov, None, "multilateration", len(L), chi2, dof)


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
    if len(L) >= 4 and _is_coplanar(L):
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


def _joint_fun(L, uv, sigma_uv, d, sigma_d, up_prior=None, up_sigma=1.0, C_prior=None, C_prior_cov=None):
    """Whitened residuals of a pose p = (Rodrigues vector of R_cw (3), C (3)): reprojection
    (normalized units / sigma_uv, 2 per LED), the finite ranges of d / sigma_d, the tilt prior
    (world up seen from the camera vs `up_prior`, / up_sigma) and the position prior (whitened by
    C_prior_cov). The returned function carries its analytic Jacobian as `fun.jac(p)` (the
    Rodrigues derivative from cv2.Rodrigues): the solver then needs no finite differences."""
    has_d = np.isfinite(d)
    wd = 1.0 / sigma_d[has_d]
    # Whitening of the position prior: r = W (C - C_prior) with W^T W = cov^-1.
    W = None if C_prior is None else np.linalg.cholesky(np.linalg.inv(C_prior_cov)).T

    def _pose(p):
        R, dR = cv2.Rodrigues(p[:3].reshape(3, 1))
        Y = L - p[3:]
        X = Y @ R.T
        z = np.where(X[:, 2] > 1e-6, X[:, 2], 1e-6)     # behind the camera: huge residual
        return R, dR, Y, X, z

    def fun(p):
        R, _, Y, X, z = _pose(p)
        r_ang = ((X[:, :2] / z[:, None]) - uv).ravel() / sigma_uv
        r_rng = (np.linalg.norm(Y[has_d], axis=1) - d[has_d]) * wd
        parts = [r_ang, r_rng]
        if up_prior is not None:
            # World up seen from the camera vs the prior's: a tilt prior, blind to yaw.
            parts.append((R[:, 2] - up_prior) / up_sigma)
        if W is not None:
            parts.append(W @ (p[3:] - C_prior))
        return np.concatenate(parts)

    def jac(p):
        R, dR, Y, X, z = _pose(p)
        n = len(L)
        dRk = dR.reshape(3, 3, 3)                        # dRk[k] = dR / d rvec_k
        # dX_i / d rvec_k = dRk[k] @ Y_i ; dX_i / dC = -R
        dX = np.empty((n, 3, 6))
        dX[:, :, :3] = np.einsum("kab,nb->nak", dRk, Y)
        dX[:, :, 3:] = -R[None, :, :]
        x, y = X[:, 0], X[:, 1]
        # d(x/z) = (dx - x/z dz) / z, d(y/z) likewise
        du = (dX[:, 0, :] - (x / z)[:, None] * dX[:, 2, :]) / z[:, None]
        dv = (dX[:, 1, :] - (y / z)[:, None] * dX[:, 2, :]) / z[:, None]
        J_ang = np.stack([du, dv], axis=1).reshape(2 * n, 6) / sigma_uv
        Yd = Y[has_d]
        J_rng = np.zeros((len(Yd), 6))
        J_rng[:, 3:] = -(Yd / np.linalg.norm(Yd, axis=1, keepdims=True)) * wd[:, None]
        parts = [J_ang, J_rng]
        if up_prior is not None:
            J_up = np.zeros((3, 6))
            J_up[:, :3] = dRk[:, :, 2].T / up_sigma       # d R[:, 2] / d rvec_k
            parts.append(J_up)
        if W is not None:
            J_c = np.zeros((3, 6))
            J_c[:, 3:] = W
            parts.append(J_c)
        return np.vstack(parts)

    fun.jac = jac
    return fun


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
    stays in, so a direction the LEDs cannot see gets a large but finite variance."""
    up = None if R_prior is None else np.asarray(R_prior, float)[:, 2]
    fun = _joint_fun(L, uv, sigma_uv, d, sigma_d, up, tilt_sigma_rad, C_prior, C_prior_cov)
    rvec, _ = cv2.Rodrigues(np.asarray(R0, float))
    p0 = np.concatenate([rvec.ravel(), np.asarray(C0, float)])
    x = robust_lm(fun, fun.jac, p0, loss=loss, f_scale=f_scale)
    R, _ = cv2.Rodrigues(x[:3].reshape(3, 1))
    if C_prior is not None:
        fun = _joint_fun(L, uv, sigma_uv, d, sigma_d, up, tilt_sigma_rad)
    cov6, chi2, dof = _covariance(fun, x)
    return R, x[3:].copy(), cov6[3:, 3:], chi2, dof


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
    if n >= 2 and is_collinear(L):
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
        cands = pnp_candidates(L, uv)
        if not cands:
            return None
        # The tilt prior (when given) also picks among P3P's up to 4 poses and keeps few-LED
        # fixes from flipping to a pose no hand holds the phone in; it is weak (10 degrees), so
        # well-determined fixes are not pulled by it.
        up_t = None if tilt_prior_R is None else np.asarray(tilt_prior_R, float)[:, 2]
        tilt_rad = math.radians(tilt_sigma_deg)
        fun = _joint_fun(L, uv, sigma_uv, dd, sigma_d, up_t, tilt_rad)
        # The candidate that explains angles (and ranges) best; ties broken by the prior position.
        def score(rc):
            r = fun(np.concatenate([cv2.Rodrigues(rc[0])[0].ravel(), rc[1]]))
            prior = 0.0 if C_prior is None else 1e-6 * float(np.sum((rc[1] - C_prior) ** 2))
            return float(r @ r) + prior
        R0, C0 = min(cands, key=score)
        if not use_ranges:
            rvec, _ = cv2.Rodrigues(R0)
            tvec = -R0 @ C0
            rvec, tvec = cv2.solvePnPRefineLM(L, uv, np.eye(3), None, rvec, tvec.reshape(3, 1))
            R0, C0 = _pose_from_cv(rvec, tvec)
        R, C, cov, chi2, dof = refine_pose(L, uv, sigma_uv, dd, sigma_d, R0, C0, loss=loss, f_scale=f_scale,
                                           R_prior=tilt_prior_R, tilt_sigma_rad=tilt_rad)
        method = "range+angle" if use_ranges else "pnp"
    else:
        return None
    if C[2] > float(L[:, 2].min()) - BELOW_CEILING_M or not np.all(np.isfinite(C)):
        return None
    return Fix(C, cov, R, method, n, chi2, dof)


# ---------------------------------------------------------------- orientation as angles

# OpenCV camera axes in the body frame (x forward, y left, z up) -- tools/synth/camera.py.
CAM_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rotation_to_ypr_deg(R_cw: np.ndarray) -> tuple[float, float, float]:
    """Camera orientation as (yaw, pitch, roll) degrees in the truth.jsonl convention of
    tools/synth/camera.py: camera-to-world ``R_cw^T = Rz(yaw) Ry(-pitch) Rx(roll) B``, B the
    OpenCV-camera-to-body axes; pitch = +90 looks straight up. At pitch = +-90 (gimbal lock)
    only yaw -/+ roll is defined and roll is reported as 0."""
    M = np.asarray(R_cw, float).T @ CAM_TO_BODY.T
    theta = math.asin(max(-1.0, min(1.0, -M[2, 0])))
    if abs(math.cos(theta)) < 1e-6:
        yaw, roll = math.atan2(-M[0, 1], M[1, 1]), 0.0
    else:
        yaw, roll = math.atan2(M[1, 0], M[0, 0]), math.atan2(M[2, 1], M[2, 2])
    return math.degrees(yaw), -math.degrees(theta), math.degrees(roll)


def ypr_to_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Inverse of `rotation_to_ypr_deg`: the world-to-camera rotation R_cw."""
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    cz, sz, cy, sy, cx, sx = math.cos(y), math.sin(y), math.cos(-p), math.sin(-p), math.cos(r), math.sin(r)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
    Ry = np.array([[cy, 0, sy], [0, 1.0, 0], [-sy, 0, cy]])
    Rx = np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return (Rz @ Ry @ Rx @ CAM_TO_BODY).T


# ---------------------------------------------------------------- the streaming stage

def _xyz(v) -> dict:
    return {"x": round(float(v[0]), 5), "y": round(float(v[1]), 5), "z": round(float(v[2]), 5)}


# Mirror of the world's y axis and of the camera's x axis (image columns reversed): a map drawn in
# a left-handed frame is solved in its mirror P = MIRROR_WORLD @ M, and the pose reported back in
# the map's frame as R = MIRROR_CAM @ R_P @ MIRROR_WORLD, the only way for it to stay a rotation.
MIRROR_WORLD = np.diag([1.0, -1.0, 1.0])
MIRROR_CAM = np.diag([-1.0, 1.0, 1.0])
# With the map's handedness unknown, a frame with this many non-collinear LEDs decides it: the
# cyclic order of 3+ LEDs seen from below differs between a map and its mirror.
HANDEDNESS_MIN_LEDS = 3
# ... when the fit in the chosen frame is this much better (chi^2 ratio) than in the other one,
# and good in itself: chi^2 per degree of freedom at most this (residuals within ~10 sigma RMS;
# the Luxapose photo's mirror fit has 22, the bundled walk's first decisive frame 6).
HANDEDNESS_CHI2_RATIO = 10.0
HANDEDNESS_MAX_CHI2_DOF = 100.0


def is_mirror_fit_better(good: Fix | None, other: Fix | None) -> bool:
    """True when `good` explains the frame (chi^2 per dof at most `HANDEDNESS_MAX_CHI2_DOF`) and
    `other` (the same data in the mirrored world) does not: no fix there (camera above the LEDs),
    or a chi^2 `HANDEDNESS_CHI2_RATIO` times worse."""
    if good is None or good.chi2 > HANDEDNESS_MAX_CHI2_DOF * max(good.dof, 1):
        return False
    if other is None:
        return True
    return other.chi2 > HANDEDNESS_CHI2_RATIO * max(good.chi2, float(good.dof), 1.0)


class PoseFilter:
    """One receiver's positioning state: per frame, the map positions, undistorted image points
    and ranges of its decoded LEDs -> a fix (`solve_fix`) -> the Kalman filter -> the INTERFACES.md
    `position` object. `Positioner` holds one; the lighting server holds one per device.

    The map's handedness (`LedMap.handedness`): "right" is solved as it is; "left" in its mirror
    (`MIRROR_WORLD`), with positions mapped back and the orientation reported against the mirrored
    camera (`MIRROR_CAM`, image x reversed) so that it is a rotation. A map that does not say is
    taken as right-handed until the first frame with `HANDEDNESS_MIN_LEDS` non-collinear LEDs,
    which is solved both ways: when only the mirror explains it (e.g. the Luxapose rig map, whose
    photo has no pose below the LEDs as surveyed), the map is left-handed for the rest of the run
    (`handedness`, "detected" in `handedness_source`), and the filter restarts in that frame.
    All state (filter, priors) lives in the solving frame.
    """

    def __init__(self, *, handedness: str | None = None, sigma_uv: float, solver: str = "auto",
                 kalman: bool = True, accel_psd: float = DEFAULT_ACCEL_PSD,
                 max_coast_s: float = DEFAULT_MAX_COAST_S, loss: str = DEFAULT_LOSS,
                 f_scale: float = DEFAULT_F_SCALE, tilt_prior: str = "up",
                 tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG, track_prior: bool = False):
        if solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}")
        if handedness not in (None, "right", "left"):
            raise ValueError(f"unknown handedness {handedness!r}")
        self.handedness = handedness or "right"
        self.handedness_source = "map" if handedness else "default"
        self.sigma_uv, self.solver = sigma_uv, solver
        self.loss, self.f_scale = loss, f_scale
        self.max_coast_s = max_coast_s
        self.tilt_prior, self.tilt_sigma_deg, self.track_prior = tilt_prior, tilt_sigma_deg, track_prior
        self._kalman_args = dict(accel_psd=accel_psd, max_coast_s=max_coast_s) if kalman else None
        self.n_fixes = 0
        self._restart()

    def _restart(self) -> None:
        self.kf = PositionKalman(**self._kalman_args) if self._kalman_args is not None else None
        self._R_cw: np.ndarray | None = None
        self._t_R: float | None = None
        self._C: np.ndarray | None = None
        self._t_C: float | None = None

    @property
    def mirrored(self) -> bool:
        return self.handedness == "left"

    def to_solving(self, L_map: np.ndarray) -> np.ndarray:
        """(N, 3) map-frame points -> the solving frame."""
        L = np.asarray(L_map, float).reshape(-1, 3)
        return L @ MIRROR_WORLD if self.mirrored else L

    def R_prior(self, t_s: float) -> np.ndarray | None:
        """World-to-camera rotation (solving frame) of the last fix, if recent enough."""
        if self._t_R is not None and 0 <= t_s - self._t_R <= self.max_coast_s:
            return self._R_cw
        return None

    def keep_orientation(self, t_s: float, R_cw: np.ndarray) -> None:
        """Remember a fix's world-to-camera rotation (solving frame) of time t_s for `R_prior`."""
        self._R_cw, self._t_R = R_cw, t_s

    def solve(self, t_s: float, L_map: np.ndarray, uv: np.ndarray | None, d: np.ndarray,
              sigma_d: np.ndarray, R_prior: np.ndarray | None = None) -> Fix | None:
        """One frame's fix in the solving frame (no state change except the handedness decision).
        L_map (N, 3) map m; uv (N, 2) undistorted normalized image points or None; d, sigma_d (N,)
        ranges and their 1-sigma, m (NaN where unknown). R_prior: solving-frame orientation guess."""
        pred = None if self.kf is None or not self.track_prior else self.kf.predict_at(t_s)
        if pred is not None:
            C_prior, C_prior_cov = pred[0][:3], pred[1][:3, :3]
        else:
            recent = self._t_C is not None and 0 <= t_s - self._t_C <= self.max_coast_s
            C_prior, C_prior_cov = (self._C if recent else None), None
        kw = dict(sigma_uv=self.sigma_uv, solver=self.solver, loss=self.loss, f_scale=self.f_scale,
                  tilt_sigma_deg=self.tilt_sigma_deg,
                  tilt_prior_R=R_LOOKING_UP if self.tilt_prior == "up" else None)
        L_map = np.asarray(L_map, float).reshape(-1, 3)
        fix = solve_fix(self.to_solving(L_map), uv, d, sigma_d, R_prior=R_prior, C_prior=C_prior,
                        C_prior_cov=C_prior_cov, **kw)
        if (self.handedness_source == "default" and uv is not None and self.solver != "multilateration"
                and len(L_map) >= HANDEDNESS_MIN_LEDS and not is_collinear(L_map)):
            # Undecided map: this frame can tell the map from its mirror.
            other = "left" if self.handedness == "right" else "right"
            L_other = L_map @ MIRROR_WORLD if other == "left" else L_map
            fix_other = solve_fix(L_other, uv, d, sigma_d, **kw)
            if is_mirror_fit_better(fix_other, fix):
                self.handedness, self.handedness_source = other, "detected"
                self._restart()
                return fix_other
            if is_mirror_fit_better(fix, fix_other):
                self.handedness_source = "detected"
        return fix

    def update(self, t_s: float, fix: Fix | None, n_leds: int) -> dict | None:
        """Feed one frame's fix (or None) to the filter; the INTERFACES.md `position` object
        (map frame) or None."""
        if fix is not None:
            self.n_fixes += 1
            self._C, self._t_C = fix.C, t_s
            if fix.R_cw is not None:
                self.keep_orientation(t_s, fix.R_cw)
        state = None
        if self.kf is not None:
            state = self.kf.step(t_s, None if fix is None else fix.C, None if fix is None else fix.cov)
        if fix is None and state is None:
            return None
        F = MIRROR_WORLD if self.mirrored else np.eye(3)
        if state is not None:
            x, P = state
            P3 = F @ P[:3, :3] @ F
            pos = _xyz(F @ x[:3])
            pos.update(method=fix.method if fix is not None else "kalman-coast", n_leds=n_leds,
                       filtered=True, std_m=[round(s, 5) for s in position_std(P3)],
                       cov=np.round(P3, 8).tolist(),
                       velocity_mps=[round(float(v), 4) for v in F @ x[3:]])
        else:
            pos = _xyz(F @ fix.C)
            pos.update(method=fix.method, n_leds=n_leds, filtered=False)
        if fix is not None:
            pos["raw"] = _xyz(F @ fix.C)
            pos["raw_std_m"] = [round(s, 5) for s in position_std(fix.cov)]
            if fix.R_cw is not None:
                R = MIRROR_CAM @ fix.R_cw @ MIRROR_WORLD if self.mirrored else fix.R_cw
                pos["R_wc"] = np.round(R.T, 6).tolist()   # camera-to-world, columns = camera axes
                yaw, pitch, roll = rotation_to_ypr_deg(R)
                pos.update(yaw_deg=round(yaw, 3), pitch_deg=round(pitch, 3), roll_deg=round(roll, 3))
        else:
            pos["raw"] = None
        if self.handedness_source != "default":
            pos["handedness"] = self.handedness
        return pos


class Positioner:
    """Decoded LEDs of one frame -> distances and camera position, Kalman-filtered over frames.

    Options (keywords, documented defaults):
    `ranging`: "oblique" (default, see receiver.ranging) or "eq18".
    `solver`: "auto" (ranges + angles), "multilateration" (ranges only) or "pnp" (angles only).
    `pixel_sigma_px`: 1-sigma of an LED image point, px (0.3: envelope centroids of blobs of
        hundreds of pixels are good to a fraction of a pixel).
    `edge_sigma_px`, `model_rel_sigma`: range error model (receiver.ranging.range_sigma_m).
    `edge_offset_px`: contour-to-true-edge offset for the area bias (receiver.ranging).
    `kalman`: filter the fixes (PositionKalman with `accel_psd` m^2/s^3, `max_coast_s`).
    `loss`, `f_scale`: robust loss of the refinements (scipy names; f_scale in sigmas).
    `ranging_iterations`: with "oblique" ranging, how often the ranges are recomputed with the
        orientation of the frame's own fix and the fix solved again (the first pass uses the
        previous frame's orientation, or "looking straight up"). Default 0: each re-solve costs
        a least-squares run (~5 ms) and moves the walk's median error by only ~3 mm; the
        reported distances always use the frame's own orientation (no re-solve needed for that).
    `ranges_only_iterations`: the same for the "multilateration" solver, whose ranges have no
        other source of orientation (the tilt feeds back into the foreshortening term).
    `tilt_prior`: "up" (default: a phone held up at the ceiling, within `tilt_sigma_deg` of
        vertical) or "previous" (the previous frame's orientation): the prior that fixes the
        rotation about the LED line when the usable LEDs are collinear (a single row of panels,
        the common case on the bundled walk) or only 2. Chaining "previous" lets the tilt random
        walk; a fixed weak prior does not.
    `track_prior`: also pull collinear fixes toward the Kalman prediction (off by default: the
        filter already fuses the fix, whose covariance is large along the unobserved direction).

    `border_margin_px`: blobs whose envelope comes this close to the image edge are left out, as
        are blobs flagged `border`: their area and centroid are cut by the frame edge.
    LEDs whose ID the map does not know are counted in `unknown_ids`.
    `handedness`: "right" or "left" overrides the map's own (`PoseFilter`); None: the map's, or
        told from the images when the map does not say.
    """

    def __init__(self, camera: CameraModel, led_map: LedMap, *, ranging: str = "oblique",
                 solver: str = "auto", pixel_sigma_px: float = 0.3, edge_sigma_px: float = 0.1,
                 model_rel_sigma: float = 0.002, edge_offset_px: float = DEFAULT_EDGE_OFFSET_PX,
                 kalman: bool = True, accel_psd: float = DEFAULT_ACCEL_PSD,
                 max_coast_s: float = DEFAULT_MAX_COAST_S, loss: str = DEFAULT_LOSS,
                 f_scale: float = DEFAULT_F_SCALE, ranging_iterations: int = 0,
                 border_margin_px: float = DEFAULT_BORDER_MARGIN_PX, tilt_prior: str = "up",
                 tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG, track_prior: bool = False,
                 ranges_only_iterations: int = 3, handedness: str | None = None):
        if ranging not in ESTIMATORS:
            raise ValueError(f"unknown ranging estimator {ranging!r}")
        self.camera, self.led_map = camera, led_map
        self.ranging, self.solver = ranging, solver
        self.edge_sigma_px, self.model_rel_sigma = edge_sigma_px, model_rel_sigma
        self.edge_offset_px = edge_offset_px
        self.ranging_iterations = ranging_iterations
        self.ranges_only_iterations = ranges_only_iterations
        self.border_margin_px = border_margin_px
        self.pose = PoseFilter(handedness=handedness or led_map.handedness,
                               sigma_uv=pixel_sigma_px / camera.focal_px, solver=solver, kalman=kalman,
                               accel_psd=accel_psd, max_coast_s=max_coast_s, loss=loss, f_scale=f_scale,
                               tilt_prior=tilt_prior, tilt_sigma_deg=tilt_sigma_deg, track_prior=track_prior)
        self.unknown_ids: set[int] = set()

    @property
    def n_fixes(self) -> int:
        return self.pose.n_fixes

    def _ranges(self, items, R_cw):
        d = np.full(len(items), np.nan)
        sd = np.full(len(items), np.nan)
        names = [""] * len(items)
        for i, (obs, led, geo) in enumerate(items):
            A = led.area_m2
            if not A:
                continue
            if self.ranging == "oblique" and geo is not None:
                Rw = np.eye(3) if R_cw is None else R_cw
                d[i] = distance_oblique(geo["area_norm"], A, ray_unit(geo["centroid_norm"]), Rw)
                names[i] = "oblique-up" if R_cw is None else "oblique-pose"
                area_px, perim = geo["area_px"], geo["perimeter_px"]
            else:
                d[i] = distance_eq18(obs.area_px, A, self.camera.focal_px)
                names[i] = "eq18"
                area_px = obs.area_px
                perim = 4.0 * math.sqrt(max(area_px, 0.0))   # square-ish blob without a contour
            sd[i] = range_sigma_m(d[i], area_px, perim, self.edge_sigma_px, self.model_rel_sigma)
        return d, sd, names

    def _touches_edge(self, obs: LedObservation) -> bool:
        if obs.contour is None or len(obs.contour) == 0:
            return False
        c = np.asarray(obs.contour, float).reshape(-1, 2)
        m = self.border_margin_px
        lo = c.min(axis=0)
        hi = c.max(axis=0)
        return bool(lo[0] <= m or lo[1] <= m or hi[0] >= self.camera.width - 1 - m
                    or hi[1] >= self.camera.height - 1 - m)

    def measure(self, leds: list[LedObservation]) -> list:
        """The frame's usable LEDs: (observation, map LED, contour geometry or None) for every
        decoded, uncut OOK or tone LED the map knows (unknown IDs are counted in `unknown_ids`).
        S2-PSK lights are left out: a street-light head or a taillight pair is seen as two
        emitter blobs, not one fixture of the map's size, from a camera looking along the road,
        not up at a ceiling; placing the vehicle from them is thesis eqs. 44-53, not this
        indoor solver (whose fixes and ranges from them were metres off on the vehicle scene)."""
        items = []
        for obs in leds:
            if obs.id is None or obs.border or obs.mode == "s2psk" or self._touches_edge(obs):
                continue
            led = self.led_map.lookup(obs.id)
            if led is None:
                self.unknown_ids.add(obs.id)
                continue
            if led.mode == "s2psk":
                continue
            geo = None
            if obs.contour is not None and len(obs.contour) >= 3:
                geo = contour_geometry(obs.contour, self.camera, self.edge_offset_px)
            items.append((obs, led, geo))
        return items

    def image_points(self, items) -> np.ndarray:
        """(N, 2) undistorted normalized image points of `measure`'s items."""
        if not items:
            return np.zeros((0, 2))
        return undistort_points(np.array([[o.cx, o.cy] for o, _, _ in items]), self.camera)

    def step(self, t_s: float, leds: list[LedObservation]) -> LocateResult:
        items = self.measure(leds)
        R_prior = self.pose.R_prior(t_s)
        d, sd, names = self._ranges(items, R_prior)
        fix = None
        if items:
            L = np.array([led.xyz for _, led, _ in items])
            uv = self.image_points(items)
            fix = self.pose.solve(t_s, L, uv, d, sd, R_prior)
            n_iter = self.ranges_only_iterations if self.solver == "multilateration" else self.ranging_iterations
            for _ in range(n_iter if self.ranging == "oblique" else 0):
                if fix is None:
                    break
                # Foreshortening with this frame's own orientation, then solve again. Ranges-only
                # fixes carry no orientation: align the camera rays with the LED directions.
                R = fix.R_cw
                if R is not None:
                    d, sd, names = self._ranges(items, R)
                else:
                    # Tilt error and range error feed each other back here with a gain of about
                    # -2/3 (ceiling LEDs), so the plain loop oscillates; averaging old and new
                    # ranges damps the loop gain to about 1/6.
                    R = align_rays(ray_unit(uv), self.pose.to_solving(L) - fix.C)
                    d_new, sd, names = self._ranges(items, R)
                    d = np.where(np.isfinite(d), 0.5 * (d + d_new), d_new)
                fix = self.pose.solve(t_s, L, uv, d, sd, R) or fix
            if fix is not None and fix.R_cw is not None and self.ranging == "oblique":
                # The reported distances use this frame's own orientation (cheap: no new solve).
                d, sd, names = self._ranges(items, fix.R_cw)
        return LocateResult(distances=self.distances(items, d, names),
                            position=self.pose.update(t_s, fix, len(items)))

    @staticmethod
    def distances(items, d: np.ndarray, names: list[str]) -> dict:
        """`LocateResult.distances` of `measure`'s items: track -> (distance m, estimator) for
        every finite range."""
        return {obs.track: (round(float(d[i]), 5), names[i])
                for i, (obs, _, _) in enumerate(items) if math.isfinite(d[i])}
