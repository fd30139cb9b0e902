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

from receiver.locate import _outline
from receiver.locate.lsq import BELOW_CEILING_M, DEFAULT_F_SCALE, DEFAULT_LOSS, Fix

CORNER_GUARD_PX = 2.0
DEFAULT_CENTROID_SIGMA_PX = 1.5
# Position prior (m) always in the covariance: a direction the frame leaves free gets about this
# 1-sigma instead of the pseudo-inverse's silent zero.
FREE_SIGMA_M = 1.0
# A fit whose chi^2 per degree of freedom exceeds this is not trusted (wrong symmetry, wrong ID).
MAX_CHI2_DOF = 50.0
# ... unless the excess comes from a few stray edge points: a fit beyond MAX_CHI2_DOF is judged
# again without the square / rect points whose whitened residual exceeds OUTLIER_SCALES robust
# scales (1.4826 x the median |residual|, at least 1), when they are at most MAX_OUTLIER_FRACTION
# of the points (`_without_outliers`). A glare speck or a codec block at a stripe's end gives one
# or two points 50-100 sigma off, which alone push a frame's chi^2 per dof past the bound (the
# robust loss keeps them from moving the pose); a wrong symmetry or ID puts whole edges off, a
# quarter of a square's points or more.
OUTLIER_SCALES = 6.0
MAX_OUTLIER_FRACTION = 0.1
# 1-sigma (px) of an edge's common offset: where a panel's edge is seen moves as a whole with what
# the point noise does not average out (the half-level crossing of a blurred edge under a tone
# curve: gamma 1.4-2.0 and blur sigma 0.7-1.5 px move it by 0.3-0.8 px; saturation, bloom and the
# rolling-shutter shear of a turning phone). The fix's covariance adds its effect on the pose
# (`_solve_native`'s G): the points' own noise shrinks with their number, an edge's offset not.
EDGE_OFFSET_SIGMA_PX = 0.5
# Levenberg-Marquardt iterations per round (a good start converges in 3-5).
MAX_ITER = 4
# Convergence of a Levenberg-Marquardt round: the largest step component (rad, m), or the relative
# cost decrease of a step.
STEP_TOL = 2e-4
COST_RTOL = 1e-6
# A second round (`solve_outline_pose`) is run only when more points than this (count, fraction)
# changed edges at the first round's pose (0: any; a handful of corner points already move the
# indoor walk's median by about 0.1 cm).
MINOR_SWITCHES = 0
MINOR_SWITCH_FRACTION = 0.0

# The robust losses the compiled solve implements (`receiver.locate.lsq._LOSSES`), by its codes.
LOSS_CODES = {"linear": 0, "soft_l1": 1, "cauchy": 2, "huber": 3}


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


@dataclass(frozen=True)
class OutlineFrame:
    """A frame's outline targets packed (what the compiled solve takes, and what the positioner
    builds with one undistortion for the whole frame): `pts` (N, 2) normalized undistorted edge
    points of every target in turn, `sigma` (N,) their 1-sigma (normalized units), `ends` (T + 1,)
    where each target's points start (`ends[k]`) and end (`ends[k + 1]`), `xyz` (T, 3) centres
    (solving frame), `half` (T, 2) half extents along world x, y, `shapes` (T,) "square" / "rect"
    / "circle", `uv` (T, 2) envelope centroids (normalized), NaN rows where a target has none.
    Arrays C-contiguous, float64 (`ends` int64): `__post_init__` makes them so."""

    pts: np.ndarray
    sigma: np.ndarray
    ends: np.ndarray
    xyz: np.ndarray
    half: np.ndarray
    shapes: tuple[str, ...]
    uv: np.ndarray

    def __post_init__(self):
        for name in ("pts", "sigma", "xyz", "half", "uv"):
            a = getattr(self, name)
            if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.flags.c_contiguous):
                object.__setattr__(self, name, np.ascontiguousarray(a, dtype=np.float64))
        if not (isinstance(self.ends, np.ndarray) and self.ends.dtype == np.int64 and self.ends.flags.c_contiguous):
            object.__setattr__(self, "ends", np.ascontiguousarray(self.ends, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.shapes)

    @property
    def n_points(self) -> int:
        return int(self.ends[-1])

    def target(self, k: int) -> OutlineTarget:
        a, b = int(self.ends[k]), int(self.ends[k + 1])
        uv = None if np.isnan(self.uv[k, 0]) else self.uv[k]
        return OutlineTarget(self.xyz[k], self.shapes[k], (float(self.half[k, 0]), float(self.half[k, 1])),
                             self.pts[a:b], self.sigma[a:b], uv)

    @property
    def targets(self) -> list[OutlineTarget]:
        """The same targets one by one (`_without_outliers`' and the tests' form)."""
        return [self.target(k) for k in range(len(self))]

    @classmethod
    def from_targets(cls, targets: list[OutlineTarget]) -> "OutlineFrame":
        ends = np.zeros(len(targets) + 1, np.int64)
        np.cumsum([len(t.pts) for t in targets], out=ends[1:])
        uv = np.array([t.uv if t.uv is not None else (np.nan, np.nan) for t in targets], float).reshape(-1, 2)
        return cls(np.concatenate([np.asarray(t.pts, float).reshape(-1, 2) for t in targets]),
                   np.concatenate([np.asarray(t.sigma, float).ravel() for t in targets]), ends,
                   np.array([t.xyz for t in targets], float).reshape(-1, 3),
                   np.array([t.half for t in targets], float).reshape(-1, 2), tuple(t.shape for t in targets), uv)

    def with_at_least(self, n: int) -> "OutlineFrame":
        """The targets with at least n points."""
        e = self.ends.tolist()
        keep = [k for k in range(len(self)) if e[k + 1] - e[k] >= n]
        if len(keep) == len(self):
            return self
        return OutlineFrame.from_targets([self.target(k) for k in keep])


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


# A panel start (`panel_start_poses`) must reproject the quadrilateral's corners within this
# (px at unit focal length: normalized units times the focal length).
START_CORNER_PX = 6.0
# Fewest edge points of a whole panel for its own start poses.
START_MIN_POINTS = 12


def _quad(pts: np.ndarray) -> np.ndarray | None:
    """The 4 corners (4, 2) of the convex quadrilateral around a panel's edge points (the hull
    simplified until 4 vertices remain), in the hull's order, or None."""
    hull = cv2.convexHull(np.ascontiguousarray(pts, np.float32))
    if hull is None or len(hull) < 4:
        return None
    peri = cv2.arcLength(hull, True)
    for eps in (0.01, 0.02, 0.04, 0.06, 0.08):
        q = cv2.approxPolyDP(hull, eps * peri, True)
        if len(q) == 4:
            return q.reshape(4, 2).astype(float)
        if len(q) < 4:
            break
    return None


def panel_start_poses(frame: "OutlineFrame", focal_px: float, z_below: float = BELOW_CEILING_M) -> list:
    """Starting poses (R_cw, C) of the outline solve from the panels alone (no tracked pose, or
    when every other start failed): for each whole square / rect panel (centroid measured, at
    least `START_MIN_POINTS` edge points) the quadrilateral around its edge points against the
    fixture's corners in each of their 8 cyclic orders (4 rotations, 2 directions; a square's
    four-fold symmetry is in there, and the solve with every LED decides between them), each by
    OpenCV's planar PnP (IPPE, up to 2 solutions), kept where the camera is below the panel and
    the corners reproject within `START_CORNER_PX`."""
    out = []
    for k in range(len(frame)):
        if frame.shapes[k] == "circle" or np.isnan(frame.uv[k, 0]):
            continue
        a, b = int(frame.ends[k]), int(frame.ends[k + 1])
        if b - a < START_MIN_POINTS:
            continue
        quad = _quad(frame.pts[a:b])
        if quad is None:
            continue
        hx, hy = frame.half[k]
        obj = np.array([[hx, hy, 0.0], [-hx, hy, 0.0], [-hx, -hy, 0.0], [hx, -hy, 0.0]])
        L = frame.xyz[k]
        for order in (quad, quad[::-1]):
            for shift in range(4):
                img = np.roll(order, shift, axis=0)
                try:
                    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
                except cv2.error:
                    continue
                for rv, tv, err in zip(rvecs, tvecs, np.ravel(errs)):
                    if not err * focal_px <= START_CORNER_PX:
                        continue
                    R = cv2.Rodrigues(rv)[0]
                    C = L - R.T @ tv.ravel()
                    if C[2] < L[2] - z_below:
                        out.append((R, C))
    return out


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


# The six distinct entries of a symmetric 3x3 matrix (a conic), in the order of `_Problem`'s
# per-point monomials (u^2, 2uv, 2u, v^2, 2v, 1).
_I6, _J6 = np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2])


class _State:
    """One evaluation of the pose p (`_Problem.residuals`)."""

    __slots__ = ("R", "dRk", "C", "m", "rho", "nh", "circ", "Y", "X", "z")


class _Problem:
    """The whitened residuals of one frame's outline solve over p = (Rodrigues vector of R_cw, C),
    vectorised over all points of all LEDs: what `_without_outliers` judges a fit's points by
    (the solve itself is receiver/locate/_outline.pyx, on the same model).

    Squares / rects: every point of every such target is stacked once (`P_all` (M, 2), its
    target `tix`); `assign` labels the points with their edges at a pose (no Python loop over
    LEDs) and the residual of a labelled point is its distance to the image line of its edge:
    the plane through the camera centre and the edge's corners A, B has the camera-frame
    normal n = R m with m = (A - C) x (B - C) = A x B + C x (A - B), the line
    l = (n0, n1, n2) / |(n0, n1)|; the residual is w (x, y, 1) . l.
    Circles (module doc): Sampson distances to the conic Ci = R Q(C) R^T (Q in `_circles`).
    Then the envelope centroids, the tilt prior and the position prior."""

    def __init__(self, targets, focal_px, sigma_c, up, up_sigma):
        self.focal_px = focal_px
        self.sigma_c, self.up, self.up_sigma = sigma_c, up, up_sigma
        self.C_prior = self.W = None
        poly = [t for t in targets if t.shape != "circle"]
        circles = [t for t in targets if t.shape == "circle"]
        self.n_circ = len(circles)
        if circles:
            # Every circle's points stacked (`cix` their circle) with their monomials: the
            # algebraic distance x^T Ci x = phi . c6 and the conic's gradient rows.
            pts = np.concatenate([t.pts for t in circles])
            u, v = pts[:, 0], pts[:, 1]
            one, zero = np.ones(len(u)), np.zeros(len(u))
            self.c_xyz = np.array([t.xyz for t in circles], float)                # (Tc, 3)
            self.c_r2 = np.array([t.half[0] ** 2 for t in circles], float)        # (Tc,)
            self.c_x = np.column_stack([u, v, one])                                # (Nc, 3)
            self.c_phi = np.column_stack([u * u, 2 * u * v, 2 * u, v * v, 2 * v, one])
            self.c_b0 = np.column_stack([u, v, one, zero, zero, zero])             # d(Ci x)_0 / d c6
            self.c_b1 = np.column_stack([zero, u, zero, v, one, zero])             # d(Ci x)_1 / d c6
            self.c_isig = 1.0 / np.concatenate([t.sigma for t in circles])
            self.cix = np.repeat(np.arange(len(circles)), [len(t.pts) for t in circles])
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
            a = self.corners
            b = corners[:, [1, 2, 3, 0]].reshape(-1, 3)
            self.AxB = np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                                        a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])
            # dm/dC_j = e_j x (A - B): (E, 3, 3) [edge, component, j].
            self.dm_dC = np.einsum("jab,eb->eaj", _CROSS, a - b)
            self.P_all = np.concatenate([t.pts for t in poly])
            self.w_all = 1.0 / np.concatenate([t.sigma for t in poly])
            self.counts = np.array([len(t.pts) for t in poly])
            self.tix = np.repeat(np.arange(len(poly)), self.counts)
        cen = [t for t in targets if t.uv is not None]
        self.L = np.array([t.xyz for t in cen]).reshape(-1, 3)
        self.uv = np.array([t.uv for t in cen]).reshape(-1, 2)
        self.labels = None
        self.n_use = 0

    def assign(self, p, keep_minor: bool = False) -> bool:
        """Label the square / rect points with their edges at pose p (`assign_edges`, all LEDs
        at once); True when the labels changed. `keep_minor`: keep the current labels (and
        return False) unless more than `MINOR_SWITCHES` or `MINOR_SWITCH_FRACTION` of the points
        moved from one edge to another (points that only crossed the corner guard do not count;
        a few points next to a corner flip between its two edges, which lie close to them anyway).

        A point's distance to an edge whose nearest point is the edge's end is its distance to
        that corner, the same number for both edges meeting there: such a tie (a point beyond a
        corner) goes to the first edge, whatever the rounding of the two segments' arithmetic."""
        if not self.n_poly:
            first = self.labels is None
            self.labels = np.zeros(0, int)
            return first
        R, _ = cv2.Rodrigues(p[:3].reshape(3, 1))
        q = _project(R, p[3:], self.corners).reshape(-1, 4, 2)             # (T, 4, 2)
        ab = np.roll(q, -1, axis=1) - q
        inv_L2 = 1.0 / np.maximum(np.sum(ab * ab, axis=2), 1e-18)            # (T, 4)
        # Per target: corners x, y, edge vectors x, y, 1 / |edge|^2, one row of 4 each, repeated
        # for its points: (5, 4, M) planes (long rows, no per-point gather).
        tab = np.concatenate([q.transpose(2, 1, 0), ab.transpose(2, 1, 0), inv_L2.T[None]])   # (5, 4, T)
        qx, qy, abx, aby, il = np.repeat(tab, self.counts, axis=2)
        relx, rely = self.P_all[:, 0] - qx, self.P_all[:, 1] - qy
        s = (relx * abx + rely * aby) * il
        ex, ey = relx - s * abx, rely - s * aby
        c2 = relx * relx + rely * rely                                       # to each edge's start corner
        d2 = np.where(s <= 0.0, c2, np.where(s >= 1.0, c2[[1, 2, 3, 0]], ex * ex + ey * ey))
        # The nearest edge (the first on ties, as argmin over the four) and the nearest corner.
        m01, m23 = np.minimum(d2[0], d2[1]), np.minimum(d2[2], d2[3])
        lab = np.where(m23 < m01, 2 + (d2[3] < d2[2]), (d2[1] < d2[0]).astype(np.int64))
        dc = np.minimum(np.minimum(c2[0], c2[1]), np.minimum(c2[2], c2[3]))
        lab[dc < (CORNER_GUARD_PX / self.focal_px) ** 2] = -1
        if keep_minor and self.labels is not None:
            old = self.labels
            switched = int(np.count_nonzero((lab != old) & (lab >= 0) & (old >= 0)))
            if switched <= max(MINOR_SWITCHES, MINOR_SWITCH_FRACTION * len(lab)):
                return False
        changed = self.labels is None or not np.array_equal(lab, self.labels)
        self.labels = lab
        if changed:
            self._group(lab)
        return changed

    def _group(self, lab) -> None:
        """The labelled points sorted by edge: their whitened rows w (x, y, 1) as (3, M') planes
        (`SW`), the points per used edge (`cnt`) and where each edge's run starts (`starts`), the
        used edges' constants (`AxB_u`, `dm_dC_u`)."""
        use = np.flatnonzero(lab >= 0)
        self.n_use = len(use)
        if not self.n_use:
            return
        eg = (self.tix[use] * 4 + lab[use]).astype(np.int16 if len(self.corners) < 2 ** 15 else np.int64)
        order = np.argsort(eg, kind="stable")                  # a radix sort for int16
        use, eg = use[order], eg[order]
        new = np.empty(len(eg), bool)
        new[0] = True
        np.not_equal(eg[1:], eg[:-1], out=new[1:])
        self.use = use                                         # point (P_all row) of each residual
        self.starts = np.flatnonzero(new)
        self.cnt = np.diff(np.append(self.starts, len(eg)))
        edges = eg[self.starts]
        w = self.w_all[use]
        P = self.P_all[use]
        sx, sy = P[:, 0] * w, P[:, 1] * w
        self.SW = np.stack([sx, sy, w])
        self.AxB_u, self.dm_dC_u = self.AxB[edges], self.dm_dC[edges]

    def residuals(self, p):
        """(r, state): the whitened residuals at p (edge points, circle points, centroids (u, v)
        interleaved, tilt prior, position prior) and the pose's intermediate terms."""
        R, dR = cv2.Rodrigues(p[:3].reshape(3, 1))
        C = p[3:]
        st = _State()
        st.R, st.dRk, st.C = R, dR.reshape(3, 3, 3), C      # dRk[k] = dR / d rvec_k
        parts = []
        if self.n_use:
            m = self.AxB_u + self.dm_dC_u @ C
            n = m @ R.T
            rho = np.maximum(np.hypot(n[:, 0], n[:, 1]), 1e-15)
            nh = n / rho[:, None]
            st.m, st.rho, st.nh = m, rho, nh
            parts.append(np.einsum("ji,ij->i", self.SW, np.repeat(nh, self.cnt, axis=0)))
        if self.n_circ:
            rc, st.circ = self._circles(R, C)
            parts.append(rc)
        if len(self.L):
            Y = self.L - C
            X = Y @ R.T
            z = np.where(X[:, 2] > 1e-6, X[:, 2], 1e-6)
            st.Y, st.X, st.z = Y, X, z
            parts.append(((X[:, :2] / z[:, None] - self.uv) / self.sigma_c).ravel())
        if self.up is not None:
            parts.append((R[:, 2] - self.up) / self.up_sigma)
        if self.C_prior is not None:
            parts.append(self.W @ (C - self.C_prior))
        return np.concatenate(parts), st

    def _circles(self, R, C):
        """Sampson distances of every circle's points at pose (R, C), and what their Jacobian
        needs. The world circle |X - L| = r on the plane z = L_z, seen from C along the world
        direction w = R^T x of an image point x, satisfies w^T Q w = 0 with (a, b, c) = L - C,
        alpha = a / c, beta = b / c: Q = [[1, 0, -alpha], [0, 1, -beta], [-alpha, -beta,
        alpha^2 + beta^2 - r^2 / c^2]], i.e. the image conic Ci = R Q R^T (= H^-T diag(1, 1, -r^2)
        H^-1 of the module doc). A circle seen edge-on (c = 0) gets residuals of 1e3."""
        d = self.c_xyz - C
        cz = d[:, 2]
        flat = cz == 0.0
        cz = np.where(flat, 1.0, cz)
        al, be = d[:, 0] / cz, d[:, 1] / cz
        Q = np.zeros((len(cz), 3, 3))
        Q[:, 0, 0] = Q[:, 1, 1] = 1.0
        Q[:, 0, 2] = Q[:, 2, 0] = -al
        Q[:, 1, 2] = Q[:, 2, 1] = -be
        Q[:, 2, 2] = al * al + be * be - self.c_r2 / (cz * cz)
        QRt = Q @ R.T
        c6 = (R @ QRt)[:, _I6, _J6][self.cix]                                  # (Nc, 6)
        val = np.einsum("ij,ij->i", self.c_phi, c6)
        cx0 = np.einsum("ij,ij->i", self.c_x, c6[:, :3])
        cx1 = np.einsum("ij,ij->i", self.c_x, c6[:, [1, 3, 4]])
        h = np.hypot(cx0, cx1)
        r = val / np.maximum(2.0 * h, 1e-12) * self.c_isig
        if flat.any():
            r[flat[self.cix]] = 1e3
        return r, (d, cz, flat, QRt, val, cx0, cx1, h)


def solve_outline_pose(targets: list[OutlineTarget] | OutlineFrame, R0: np.ndarray, C0: np.ndarray, *, focal_px: float,
                       centroid_sigma_px: float = DEFAULT_CENTROID_SIGMA_PX, up_prior: np.ndarray | None = None,
                       tilt_sigma_rad: float = math.radians(10.0), C_prior: np.ndarray | None = None,
                       C_prior_cov: np.ndarray | None = None, loss: str = DEFAULT_LOSS,
                       f_scale: float = DEFAULT_F_SCALE, rounds: int = 2, max_iter: int = MAX_ITER) -> Fix | None:
    """Pose (R_cw, C) from the outline targets of one frame, started at (R0, C0) (module doc).
    Returns a `Fix` (method "outline") or None when the outlines do not determine a trustworthy
    position (too few points, camera not below the LEDs, residuals far beyond their sigmas).
    `targets`: a list of `OutlineTarget` or the packed `OutlineFrame` (targets with fewer than 3
    points are left out). Each of the `rounds` assigns the points to edges at the current pose and runs at most
    `max_iter` Levenberg-Marquardt iterations; a round whose assignment did not change after a
    converged one is skipped. A fit beyond `MAX_CHI2_DOF` is solved again from its result without
    its few outlying edge points (`_without_outliers`) and judged on the rest. `loss`: one of
    `LOSS_CODES` (else ValueError)."""
    if loss not in LOSS_CODES:
        raise ValueError(f"unknown loss {loss!r}: one of {', '.join(LOSS_CODES)}")
    if isinstance(targets, OutlineFrame):
        frame = targets.with_at_least(3)
        targets = None
        shapes = frame.shapes
    else:
        targets = [t for t in targets if len(t.pts) >= 3]
        frame = None
        shapes = tuple(t.shape for t in targets)
    if not shapes:
        return None
    only_circle = len(shapes) == 1 and shapes[0] == "circle"
    if only_circle and C_prior is None:
        return None
    W = None if C_prior is None else np.linalg.cholesky(np.linalg.inv(C_prior_cov)).T
    rvec, _ = cv2.Rodrigues(np.asarray(R0, float))
    p0 = np.concatenate([rvec.ravel(), np.asarray(C0, float)])
    args = (p0, focal_px, centroid_sigma_px / focal_px, up_prior, tilt_sigma_rad, C_prior, W, loss, f_scale,
            rounds, max_iter)

    def solve(targets, frame, p0):
        return _solve_native(frame if frame is not None else OutlineFrame.from_targets(targets), p0, *args[1:])

    p, R, chi2, n_res, JtJ, G = solve(targets, frame, p0)
    kept = None
    if chi2 > MAX_CHI2_DOF * (n_res + 3 - len(p)) and np.all(np.isfinite(p)):
        kept = _without_outliers(targets if targets is not None else frame.targets, p, focal_px)
        if kept is not None:
            p, R, chi2, n_res, JtJ, G = solve(kept, None, p.copy())
    C = p[3:].copy()
    z_min = float(frame.xyz[:, 2].min()) if frame is not None else min(float(t.xyz[2]) for t in targets)
    if not np.all(np.isfinite(C)) or C[2] > z_min - BELOW_CEILING_M:
        return None
    # Covariance: without the tracked-position prior (the filter holds it), with a weak one
    # (`FREE_SIGMA_M`, zero residuals) that marks directions the outlines leave free (module doc).
    dof = n_res + 3 - len(p)
    if dof <= 0 or chi2 / dof > MAX_CHI2_DOF:
        return None
    JtJ[3:, 3:] += _FREE_PRIOR
    A_inv = _covariance6(JtJ)
    cov6 = A_inv * max(1.0, chi2 / dof)
    if EDGE_OFFSET_SIGMA_PX > 0:
        # ... plus the edges' common offsets (`EDGE_OFFSET_SIGMA_PX`) through the solve's gain.
        cov6 = cov6 + (EDGE_OFFSET_SIGMA_PX / focal_px) ** 2 * (A_inv @ G @ A_inv)
    return Fix(C, cov6[3:, 3:], R, "outline", len(shapes), chi2, dof)


def _without_outliers(targets: list[OutlineTarget], p: np.ndarray, focal_px: float) -> list[OutlineTarget] | None:
    """The targets without their outlying square / rect edge points at pose p (`OUTLIER_SCALES`),
    or None when there are none or more than `MAX_OUTLIER_FRACTION` of the points."""
    prob = _Problem(targets, focal_px, 1.0, None, 1.0)
    if not prob.n_poly:
        return None
    prob.assign(p)
    if not prob.n_use:
        return None
    r = np.abs(prob.residuals(p)[0][:prob.n_use])
    scale = max(1.0, 1.4826 * float(np.median(r)))
    bad = prob.use[r > OUTLIER_SCALES * scale]
    n_all = sum(len(t.pts) for t in targets)
    if not len(bad) or len(bad) > MAX_OUTLIER_FRACTION * n_all:
        return None
    keep = np.ones(len(prob.P_all), bool)
    keep[bad] = False
    out, k = [], 0
    for t in targets:
        if t.shape == "circle":
            out.append(t)
            continue
        m = keep[k:k + len(t.pts)]
        k += len(t.pts)
        out.append(OutlineTarget(t.xyz, t.shape, t.half, t.pts[m], t.sigma[m], t.uv))
    return [t for t in out if len(t.pts) >= 3]


_EMPTY = np.zeros(0)
_NO_W = np.zeros((3, 3))
_FREE_PRIOR = np.eye(3) / FREE_SIGMA_M ** 2
# The compiled path inverts J^T J by Cholesky where it is this well conditioned (smallest pivot^2
# over the largest diagonal entry; the inverse then equals the pseudo-inverse to ~1e-8 relative
# at worst, ~1e-13 on the recordings), else takes numpy's pseudo-inverse.
SPD_MIN_PIVOT_RATIO = 1e-8


def _covariance6(JtJ: np.ndarray) -> np.ndarray:
    """(J^T J)^+ of the fix: np.linalg.pinv, or the compiled Cholesky inverse where J^T J is
    well conditioned (`SPD_MIN_PIVOT_RATIO`): the same matrix to rounding, at 1 % of the cost."""
    out = np.empty((6, 6))
    if _outline.spd_inverse(JtJ, out, SPD_MIN_PIVOT_RATIO):
        return out
    return np.linalg.pinv(JtJ)


def _solve_native(frame: OutlineFrame, p, focal_px, sigma_c, up_prior, tilt_sigma_rad, C_prior, W, loss, f_scale,
                  rounds, max_iter):
    """The rounds of `solve_outline_pose` in the kernel (receiver/locate/_outline.pyx) on the
    packed frame: (p, R_cw, chi^2 and residual count without the position prior's rows,
    unweighted J^T J without them, G): G the (6, 6) sum over the square / rect edges of g g^T,
    g = the sum over the edge's points of J_i / sigma_i (J_i a point's whitened Jacobian row):
    an offset b common to an edge's points moves the solution by -A^-1 g b (A = J^T J)."""
    lab = np.empty(len(frame.pts), np.int32)
    R = np.empty((3, 3))
    JtJ = np.empty((6, 6))
    G = np.empty((6, 6))
    _, chi2, n_res = _outline.solve(p, lab, frame.pts, frame.sigma, frame.ends, frame.xyz, frame.half,
                              np.array([s == "circle" for s in frame.shapes], np.int32), frame.uv, sigma_c,
                              _EMPTY if up_prior is None else np.ascontiguousarray(up_prior, float), tilt_sigma_rad,
                              _EMPTY if C_prior is None else np.ascontiguousarray(C_prior, float),
                              _NO_W if W is None else np.ascontiguousarray(W, float), LOSS_CODES[loss], f_scale,
                              rounds, max_iter, (CORNER_GUARD_PX / focal_px) ** 2, MINOR_SWITCHES,
                              MINOR_SWITCH_FRACTION, STEP_TOL, COST_RTOL, R, JtJ, G)
    return p, R, chi2, n_res, JtJ, G
