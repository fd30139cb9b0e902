# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled map-aided association of the vehicle stage (receiver.locate.vehicle
VehicleLocator._associate, whose numpy form stays the reference): the mapped heads projected
from the predicted camera with their 2x2 image covariances, every candidate pair's Mahalanobis^2
to each, the unique-gate and separation checks, in one call per frame (the numpy form: ~40
small-array calls). Products are summed in index order and the 2x2 inverse is Cramer's rule
(numpy: BLAS and LAPACK): the Mahalanobis^2 values agree to a few ulps; the decisions (gate,
separation tolerance) are the same except for a value within ulps of its threshold."""

from libc.math cimport sqrt, fabs


def associate(const double[:, ::1] H, const double[::1] Bl, const unsigned char[::1] use,
              const double[:, ::1] R, double cx, double cy, double cz, const double[:, ::1] Pxy, double add,
              double focal, const double[:, ::1] und, const double[::1] sep, double gate, double sep_tol,
              long[::1] out):
    """H (n, 3) mapped heads (m, road frame), Bl (n,) their baselines (m), `use` (n,) 0 for a head
    decoded in this frame; R (3, 3) the predicted camera's world-to-camera rotation, (cx, cy, cz)
    its centre; Pxy (2, 2) the predicted position covariance (m^2); `add` the variance (normalized
    image units^2) added on each axis; und (m, 2) the candidate pairs' undistorted midpoints, sep
    (m,) their separations (px). out (m,): the head index matched to each pair, else -1.
    Returns how many pairs were matched. Raises ValueError on mismatched sizes."""
    cdef Py_ssize_t n = H.shape[0], m = und.shape[0], h, a, k, hit, cnt
    if H.shape[1] != 3 or Bl.shape[0] != n or use.shape[0] != n or R.shape[0] != 3 or R.shape[1] != 3 \
            or Pxy.shape[0] != 2 or Pxy.shape[1] != 2 or und.shape[1] != 2 or sep.shape[0] != m \
            or out.shape[0] != m:
        raise ValueError("associate: H (n, 3), Bl (n,), use (n,), R (3, 3), Pxy (2, 2), und (m, 2), "
                         "sep (m,), out (m,) needed")
    cdef double vx, vy, vz, X0, X1, X2, u0, u1, j00, j01, j10, j11, t00, t01, t10, t11
    cdef double c00, c01, c10, c11, det, d0, d1, m2, sp
    cdef double p00 = Pxy[0, 0], p01 = Pxy[0, 1], p10 = Pxy[1, 0], p11 = Pxy[1, 1]
    # per head in view: u (2), inverse covariance (4), predicted separation
    proj = [None] * n
    cdef list ph = []
    for h in range(n):
        if not use[h]:
            continue
        vx, vy, vz = H[h, 0] - cx, H[h, 1] - cy, H[h, 2] - cz
        X0 = vx * R[0, 0] + vy * R[0, 1] + vz * R[0, 2]
        X1 = vx * R[1, 0] + vy * R[1, 1] + vz * R[1, 2]
        X2 = vx * R[2, 0] + vy * R[2, 1] + vz * R[2, 2]
        if not X2 > 1.0:
            continue
        u0, u1 = X0 / X2, X1 / X2
        # J = d(u) / d(C x, y) with dX/dC = -R[:, :2]
        j00 = (-R[0, 0] - u0 * -R[2, 0]) / X2
        j01 = (-R[0, 1] - u0 * -R[2, 1]) / X2
        j10 = (-R[1, 0] - u1 * -R[2, 0]) / X2
        j11 = (-R[1, 1] - u1 * -R[2, 1]) / X2
        t00, t01 = j00 * p00 + j01 * p10, j00 * p01 + j01 * p11      # J Pxy
        t10, t11 = j10 * p00 + j11 * p10, j10 * p01 + j11 * p11
        c00 = t00 * j00 + t01 * j01 + add                             # (J Pxy) J'
        c01 = t00 * j10 + t01 * j11
        c10 = t10 * j00 + t11 * j01
        c11 = t10 * j10 + t11 * j11 + add
        det = c00 * c11 - c01 * c10
        ph.append((h, u0, u1, c11 / det, -c01 / det, -c10 / det, c00 / det,
                   focal * Bl[h] / sqrt(vx * vx + vy * vy + vz * vz)))
    cdef Py_ssize_t nv = len(ph)
    inside = bytearray(m * nv)
    cdef unsigned char[::1] ins = inside
    for a in range(m):
        for k in range(nv):
            _, u0, u1, c00, c01, c10, c11, _ = ph[k]
            d0, d1 = und[a, 0] - u0, und[a, 1] - u1
            m2 = d0 * (c00 * d0 + c01 * d1) + d1 * (c10 * d0 + c11 * d1)
            ins[a * nv + k] = m2 <= gate
    cdef Py_ssize_t matched = 0
    for a in range(m):
        out[a] = -1
        hit = -1
        cnt = 0
        for k in range(nv):
            if ins[a * nv + k]:
                cnt += 1
                hit = k
        if cnt != 1:
            continue
        cnt = 0
        for k in range(m):
            cnt += ins[k * nv + hit]
        if cnt != 1:
            continue
        sp = ph[hit][7]
        if not (sep[a] > 0 and fabs(sep[a] / sp - 1.0) <= sep_tol):
            continue
        out[a] = ph[hit][0]
        matched += 1
    return matched
