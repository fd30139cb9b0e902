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

from receiver.locate.lsq import (
    _LOSSES,
    lm_iterate,
    BELOW_CEILING_M,
    DEFAULT_F_SCALE,
    DEFAULT_LOSS,
    Fix,
)

CORNER_GUARD_PX = 2.0
DEFAULT_CENTROID_SIGMA_PX = 1.5
# Position prior (m) always in the covariance: a direction the frame leaves free gets about this
# 1-sigma instead of the pseudo-inverse's silent zero.
FREE_SIGMA_M = 1.0
# A fit whose chi^2 per degree of freedom exceeds this is not trusted (wrong symmetry, wrong ID).
MAX_CHI2_DOF = 50.0
# Levenberg-Marquardt iterations per round (a good start converges in 3-5).
MAX_ITER = 4
# Convergence of a Levenberg-Marquardt round: the largest step component (rad, m), or the relative
# cost decrease of a step.
STEP_TOL = 2e-4
COST_RTOL = 1e-6
# A second round (`solve_outline_pose`) is run only when more points than this (count, fraction)
# changed edges at the first round's pose (0: any; skipping a handful of corner points moved the
# walk median 0.51 -> 0.62 cm).
MINOR_SWITCHES = 0
MINOR_SWITCH_FRACTION = 0.0


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


# Cross products e_j x d as a matrix: _CROSS[j] @ d = e_j x d.
_CROSS = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                   [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                   [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], float)


class _Problem:
    """The whitened residuals of one frame's outline solve and their analytic Jacobian, over
    p = (Rodrigues vector of R_cw, C), vectorised over all points of all LEDs.

    Squares / rects: every point of every such target is stacked once (`P` (M, 2), its
    target `tix`); `assign` labels the points with their edges at a pose (no Python loop over
    LEDs) and the residual of a labelled point is its distance to the image line of its edge:
    the plane through the camera centre and the edge's corners A, B has the camera-frame
    normal n = R m with m = (A - C) x (B - C) = A x B + C x (A - B), the line (n0, n1, n2) / |(n0, n1)|.
    Circles (module doc): Sampson distances, their Jacobian by forward differences."""

    def __init__(self, targets, focal_px, sigma_c, up, up_sigma):
        self.focal_px = focal_px
        self.sigma_c, self.up, self.up_sigma = sigma_c, up, up_sigma
        self.C_prior = self.W = None
        poly = [t for t in targets if t.shape != "circle"]
        self.circles = [t for t in targets if t.shape == "circle"]
        if self.circles:
            # Every circle's points stacked (homogeneous, `cix` their circle), the circles' centres
            # and radii: `_circles` evaluates all circles, and the six perturbed poses of their
            # forward-difference Jacobian, in one batch.
            pts = np.concatenate([t.pts for t in self.circles])
            self.c_xyz = np.array([t.xyz for t in self.circles], float)           # (Tc, 3)
            self.c_r2 = np.array([t.half[0] ** 2 for t in self.circles], float)   # (Tc,)
            self.c_x = np.column_stack([pts, np.ones(len(pts))])                   # (Nc, 3)
            self.c_sigma = np.concatenate([t.sigma for t in self.circles])
            self.cix = np.repeat(np.arange(len(self.circles)), [len(t.pts) for t in self.circles])
        self.n_poly = len(poly)
        if poly:
            # The corners of every target at once (`_corners`), and the next corner of each.
            xyz = np.array([t.xyz for t in poly], float)                     # (T, 3)
            half = np.array([t.half for t in poly], float)                   # (T, 2)
            sgn = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], float)
            off = np.zeros((len(poly), 4, 3))
            off[:, :, :2] = sgn[None] * half[:, None, :]
            corners = xyz[:, None, :] + off                                  # (T, 4, 3)
            self.corners = corners.reshape(-1, 3)
            self.A = self.corners
            self.B = corners[:, [1, 2, 3, 0]].reshape(-1, 3)
            a, b = self.A, self.B
            self.AxB = np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                                        a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])
            self.D = self.A - self.B
            # dm/dC_j = e_j x (A - B): (E, 3, 3) [edge, component, j].
            self.dm_dC = np.einsum("jab,eb->eaj", _CROSS, self.D)
            counts = [len(t.pts) for t in poly]
            self.P_all = np.concatenate([t.pts for t in poly])
            self.w_all = 1.0 / np.concatenate([t.sigma for t in poly])
            self.tix = np.repeat(np.arange(len(poly)), counts)
        cen = [t for t in targets if t.uv is not None]
        self.L = np.array([t.xyz for t in cen]).reshape(-1, 3)
        self.uv = np.array([t.uv for t in cen]).reshape(-1, 2)
        self.labels = None
        self.S = None

    def assign(self, p, keep_minor: bool = False) -> bool:
        """Label the square / rect points with their edges at pose p (`assign_edges`, all LEDs
        at once); True when the labels changed. `keep_minor`: keep the current labels (and
        return False) unless more than `MINOR_SWITCHES` or `MINOR_SWITCH_FRACTION` of the points
        moved from one edge to another (points that only crossed the corner guard do not count;
        a few points next to a corner flip between its two edges, which lie close to them anyway)."""
        if not self.n_poly:
            first = self.labels is None
            self.labels = np.zeros(0, int)
            return first
        R, _ = cv2.Rodrigues(p[:3].reshape(3, 1))
        q = _project(R, p[3:], self.corners).reshape(-1, 4, 2)             # (T, 4, 2)
        ab = np.roll(q, -1, axis=1) - q
        inv_L2 = 1.0 / np.maximum(np.sum(ab * ab, axis=2), 1e-18)            # (T, 4)
        t = self.tix
        px, py = self.P_all[:, 0], self.P_all[:, 1]
        # The four edges one after the other over (M,) arrays (short-axis reductions are slow):
        # the nearest edge (the first on ties, as argmin) and the nearest corner.
        lab = np.zeros(len(t), np.int64)
        for k in range(4):
            relx, rely = px - q[t, k, 0], py - q[t, k, 1]
            abx, aby = ab[t, k, 0], ab[t, k, 1]
            s = np.clip((relx * abx + rely * aby) * inv_L2[t, k], 0.0, 1.0)
            ex, ey = relx - s * abx, rely - s * aby
            d2, c2 = ex * ex + ey * ey, relx * relx + rely * rely
            if k == 0:
                best, dc = d2, c2
            else:
                closer = d2 < best
                lab[closer] = k
                best = np.minimum(best, d2)
                dc = np.minimum(dc, c2)
        lab[dc < (CORNER_GUARD_PX / self.focal_px) ** 2] = -1
        if keep_minor and self.labels is not None:
            old = self.labels
            switched = int(np.count_nonzero((lab != old) & (lab >= 0) & (old >= 0)))
            if switched <= max(MINOR_SWITCHES, MINOR_SWITCH_FRACTION * len(lab)):
                return False
        changed = self.labels is None or not np.array_equal(lab, self.labels)
        self.labels = lab
        use = np.flatnonzero(lab >= 0)
        # r = S @ (the edges' unit lines, flattened): row i holds w_i (x_i, y_i, 1) at its edge.
        e3 = 3 * (self.tix[use] * 4 + lab[use])
        w = self.w_all[use]
        P = self.P_all[use]
        vals = np.column_stack([P[:, 0] * w, P[:, 1] * w, w]).ravel()
        cols = (e3[:, None] + np.arange(3)).ravel()
        from scipy.sparse import csr_matrix  # lazy: not needed by a map of unknown sizes (a photo)
        self.S = csr_matrix((vals, cols, np.arange(0, 3 * len(use) + 1, 3)), shape=(len(use), len(self.A) * 3))
        return changed

    def _circles(self, p, jac: bool):
        """`_circle_residuals` of every circle at pose p and, with `jac`, their forward-difference
        Jacobian (steps of 1e-7): the pose and its six perturbations evaluated together. A
        singular circle homography (a circle seen edge-on) falls back to the per-circle loop,
        which gives that circle alone its 1e3 residuals."""
        ps = np.repeat(p[None], 7 if jac else 1, axis=0)
        if jac:
            ps[np.arange(1, 7), np.arange(6)] += 1e-7
        Rs = np.array([cv2.Rodrigues(q[:3].reshape(3, 1))[0] for q in ps])        # (K, 3, 3)
        # H = [R e_x, R e_y, R (L - C)] per pose and circle: (K, Tc, 3, 3).
        H = np.empty((len(ps), len(self.circles), 3, 3))
        H[:, :, :, 0] = Rs[:, None, :, 0]
        H[:, :, :, 1] = Rs[:, None, :, 1]
        H[:, :, :, 2] = np.einsum("kab,ktb->kta", Rs, self.c_xyz[None] - ps[:, None, 3:])
        try:
            Hi = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            r = np.array([np.concatenate([_circle_residuals(t, R, q[3:]) for t in self.circles])
                          for R, q in zip(Rs, ps)])
        else:
            dg = np.ones((len(self.circles), 3))
            dg[:, 2] = -self.c_r2
            Ci = np.einsum("ktba,tb,ktbc->ktac", Hi, dg, Hi)                     # Hi^T diag Hi
            Cx = np.einsum("knij,nj->kni", Ci[:, self.cix], self.c_x)             # (K, Nc, 3)
            val = np.einsum("nj,knj->kn", self.c_x, Cx)
            g = 2.0 * np.hypot(Cx[..., 0], Cx[..., 1])
            r = val / np.maximum(g, 1e-12) / self.c_sigma
        if not jac:
            return r[0], None
        return r[0], ((r[1:] - r[0]) / 1e-7).T

    def __call__(self, p, jac: bool = True):
        R, dR = cv2.Rodrigues(p[:3].reshape(3, 1))
        C = p[3:]
        dRk = dR.reshape(3, 3, 3)                      # dRk[k] = dR / d rvec_k
        parts, jparts = [], []
        if self.n_poly and self.S.shape[0]:
            m = self.AxB + self.dm_dC @ C
            n = m @ R.T
            rho = np.maximum(np.hypot(n[:, 0], n[:, 1]), 1e-15)
            nh = n / rho[:, None]
            parts.append(self.S @ nh.ravel())
            if jac:
                dn = np.empty((len(n), 3, 6))
                dn[:, :, :3] = (m @ dRk.transpose(0, 2, 1)).transpose(1, 2, 0)   # (dRk[k] @ m_e)[a]
                dn[:, :, 3:] = R @ self.dm_dC                                       # R (e_j x D_e)
                drho = (nh[:, 0, None] * dn[:, 0] + nh[:, 1, None] * dn[:, 1]) / rho[:, None]
                dnh = dn / rho[:, None, None] - nh[:, :, None] * drho[:, None, :]
                jparts.append(self.S @ dnh.reshape(-1, 6))
        if self.circles:
            r0, Jc = self._circles(p, jac)
            parts.append(r0)
            if jac:
                jparts.append(Jc)
        if len(self.L):
            Y = self.L - C
            X = Y @ R.T
            z = np.where(X[:, 2] > 1e-6, X[:, 2], 1e-6)
            parts.append(((X[:, :2] / z[:, None] - self.uv) / self.sigma_c).ravel())
            if jac:
                dX = np.empty((len(Y), 3, 6))
                dX[:, :, :3] = np.einsum("kab,nb->nak", dRk, Y)
                dX[:, :, 3:] = -R[None]
                du = (dX[:, 0] - (X[:, 0] / z)[:, None] * dX[:, 2]) / z[:, None]
                dv = (dX[:, 1] - (X[:, 1] / z)[:, None] * dX[:, 2]) / z[:, None]
                jparts.append(np.stack([du, dv], axis=1).reshape(-1, 6) / self.sigma_c)
        if self.up is not None:
            parts.append((R[:, 2] - self.up) / self.up_sigma)
            if jac:
                J_up = np.zeros((3, 6))
                J_up[:, :3] = dRk[:, :, 2].T / self.up_sigma
                jparts.append(J_up)
        if self.C_prior is not None:
            parts.append(self.W @ (C - self.C_prior))
            if jac:
                J_c = np.zeros((3, 6))
                J_c[:, 3:] = self.W
                jparts.append(J_c)
        r = np.concatenate(parts)
        return (r, np.concatenate(jparts)) if jac else r


def _lm(prob: _Problem, p0, loss, f_scale, max_iter):
    """`receiver.locate.lsq.lm_iterate` on a problem that gives residuals and Jacobian in one
    call, stopping once a step moves the pose by less than `STEP_TOL` (m, rad) or lowers the
    cost by less than `COST_RTOL` of it (a warm start from the last frame's pose gets there in
    1-3 iterations). Returns (p, converged, r, J) with the residuals and Jacobian at p."""
    if loss not in _LOSSES:
        from scipy.optimize import least_squares  # lazy: scipy.optimize costs ~0.8 s to import (see kalman.preload)
        p = least_squares(lambda q: prob(q, False), np.asarray(p0, float), jac=lambda q: prob(q)[1], loss=loss,
                          f_scale=f_scale, method="trf").x
        r, J = prob(p)
        return p, True, r, J

    def done(dp, p, c, c_new):
        return float(np.max(np.abs(dp))) <= STEP_TOL or c - c_new <= COST_RTOL * c

    return lm_iterate(prob, p0, done, loss=loss, f_scale=f_scale, max_iter=max_iter)


def solve_outline_pose(targets: list[OutlineTarget], R0: np.ndarray, C0: np.ndarray, *, focal_px: float,
                       centroid_sigma_px: float = DEFAULT_CENTROID_SIGMA_PX, up_prior: np.ndarray | None = None,
                       tilt_sigma_rad: float = math.radians(10.0), C_prior: np.ndarray | None = None,
                       C_prior_cov: np.ndarray | None = None, loss: str = DEFAULT_LOSS,
                       f_scale: float = DEFAULT_F_SCALE, rounds: int = 2, max_iter: int = MAX_ITER) -> Fix | None:
    """Pose (R_cw, C) from the outline targets of one frame, started at (R0, C0) (module doc).
    Returns a `Fix` (method "outline") or None when the outlines do not determine a trustworthy
    position (too few points, camera not below the LEDs, residuals far beyond their sigmas).
    Each of the `rounds` assigns the points to edges at the current pose and runs at most
    `max_iter` Levenberg-Marquardt iterations; a round whose assignment did not change after a
    converged one is skipped."""
    targets = [t for t in targets if len(t.pts) >= 3]
    if not targets:
        return None
    only_circle = len(targets) == 1 and targets[0].shape == "circle"
    if only_circle and C_prior is None:
        return None
    prob = _Problem(targets, focal_px, centroid_sigma_px / focal_px, up_prior, tilt_sigma_rad)
    if C_prior is not None:
        prob.C_prior = np.asarray(C_prior, float)
        prob.W = np.linalg.cholesky(np.linalg.inv(C_prior_cov)).T
    rvec, _ = cv2.Rodrigues(np.asarray(R0, float))
    p = np.concatenate([rvec.ravel(), np.asarray(C0, float)])
    converged = False
    for k in range(rounds):
        changed = prob.assign(p, keep_minor=k > 0 and converged)
        if k > 0 and converged and not changed:
            break
        p, converged, r, J = _lm(prob, p, loss, f_scale, max_iter)
    R, _ = cv2.Rodrigues(p[:3].reshape(3, 1))
    C = p[3:].copy()
    z_min = min(float(t.xyz[2]) for t in targets)
    if not np.all(np.isfinite(C)) or C[2] > z_min - BELOW_CEILING_M:
        return None
    # Covariance: without the tracked-position prior (the filter holds it), with a weak one that
    # marks directions the outlines leave free (module doc).
    # (The residuals at p with the prior swapped: the tracked one's rows out, the weak one's in.)
    if prob.C_prior is not None:
        r, J = r[:-3], J[:-3]
    J_free = np.zeros((3, 6))
    J_free[:, 3:] = np.eye(3) / FREE_SIGMA_M
    r, J = np.concatenate([r, np.zeros(3)]), np.vstack([J, J_free])
    dof = len(r) - len(p)
    chi2 = float(r @ r)
    if dof <= 0 or chi2 / dof > MAX_CHI2_DOF:
        return None
    cov6 = np.linalg.pinv(J.T @ J) * max(1.0, chi2 / dof)
    n = len(targets)
    return Fix(C, cov6[3:, 3:], R, "outline", n, chi2, dof)
