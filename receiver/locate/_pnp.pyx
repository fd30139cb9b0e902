# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Centroid + range pose refinement (`receiver.locate.pose.refine_pose`), its one implementation:
the whitened residuals -- reprojection (2 per LED, normalized units / sigma_uv), the finite
ranges (/ sigma_d), the tilt prior (3), the position prior (3) -- their analytic Jacobian, and a
robust Levenberg-Marquardt (IRLS weights rho'(z) of scipy's losses, damping
lam * max(diag A, 1e-12) from 1e-3, x10 on a rejected step up to 1e8, / 10 on a kept one down to
1e-12, stop on a relative step below LM_XTOL or a relative cost decrease below LM_FTOL) in one call.
tests/locate/test_refine_pose.py checks it against known poses, cv2.projectPoints, finite
differences and cv2.solvePnP.

Parameters p = (Rodrigues vector of R_cw (3), C (3) world m)."""

from libc.math cimport sqrt
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy
from receiver.locate._rodrigues cimport rodrigues, cam_point
from receiver.locate._solve6 cimport lm_damping, lm_step
from receiver.locate._loss cimport loss_rho, loss_w
from receiver.core._npsum cimport pw_sum

# lsq.LM_LAMBDA0, LM_LAMBDA_MAX (the damping bounds of lsq.lm_batch, the same rule).
DEF LAMBDA0 = 1e-3
DEF LAMBDA_MAX = 1e8


cdef struct Prob:
    int n                  # LEDs
    int m                  # residuals
    const double* L        # (n, 3) world m
    const double* uv       # (n, 2) normalized
    const double* d        # (n,) ranges m, NaN / inf: none
    const double* sd       # (n,) their 1-sigma m
    double sig             # sigma_uv (divided by)
    int has_up
    double up[3]
    double up_sig
    int has_prior
    double Cp[3]
    double W[9]


cdef inline bint finite(double x) noexcept nogil:
    return x - x == 0.0


cdef inline double offset(const double* L, const double* C, double* Y) noexcept nogil:
    """Y = L - C (world, m); returns |Y|."""
    Y[0] = L[0] - C[0]
    Y[1] = L[1] - C[1]
    Y[2] = L[2] - C[2]
    return sqrt(Y[0] * Y[0] + Y[1] * Y[1] + Y[2] * Y[2])


cdef void residuals(const Prob* pr, const double* p, double* r, double* R, double* dR) noexcept nogil:
    """The whitened residuals r (m,) at p (module doc); R, dR: Rodrigues of p[:3] and its Jacobian."""
    cdef int i, k, j = 2 * pr.n
    cdef double z, nrm
    cdef double Y[3]
    cdef double X[3]
    cdef const double* C = p + 3
    rodrigues(p, R, dR)
    for i in range(pr.n):
        cam_point(pr.L + 3 * i, C, R, Y, X)
        z = X[2] if X[2] > 1e-6 else 1e-6
        r[2 * i] = (X[0] / z - pr.uv[2 * i]) / pr.sig
        r[2 * i + 1] = (X[1] / z - pr.uv[2 * i + 1]) / pr.sig
    for i in range(pr.n):
        if finite(pr.d[i]):
            nrm = offset(pr.L + 3 * i, C, Y)
            r[j] = (nrm - pr.d[i]) * (1.0 / pr.sd[i])
            j += 1
    if pr.has_up:
        for k in range(3):
            r[j + k] = (R[3 * k + 2] - pr.up[k]) / pr.up_sig
        j += 3
    if pr.has_prior:
        for k in range(3):
            r[j + k] = pr.W[3 * k] * (C[0] - pr.Cp[0]) + pr.W[3 * k + 1] * (C[1] - pr.Cp[1]) \
                + pr.W[3 * k + 2] * (C[2] - pr.Cp[2])


cdef void jacobian(const Prob* pr, const double* p, const double* R, const double* dR, double* J) noexcept nogil:
    """The residuals' Jacobian J (m, 6) row-major at p (R, dR from `residuals` at p)."""
    cdef int i, k, a, j = 2 * pr.n
    cdef double z, xz, yz, nrm, wd
    cdef double Y[3]
    cdef double X[3]
    cdef double dX[18]
    cdef double* row
    cdef const double* C = p + 3
    for i in range(pr.n):
        cam_point(pr.L + 3 * i, C, R, Y, X)
        z = X[2] if X[2] > 1e-6 else 1e-6
        for a in range(3):          # dX[a * 6 + k]: d X_a / d p_k
            for k in range(3):
                dX[6 * a + k] = dR[9 * k + 3 * a] * Y[0] + dR[9 * k + 3 * a + 1] * Y[1] + dR[9 * k + 3 * a + 2] * Y[2]
                dX[6 * a + 3 + k] = -R[3 * a + k]
        xz = X[0] / z
        yz = X[1] / z
        row = J + 12 * i
        for k in range(6):
            row[k] = (dX[k] - xz * dX[12 + k]) / z / pr.sig
            row[6 + k] = (dX[6 + k] - yz * dX[12 + k]) / z / pr.sig
    for i in range(pr.n):
        if finite(pr.d[i]):
            nrm = offset(pr.L + 3 * i, C, Y)
            wd = 1.0 / pr.sd[i]
            row = J + 6 * j
            row[0] = 0.0
            row[1] = 0.0
            row[2] = 0.0
            row[3] = -(Y[0] / nrm) * wd
            row[4] = -(Y[1] / nrm) * wd
            row[5] = -(Y[2] / nrm) * wd
            j += 1
    if pr.has_up:
        for a in range(3):
            row = J + 6 * (j + a)
            for k in range(3):
                row[k] = dR[9 * k + 3 * a + 2] / pr.up_sig
                row[3 + k] = 0.0
        j += 3
    if pr.has_prior:
        for a in range(3):
            row = J + 6 * (j + a)
            for k in range(3):
                row[k] = 0.0
                row[3 + k] = pr.W[3 * a + k]


cdef double cost_of(const double* r, int m, int loss, double fs, double* z) noexcept nogil:
    """`lsq._loss_cost`: 0.5 f_scale^2 sum rho(z), z = (r / f_scale)^2 (z kept for the weights)."""
    cdef int i
    cdef double q
    cdef double* rho = z + m
    for i in range(m):
        q = r[i] / fs
        z[i] = q * q
        rho[i] = loss_rho(loss, z[i])
    return 0.5 * fs * fs * pw_sum(rho, m)


cdef int lm(const Prob* pr, double* p, double* r, double* J, double* z, double* r_new, double* z_new,
            int loss, double fs, int max_iter, double xtol, double ftol) noexcept nogil:
    """Robust Levenberg-Marquardt (module doc; `lsq.lm_batch`'s rule for one problem): p, r, J
    end at the returned pose (J at p). Returns 1 when converged (also when the damping ran out),
    0 when max_iter ran out."""
    cdef double A[36]
    cdef double g[6]
    cdef double mg[6]
    cdef double dA[6]
    cdef double dp[6]
    cdef double p_new[6]
    cdef double R[9]
    cdef double dR[27]
    cdef double lam = LAMBDA0, c, c_new, wi, ja, s_dp, s_p
    cdef int it, i, a, b, k, stop, converged = 0, m = pr.m
    cdef double* t
    residuals(pr, p, r, R, dR)
    c = cost_of(r, m, loss, fs, z)
    for it in range(max_iter + 1):
        jacobian(pr, p, R, dR, J)
        if it == max_iter:
            break
        for k in range(36):
            A[k] = 0.0
        for k in range(6):
            g[k] = 0.0
        for i in range(m):
            wi = loss_w(loss, z[i])
            for a in range(6):
                ja = J[6 * i + a]
                g[a] += (ja * wi) * r[i]
                for b in range(a, 6):
                    A[6 * a + b] += ja * (J[6 * i + b] * wi)
        for a in range(6):
            for b in range(a):
                A[6 * a + b] = A[6 * b + a]
        lm_damping(A, dA)
        for k in range(6):
            mg[k] = -g[k]
        while True:
            lm_step(A, dA, mg, lam, p, dp, p_new)
            residuals(pr, p_new, r_new, R, dR)
            c_new = cost_of(r_new, m, loss, fs, z_new)
            if c_new <= c:
                break
            lam *= 10.0
            if lam > LAMBDA_MAX:
                return 1                 # J is at p: computed at the top of this iteration
        s_dp = 0.0
        s_p = 0.0
        for k in range(6):
            s_dp += dp[k] * dp[k]
            s_p += p[k] * p[k]
        stop = 1 if (sqrt(s_dp) <= xtol * (1.0 + sqrt(s_p)) or c - c_new <= ftol * c) else 0
        for k in range(6):
            p[k] = p_new[k]
        memcpy(r, r_new, m * sizeof(double))
        memcpy(z, z_new, 2 * m * sizeof(double))
        c = c_new
        lam = lam / 10.0
        if lam < 1e-12:
            lam = 1e-12
        if stop:
            converged = 1
            jacobian(pr, p, R, dR, J)     # R, dR: residuals() at p_new = p
            break
    return converged


cdef int setup(Prob* pr, const double[:, ::1] L, const double[:, ::1] uv, double sigma_uv, const double[::1] d,
               const double[::1] sigma_d, const double[::1] up, double up_sigma, const double[:, ::1] W,
               const double[::1] Cp) except -1:
    cdef int n = L.shape[0], i, k, nd = 0
    if L.shape[1] != 3 or uv.shape[0] != n or uv.shape[1] != 2 or d.shape[0] != n or sigma_d.shape[0] != n \
            or up.shape[0] not in (0, 3) or Cp.shape[0] not in (0, 3) or (Cp.shape[0] == 3) != (W.shape[0] == 3) \
            or (W.shape[0] == 3 and W.shape[1] != 3) or n < 1:
        raise ValueError("inconsistent pose arrays")
    for i in range(n):
        if finite(d[i]):
            nd += 1
    pr.n = n
    pr.L = &L[0, 0]
    pr.uv = &uv[0, 0]
    pr.d = &d[0]
    pr.sd = &sigma_d[0]
    pr.sig = sigma_uv
    pr.has_up = up.shape[0] == 3
    pr.up_sig = up_sigma
    for k in range(3):
        pr.up[k] = up[k] if pr.has_up else 0.0
    pr.has_prior = Cp.shape[0] == 3
    for k in range(3):
        pr.Cp[k] = Cp[k] if pr.has_prior else 0.0
    for k in range(9):
        pr.W[k] = W[k // 3, k % 3] if pr.has_prior else 0.0
    pr.m = 2 * n + nd + 3 * pr.has_up + 3 * pr.has_prior
    return 0


def evaluate(const double[:, ::1] L, const double[:, ::1] uv, double sigma_uv, const double[::1] d,
             const double[::1] sigma_d, const double[::1] up, double up_sigma, const double[:, ::1] W,
             const double[::1] Cp, const double[:, ::1] P, double[:, ::1] r_out, double[:, :, ::1] J_out):
    """The whitened residuals (and, when J_out has rows, Jacobians) at each pose P[k] (6,):
    r_out (K, >= m), J_out (K, >= m, 6) or (0, 0, 6), their first m columns / rows filled.
    `up` / `Cp` empty: no tilt / position prior (W (3, 3): the prior's whitening, W^T W = cov^-1).
    Returns m: 2 per LED, 1 per finite range, 3 per prior (at most 3 n + 6)."""
    cdef Prob pr
    cdef double R[9]
    cdef double dR[27]
    cdef int k, K = P.shape[0]
    setup(&pr, L, uv, sigma_uv, d, sigma_d, up, up_sigma, W, Cp)
    if P.shape[1] != 6 or r_out.shape[0] != K or r_out.shape[1] < pr.m \
            or (J_out.shape[0] and (J_out.shape[0] != K or J_out.shape[1] < pr.m or J_out.shape[2] != 6)):
        raise ValueError("inconsistent pose output arrays")
    with nogil:
        for k in range(K):
            residuals(&pr, &P[k, 0], &r_out[k, 0], R, dR)
            if J_out.shape[0]:
                jacobian(&pr, &P[k, 0], R, dR, &J_out[k, 0, 0])
    return pr.m


def refine(const double[:, ::1] L, const double[:, ::1] uv, double sigma_uv, const double[::1] d,
           const double[::1] sigma_d, const double[::1] up, double up_sigma, const double[:, ::1] W,
           const double[::1] Cp, double[::1] p, int loss, double f_scale, int max_iter, double xtol, double ftol,
           double[::1] r_out, double[:, ::1] J_out):
    """The robust Levenberg-Marquardt (module doc) on the problem from p (6,), updated in place to the solution;
    the first m entries of r_out (>= m,) and rows of J_out (>= m, 6): the residuals and Jacobian
    there (m as `evaluate` returns it). Returns (m, converged)."""
    cdef Prob pr
    cdef int m, ok
    cdef double* work
    setup(&pr, L, uv, sigma_uv, d, sigma_d, up, up_sigma, W, Cp)
    m = pr.m
    if p.shape[0] != 6 or r_out.shape[0] < m or J_out.shape[0] < m or J_out.shape[1] != 6:
        raise ValueError("inconsistent pose output arrays")
    work = <double*> malloc(5 * m * sizeof(double))
    if work == NULL:
        raise MemoryError()
    with nogil:
        ok = lm(&pr, &p[0], &r_out[0], &J_out[0, 0], work, work + 2 * m, work + 3 * m, loss, f_scale, max_iter,
                xtol, ftol)
    free(work)
    return m, ok == 1
