"""Camera pose from the LEDs' outlines: the edge points of their lit stripes
(`receiver.vision.outline.stripe_edge_points`, undistorted) against the projected outlines of the
map's fixtures, in one robust least-squares solve over all LEDs of a frame.

Model (world frame of `receiver.locate.pose`, normalized undistorted image coordinates):

* square / rect: four straight edges on the ceiling plane. `size` = [width, length]: the width
  along world y, the length along world x (the map's convention for rects, as the synthetic
  camera's `u_axis` (0, 1, 0) draws them). A straight world line stays straight in the
  undistorted image, so a point's residual is its signed distance to the line through its edge's
  two projected corners. Each point is assigned to the edge nearest to it at the initial pose
  (points within `CORNER_GUARD_PX` of a projected corner are left out: the blur rounds the
  corner); the assignment is redone once after the first solve.
* circle: the image of the ceiling circle is the conic ``H^-T diag(1, 1, -r^2) H^-1`` with
  ``H = [R e_x, R e_y, R (L - C)]``; a point's residual is its Sampson distance to it.

Residuals are whitened by each point's sigma (pixels / focal length). Alongside the outline
points: each LED's envelope centroid (sigma `centroid_sigma_px`: the caps of a striped envelope
can miss up to two chips, so the centroid is a weak constraint where the outline says nothing,
e.g. along the vertical edges of an unrotated rect), the weak tilt prior of `receiver.locate.pose`
("held up at the ceiling") and, for outlines that leave a direction free, the tracked position.

What a frame determines:
* 2+ LEDs with outlines, or one square/rect: the full pose (a square's four-fold symmetry is
  resolved by the initial pose, i.e. by the neighbours' centroids or the tracked orientation;
  without either, a lone square gives no fix).
* one circle: everything except the rotation about its normal, which moves the camera on a
  horizontal circle about the LED; the tracked position picks the point (no track: no fix), and
  the covariance is computed with only a weak `FREE_SIGMA_M` prior on the position, so that
  direction is marked as (almost) unmeasured for the Kalman filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from receiver.locate.lsq import BELOW_CEILING_M, DEFAULT_F_SCALE, DEFAULT_LOSS, Fix, robust_lm

CORNER_GUARD_PX = 2.0
DEFAULT_CENTROID_SIGMA_PX = 1.5
# Position prior (m) always in the covariance: a direction the frame leaves free gets about this
# 1-sigma instead of the pseudo-inverse's silent zero.
FREE_SIGMA_M = 1.0
# A fit whose chi^2 per degree of freedom exceeds this is not trusted (wrong symmetry, wrong ID).
MAX_CHI2_DOF = 50.0
# Levenberg-Marquardt iterations per round (a good start converges in 3-5).
MAX_ITER = 4


@dataclass
class OutlineTarget:
    """One fixture seen by its outline. `xyz` (3,) centre (solving frame), `shape`, `half` (hx,
    hy) half extents along world x and y (circle: (r, r)), `pts` (N, 2) normalized undistorted
    edge points, `sigma` (N,) their 1-sigma (normalized units), `uv` (2,) its centroid (normalized)
    or None (an LED cut by the image border: its edges only)."""

    xyz: np.ndarray
    shape: str
    half: tuple[float, float]
    pts: np.ndarray
    sigma: np.ndarray
    uv: np.ndarray | None = None
    labels: np.ndarray | None = None


def fixture_half_extents(shape: str | None, size) -> tuple[float, float] | None:
    """(hx, hy) half extents along world x and y of a map fixture, or None when unknown."""
    if not shape or not size:
        return None
    if shape == "circle":
        return size[0] / 2, size[0] / 2
    if shape == "square":
        return size[0] / 2, size[0] / 2
    if shape == "rect":
        return (size[1] if len(size) > 1 else size[0]) / 2, size[0] / 2
    return None


def _corners(t: OutlineTarget) -> np.ndarray:
    hx, hy = t.half
    return t.xyz + np.array([[hx, hy, 0.0], [-hx, hy, 0.0], [-hx, -hy, 0.0], [hx, -hy, 0.0]])


def _project(R, C, X):
    Xc = (np.asarray(X) - C) @ R.T
    z = np.where(Xc[..., 2] > 1e-6, Xc[..., 2], 1e-6)
    return Xc[..., :2] / z[..., None]


def assign_edges(t: OutlineTarget, R, C, focal_px: float) -> np.ndarray:
    """Edge index 0..3 of each point of a square/rect at pose (R, C), -1 near a corner."""
    q = _project(R, C, _corners(t))
    a, b = q, np.roll(q, -1, axis=0)
    ab = b - a
    L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-18)
    rel = t.pts[:, None, :] - a[None, :, :]
    s = np.clip(np.einsum("nkj,kj->nk", rel, ab) / L2, 0, 1)
    dist = np.linalg.norm(rel - s[..., None] * ab[None], axis=2)
    lab = np.argmin(dist, axis=1)
    dc = np.min(np.linalg.norm(t.pts[:, None, :] - q[None], axis=2), axis=1)
    lab[dc < CORNER_GUARD_PX / focal_px] = -1
    return lab


def _circle_residuals(t: OutlineTarget, R, C) -> np.ndarray:
    r = t.half[0]
    H = np.column_stack([R[:, 0], R[:, 1], R @ (t.xyz - C)])
    try:
        Hi = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.full(len(t.pts), 1e3)
    Ci = Hi.T @ np.diag([1.0, 1.0, -r * r]) @ Hi
    x = np.column_stack([t.pts, np.ones(len(t.pts))])
    Cx = x @ Ci.T
    val = np.sum(x * Cx, axis=1)
    g = 2.0 * np.hypot(Cx[:, 0], Cx[:, 1])
    return val / np.maximum(g, 1e-12) / t.sigma


def _stack_edges(targets):
    """Every assigned point of the frame's squares / rects and its edge: (P (M, 2), 1/sigma (M,),
    edge index (M,), edge corners A (E, 3), B (E, 3)), for one vectorised residual."""
    P, w, idx, A, B = [np.zeros((0, 2))], [np.zeros(0)], [np.zeros(0, int)], [], []
    for t in targets:
        if t.shape == "circle" or t.labels is None:
            continue
        use = t.labels >= 0
        q = _corners(t)
        P.append(t.pts[use])
        w.append(1.0 / t.sigma[use])
        idx.append(t.labels[use] + len(A))
        A.extend(q)
        B.extend(np.roll(q, -1, axis=0))
    A = np.array(A).reshape(-1, 3)
    B = np.array(B).reshape(-1, 3)
    return np.concatenate(P), np.concatenate(w), np.concatenate(idx).astype(int), A, B


def _make_fun(targets, sigma_c, up, up_sigma, C_prior, W):
    """Whitened residuals of p = (Rodrigues vector of R_cw, C). An edge point's residual is its
    distance to the image line of its edge: the plane through the camera centre and the edge's
    corners A, B has the camera-frame normal n = R ((A - C) x (B - C)), the line (n0, n1, n2)."""
    P, w, idx, A, B = _stack_edges(targets)
    circles = [t for t in targets if t.shape == "circle"]
    cen = [t for t in targets if t.uv is not None]
    L = np.array([t.xyz for t in cen]).reshape(-1, 3)
    uv = np.array([t.uv for t in cen]).reshape(-1, 2)

    def fun(p):
        R, _ = cv2.Rodrigues(p[:3].reshape(3, 1))
        C = p[3:]
        parts = []
        if len(A):
            a, b = A - C, B - C
            m = np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                                 a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])
            n = m @ R.T
            n = n / np.maximum(np.hypot(n[:, 0], n[:, 1]), 1e-15)[:, None]
            nn = n[idx]
            parts.append((P[:, 0] * nn[:, 0] + P[:, 1] * nn[:, 1] + nn[:, 2]) * w)
        parts += [_circle_residuals(t, R, C) for t in circles]
        if len(L):
            parts.append(((_project(R, C, L) - uv) / sigma_c).ravel())
        if up is not None:
            parts.append((R[:, 2] - up) / up_sigma)
        if C_prior is not None:
            parts.append(W @ (C - C_prior))
        return np.concatenate(parts)
    return fun


def _fd_jac(fun, p, step=1e-7):
    """Forward-difference Jacobian (6 extra evaluations of the vectorised residual)."""
    f0 = fun(p)
    J = np.empty((len(f0), len(p)))
    for i in range(len(p)):
        q = p.copy()
        q[i] += step
        J[:, i] = (fun(q) - f0) / step
    return J


def solve_outline_pose(targets: list[OutlineTarget], R0: np.ndarray, C0: np.ndarray, *, focal_px: float,
                       centroid_sigma_px: float = DEFAULT_CENTROID_SIGMA_PX, up_prior: np.ndarray | None = None,
                       tilt_sigma_rad: float = math.radians(10.0), C_prior: np.ndarray | None = None,
                       C_prior_cov: np.ndarray | None = None, loss: str = DEFAULT_LOSS,
                       f_scale: float = DEFAULT_F_SCALE, rounds: int = 2) -> Fix | None:
    """Pose (R_cw, C) from the outline targets of one frame, started at (R0, C0) (module doc).
    Returns a `Fix` (method "outline") or None when the outlines do not determine a trustworthy
    position (too few points, camera not below the LEDs, residuals far beyond their sigmas)."""
    targets = [t for t in targets if len(t.pts) >= 3]
    if not targets:
        return None
    only_circle = len(targets) == 1 and targets[0].shape == "circle"
    if only_circle and C_prior is None:
        return None
    W = None
    if C_prior is not None:
        W = np.linalg.cholesky(np.linalg.inv(C_prior_cov)).T
    sigma_c = centroid_sigma_px / focal_px
    rvec, _ = cv2.Rodrigues(np.asarray(R0, float))
    p = np.concatenate([rvec.ravel(), np.asarray(C0, float)])
    for _ in range(rounds):
        R, _ = cv2.Rodrigues(p[:3].reshape(3, 1))
        for t in targets:
            if t.shape != "circle":
                t.labels = assign_edges(t, R, p[3:], focal_px)
        fun = _make_fun(targets, sigma_c, up_prior, tilt_sigma_rad, C_prior, W)
        p = robust_lm(fun, lambda q: _fd_jac(fun, q), p, loss=loss, f_scale=f_scale, max_iter=MAX_ITER)
    R, _ = cv2.Rodrigues(p[:3].reshape(3, 1))
    C = p[3:].copy()
    z_min = min(float(t.xyz[2]) for t in targets)
    if not np.all(np.isfinite(C)) or C[2] > z_min - BELOW_CEILING_M:
        return None
    # Covariance: without the tracked-position prior (the filter holds it), with a weak one that
    # marks directions the outlines leave free (module doc).
    fun_c = _make_fun(targets, sigma_c, up_prior, tilt_sigma_rad, C, np.eye(3) / FREE_SIGMA_M)
    r = fun_c(p)
    J = _fd_jac(fun_c, p)
    dof = len(r) - len(p)
    chi2 = float(r @ r)
    if dof <= 0 or chi2 / dof > MAX_CHI2_DOF:
        return None
    cov6 = np.linalg.pinv(J.T @ J) * max(1.0, chi2 / dof)
    n = len(targets)
    return Fix(C, cov6[3:, 3:], R, "outline", n, chi2, dof)
