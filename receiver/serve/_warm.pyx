# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Kept: without it the lighting server spends 89 % more CPU per reply (docs/kernels.md).
"""Compiled warm-started fix of one frame for the lighting server (`receiver.serve.fixes`).

The same problem and solver as `receiver.locate.pose.refine_warm_batch` with
`receiver.locate.lsq.lm_batch` for a batch of one, written as plain loops over one frame's few
LEDs: whitened residuals (2 reprojection rows per LED in normalized units / sigma_uv, a range row
per ranged LED / sigma_d, 3 tilt-prior rows / up_sigma), the multiplicative orientation step
R <- exp([w]x) R (Rodrigues' formula), iteratively reweighted Levenberg-Marquardt with scipy's
robust losses, damping relative to the normal matrix' diagonal, the step and cost-decrease stopping
rules; then chi^2 and the position block of s^2 (J^T J)^-1. Numbers agree with the numpy path to
rounding (sums are taken in another order; the tests compare both); a frame is solved by itself,
so a reply does not depend on which other datagrams were batched with it.

`solve(...)` returns a status: FAIL (not converged, singular normal equations, a non-finite
number: the caller solves the frame from scratch), OK (the outputs are filled), or REFERENCE
(J^T J too close to singular for a plain inverse, where numpy's pseudo-inverse is the reference:
the caller runs the numpy path).
"""

from libc.math cimport sqrt, cos, sin, fabs, isfinite
from receiver.locate._loss cimport loss_rho, loss_w
from receiver.locate._solve6 cimport solve6

from receiver.core._buf cimport load, store

# Residual rows at most: 64 LEDs (wire.MAX_LEDS) x (2 angles + 1 range) + 3 tilt rows.
cdef enum:
    MAX_LEDS = 64
    MAX_ROWS = 3 * 64 + 3

FAIL = 0
OK = 1
REFERENCE = 2
# Losses by code (`receiver.locate.lsq._LOSSES`).
LOSS_CODES = {"linear": 0, "soft_l1": 1, "cauchy": 2, "huber": 3}
# A pivot of J^T J below this times its largest diagonal element leaves the inverse to numpy's
# pseudo-inverse (REFERENCE).
cdef double PIVOT_REL = 1e-13


cdef struct Frame:
    int n
    int has_up
    double wa            # 1 / sigma_uv
    double wt            # 1 / up_sigma
    double f_scale
    int loss
    double L[MAX_LEDS][3]
    double uv[MAX_LEDS][2]
    double d[MAX_LEDS]
    double wr[MAX_LEDS]  # 1 / sigma_d, 0 without a range
    int has_d[MAX_LEDS]
    double up[3]


cdef int _evaluate(Frame* f, double* R, double* C, double* r, double* J, double* cost) noexcept nogil:
    """Residuals r (m,) and Jacobian J (m, 6) at (R (3, 3) row-major, C (3,)); the robust cost
    0.5 f^2 sum rho((r / f)^2). Returns m."""
    cdef int k, i, j, m = 0
    cdef double Y[3]
    cdef double X[3]
    cdef double dX[3][6]
    cdef double x2, iz, u, v, s, rng, c, z, q
    for k in range(f.n):
        for i in range(3):
            Y[i] = f.L[k][i] - C[i]
        for i in range(3):
            X[i] = Y[0] * R[3 * i] + Y[1] * R[3 * i + 1] + Y[2] * R[3 * i + 2]
        x2 = X[2]
        if x2 < 1e-6:                 # behind the camera: a huge residual (NaN stays NaN)
            x2 = 1e-6
        iz = 1.0 / x2
        u = X[0] * iz
        v = X[1] * iz
        r[m] = (u - f.uv[k][0]) * f.wa
        r[m + 1] = (v - f.uv[k][1]) * f.wa
        # dX / d(w, C) = [-[X]x, -R]
        dX[0][0] = 0.0
        dX[0][1] = X[2]
        dX[0][2] = -X[1]
        dX[1][0] = -X[2]
        dX[1][1] = 0.0
        dX[1][2] = X[0]
        dX[2][0] = X[1]
        dX[2][1] = -X[0]
        dX[2][2] = 0.0
        for i in range(3):
            for j in range(3):
                dX[i][3 + j] = -R[3 * i + j]
        s = iz * f.wa
        for j in range(6):
            J[6 * m + j] = (dX[0][j] - u * dX[2][j]) * s
            J[6 * (m + 1) + j] = (dX[1][j] - v * dX[2][j]) * s
        m += 2
    for k in range(f.n):
        if not f.has_d[k]:
            continue
        for i in range(3):
            Y[i] = f.L[k][i] - C[i]
        rng = sqrt(Y[0] * Y[0] + Y[1] * Y[1] + Y[2] * Y[2])
        r[m] = (rng - f.d[k]) * f.wr[k]
        q = rng if rng > 1e-12 else 1e-12
        s = -f.wr[k] / q
        for j in range(3):
            J[6 * m + j] = 0.0
            J[6 * m + 3 + j] = Y[j] * s
        m += 1
    if f.has_up:
        # world up seen from the camera: R e_z (column 2); d/dw = -[R e_z]x
        for i in range(3):
            r[m + i] = (R[3 * i + 2] - f.up[i]) * f.wt
        _cross_rows(R[2], R[5], R[8], -f.wt, &J[6 * m])
        m += 3
    c = 0.0
    for i in range(m):
        z = (r[i] / f.f_scale) * (r[i] / f.f_scale)
        c += loss_rho(f.loss, z)
    cost[0] = 0.5 * f.f_scale * f.f_scale * c
    return m


cdef inline void _cross_rows(double a0, double a1, double a2, double s, double* J) noexcept nogil:
    """Rows 0..2 of J (stride 6): s [a]x in columns 0..2, zeros in 3..5."""
    J[0] = 0.0
    J[1] = -a2 * s
    J[2] = a1 * s
    J[6] = a2 * s
    J[7] = 0.0
    J[8] = -a0 * s
    J[12] = -a1 * s
    J[13] = a0 * s
    J[14] = 0.0
    cdef int i
    for i in range(3):
        J[6 * i + 3] = 0.0
        J[6 * i + 4] = 0.0
        J[6 * i + 5] = 0.0


cdef int _inverse6(double* A, double* Ainv) noexcept nogil:
    """Ainv = A^-1 (6 x 6 symmetric positive semi-definite, row-major) by Gauss-Jordan with
    partial pivoting; 0 when a pivot is below PIVOT_REL of the largest diagonal element."""
    cdef double M[6][12]
    cdef int i, j, k, p
    cdef double t, big = 0.0
    for i in range(6):
        big = A[7 * i] if A[7 * i] > big else big
        for j in range(6):
            M[i][j] = A[6 * i + j]
            M[i][6 + j] = 1.0 if i == j else 0.0
    if not big > 0.0:
        return 0
    for k in range(6):
        p = k
        for i in range(k + 1, 6):
            if fabs(M[i][k]) > fabs(M[p][k]):
                p = i
        if not fabs(M[p][k]) > PIVOT_REL * big:
            return 0
        if p != k:
            for j in range(12):
                t = M[k][j]
                M[k][j] = M[p][j]
                M[p][j] = t
        t = 1.0 / M[k][k]
        for j in range(12):
            M[k][j] *= t
        for i in range(6):
            if i != k and M[i][k] != 0.0:
                t = M[i][k]
                for j in range(12):
                    M[i][j] -= t * M[k][j]
    for i in range(6):
        for j in range(6):
            Ainv[6 * i + j] = M[i][6 + j]
    return 1


cdef void _rotation_step(double* w, double* R, double* out) noexcept nogil:
    """out = exp([w]x) R (3 x 3 row-major), Rodrigues' formula as `_rotation_steps` writes it."""
    cdef double th2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    cdef double th = sqrt(th2)
    cdef double a, b, ct = cos(th)
    cdef double E[3][3]
    cdef int i, j
    if th < 1e-8:
        a, b = 1.0, 0.5
    else:
        a = sin(th) / th
        b = (1.0 - ct) / (th * th)
    E[0][0] = ct + b * w[0] * w[0]
    E[0][1] = -a * w[2] + b * w[0] * w[1]
    E[0][2] = a * w[1] + b * w[0] * w[2]
    E[1][0] = a * w[2] + b * w[1] * w[0]
    E[1][1] = ct + b * w[1] * w[1]
    E[1][2] = -a * w[0] + b * w[1] * w[2]
    E[2][0] = -a * w[1] + b * w[2] * w[0]
    E[2][1] = a * w[0] + b * w[2] * w[1]
    E[2][2] = ct + b * w[2] * w[2]
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = E[i][0] * R[j] + E[i][1] * R[3 + j] + E[i][2] * R[6 + j]


cdef int _lm(Frame* f, double* R, double* C, double* r, double* J, int* m_out, double xtol, double ftol,
             double lam0, double lam_max, int max_rounds) noexcept nogil:
    """`lm_batch` of one frame from (R, C), updated in place; r, J at the solution. 1 when it
    stopped by its rules, 0 when the rounds ran out or the normal equations were singular."""
    cdef double r_new[MAX_ROWS]
    cdef double J_new[MAX_ROWS * 6]
    cdef double w[MAX_ROWS]
    cdef double A[36]
    cdef double g[6]
    cdef double dx[6]
    cdef double R_new[9]
    cdef double C_new[3]
    cdef double c, c_new, lam = lam0, t, z, norm
    cdef int m, m_new, i, j, k, rnd, accept, stop
    m = _evaluate(f, R, C, r, J, &c)
    for rnd in range(max_rounds):
        for k in range(m):
            z = (r[k] / f.f_scale) * (r[k] / f.f_scale)
            w[k] = loss_w(f.loss, z)
        for i in range(6):
            for j in range(6):
                t = 0.0
                for k in range(m):
                    t += J[6 * k + i] * (J[6 * k + j] * w[k])
                A[6 * i + j] = t
            t = 0.0
            for k in range(m):
                t += J[6 * k + i] * (w[k] * r[k])
            g[i] = -t
        for i in range(6):
            t = A[7 * i] if A[7 * i] > 1e-12 else 1e-12
            A[7 * i] += lam * t
        if solve6(A, g, dx):                 # singular: as LAPACK's gesv reports
            m_out[0] = m
            return 0
        for i in range(6):
            g[i] = dx[i]
        norm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2] + g[3] * g[3] + g[4] * g[4] + g[5] * g[5])
        if norm <= xtol:                     # nothing left to gain: done here
            m_out[0] = m
            return 1
        _rotation_step(g, R, R_new)
        for i in range(3):
            C_new[i] = C[i] + g[3 + i]
        m_new = _evaluate(f, R_new, C_new, r_new, J_new, &c_new)
        accept = c_new <= c
        if accept:
            stop = c - c_new <= ftol * c
            for i in range(9):
                R[i] = R_new[i]
            for i in range(3):
                C[i] = C_new[i]
            for k in range(m_new * 6):
                J[k] = J_new[k]
            for k in range(m_new):
                r[k] = r_new[k]
            m = m_new
            c = c_new
            lam = lam * 0.1
        else:
            stop = 0
            lam = lam * 10.0
        if lam < 1e-12:
            lam = 1e-12
        if stop or lam > lam_max:
            m_out[0] = m
            return 1
    m_out[0] = m
    return 0


def solve(L, uv, double sigma_uv, d, sigma_d, up, double up_sigma, R0, C0, str loss, double f_scale,
          double xtol, double ftol, double lam0, double lam_max, int max_rounds, out):
    """One frame's warm-started fix (module docstring). L (n, 3) m; uv (n, 2); d / sigma_d (n,)
    m (no range where d is not finite or sigma_d is not finite and positive); up (3,) or None, of
    sigma up_sigma rad; start R0 (3, 3), C0 (3,); all float64 arrays, any strides. Fills out (21,):
    the centre C (3,), R (3, 3) and the centre's covariance (3, 3, m^2), and returns
    (status, chi2, dof, the lowest LED's z, ranged LEDs)."""
    cdef Frame f
    cdef int i, j, k, m = 0, status, n
    cdef double Lb[MAX_LEDS * 3]
    cdef double uvb[MAX_LEDS * 2]
    cdef double db[MAX_LEDS]
    cdef double sdb[MAX_LEDS]
    cdef double R[9]
    cdef double C[3]
    cdef double res[21]
    cdef double r[MAX_ROWS]
    cdef double J[MAX_ROWS * 6]
    cdef double JtJ[36]
    cdef double cov[36]
    cdef double chi2 = 0.0, s2, t, z_min = 0.0
    cdef int dof, n_ranges = 0
    if loss not in LOSS_CODES or not 1 <= len(L) <= MAX_LEDS:
        return REFERENCE, 0.0, 0, z_min, 0
    n = load(L, Lb, MAX_LEDS, 3)
    if load(uv, uvb, MAX_LEDS, 2) != n or load(d, db, MAX_LEDS, 0) != n or load(sigma_d, sdb, MAX_LEDS, 0) != n:
        raise ValueError("L, uv, d and sigma_d must have one row per LED")
    load(R0, R, 3, 3)
    load(C0, C, 3, 0)
    f.n = n
    f.loss = LOSS_CODES[loss]
    f.f_scale = f_scale
    f.wa = 1.0 / sigma_uv
    f.has_up = up is not None
    f.wt = 1.0 / up_sigma if f.has_up else 0.0
    if f.has_up:
        load(up, f.up, 3, 0)
    z_min = Lb[2]
    for k in range(n):
        for i in range(3):
            f.L[k][i] = Lb[3 * k + i]
        f.uv[k][0] = uvb[2 * k]
        f.uv[k][1] = uvb[2 * k + 1]
        # `receiver.locate.pose.warm_problem`'s rule: a range counts with a finite positive sigma
        f.has_d[k] = isfinite(db[k]) and isfinite(sdb[k]) and sdb[k] > 0
        n_ranges += f.has_d[k]
        if Lb[3 * k + 2] < z_min:
            z_min = Lb[3 * k + 2]
        f.d[k] = db[k] if f.has_d[k] else 0.0
        f.wr[k] = 1.0 / sdb[k] if f.has_d[k] else 0.0
    with nogil:
        status = _lm(&f, R, C, r, J, &m, xtol, ftol, lam0, lam_max, max_rounds)
    dof = m - 6
    if not status:
        return FAIL, 0.0, dof, z_min, n_ranges
    for k in range(m):
        chi2 += r[k] * r[k]
    for i in range(6):
        for j in range(6):
            t = 0.0
            for k in range(m):
                t += J[6 * k + i] * J[6 * k + j]
            JtJ[6 * i + j] = t
    if not _inverse6(JtJ, cov):
        return REFERENCE, chi2, dof, z_min, n_ranges
    for i in range(36):
        if not isfinite(cov[i]):
            return FAIL, chi2, dof, z_min, n_ranges
    s2 = 1.0
    if dof > 0 and chi2 / dof > 1.0:
        s2 = chi2 / dof
    for i in range(3):
        res[i] = C[i]
        if not isfinite(C[i]):
            return FAIL, chi2, dof, z_min, n_ranges
        for j in range(3):
            res[3 + 3 * i + j] = R[3 * i + j]
            res[12 + 3 * i + j] = cov[6 * (3 + i) + 3 + j] * s2
            if not isfinite(R[3 * i + j]):
                return FAIL, chi2, dof, z_min, n_ranges
    store(out, res, 21, 0)
    return OK, chi2, dof, z_min, n_ranges
