# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Host-pose solve of the vehicle stage (receiver.locate.vehicle_host._solve_native), its one
implementation: a damped soft-L1 Levenberg-Marquardt (the damping rule of receiver.locate.lsq.lm_batch) on
the residuals below, with their analytic Jacobian (a frame's solve is 2-4 evaluations of 8-30
residual rows, where numpy's per-call overhead would be most of the cost).
tests/engine/test_vehicle_native.py checks the residuals against the geometry, the Jacobian
against finite differences and the solution against scipy.optimize.least_squares.

Pose p = (Rodrigues vector of R_cw (3), camera centre C (3), m). Residual rows, in order:
* angles: per point (x, y) normalized image error / sigma_uv; the first 4 n_pairs rows (points
  a, b of each pair) turned into the pair's midpoint (x, y) and its centroid difference (x, y)
  times `sep_gain` (orthonormal turn, 1/sqrt 2);
* ranges: (|L - C| - d) / sigma_d of the points with a finite d;
* tilt prior: (R[:, 2] - up) / up_sigma (3 rows);
* position prior: W (C - C_prior) (3 rows);
* attitude rows `att` (kind 0 yaw, 1 pitch, 2 roll, 3 midpoint range; columns kind, v0, sigma,
  Mx, My, Mz, D, sigma_D): yaw = the optical axis's azimuth atan2(R[2, 1], R[2, 0]) (wrapped),
  pitch = asin(R[2, 2]), roll = atan2(-R[0, 2], -R[1, 2]) (receiver.locate.pose.ypr_to_rotation's
  angles), midpoint range = |M - C| - D.
Rodrigues' rotation and derivative are OpenCV's formulas (cv::Rodrigues, 3x9 row-major dR/drvec).
"""

from libc.math cimport sqrt, sin, cos, atan2, asin, fabs, fmod, M_PI, isfinite
from receiver.locate._rodrigues cimport rodrigues
from receiver.locate._solve6 cimport lm_damping, lm_step
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy



cdef inline double wrap_pi(double a) noexcept nogil:
    """receiver.locate.road_kalman.wrap_pi: -((-a + pi) mod 2 pi - pi), Python's floored mod."""
    cdef double x = -a + M_PI
    cdef double m = fmod(x, 2 * M_PI)
    if m != 0.0 and (m < 0.0) != (2 * M_PI < 0.0):
        m += 2 * M_PI
    return -(m - M_PI)


cdef struct Problem:
    int M               # points
    int n_pairs
    int n_rows
    int n_att
    const double* L     # (M, 3)
    const double* uv    # (M, 2)
    const double* d     # (M,) NaN: no range row
    const double* sd    # (M,)
    const double* up    # (3,)
    const double* Cp    # (3,)
    const double* W     # (3, 3)
    const double* att   # (n_att, 8)
    double sigma_uv
    double up_sigma
    double sep_gain


cdef void evaluate(const Problem* P, const double* p, double* r, double* J) noexcept nogil:
    """Residuals r (n_rows) and Jacobian J (n_rows, 6) at p (module doc)."""
    cdef double R[9]
    cdef double dR[27]
    cdef double Y[3]
    cdef double X[3]
    cdef double dX[18]
    cdef double Vm[3]
    cdef int i, k, a, row, kind
    cdef double z, xz, yz, nrm, h, g, t0, t1, t2, t3, A0, B0, n2, v0, sig, dm, zz
    cdef double* Jr
    rodrigues(p, R, dR)
    row = 0
    for i in range(P.M):
        Y[0] = P.L[3 * i] - p[3]
        Y[1] = P.L[3 * i + 1] - p[4]
        Y[2] = P.L[3 * i + 2] - p[5]
        for a in range(3):
            X[a] = Y[0] * R[3 * a] + Y[1] * R[3 * a + 1] + Y[2] * R[3 * a + 2]
        z = X[2] if X[2] > 1e-6 else 1e-6
        for a in range(3):
            for k in range(3):
                dX[6 * a + k] = dR[9 * k + 3 * a] * Y[0] + dR[9 * k + 3 * a + 1] * Y[1] + dR[9 * k + 3 * a + 2] * Y[2]
            for k in range(3):
                dX[6 * a + 3 + k] = -R[3 * a + k]
        xz = X[0] / z
        yz = X[1] / z
        r[row] = (xz - P.uv[2 * i]) / P.sigma_uv
        r[row + 1] = (yz - P.uv[2 * i + 1]) / P.sigma_uv
        for k in range(6):
            J[6 * row + k] = ((dX[k] - xz * dX[12 + k]) / z) / P.sigma_uv
            J[6 * (row + 1) + k] = ((dX[6 + k] - yz * dX[12 + k]) / z) / P.sigma_uv
        row += 2
    # A pair's two points -> midpoint and (scaled) difference.
    h = 1.0 / sqrt(2.0)
    g = P.sep_gain
    for i in range(P.n_pairs):
        a = 4 * i
        t0, t1, t2, t3 = r[a], r[a + 1], r[a + 2], r[a + 3]
        r[a] = h * t0 + 0.0 * t1 + h * t2 + 0.0 * t3
        r[a + 1] = 0.0 * t0 + h * t1 + 0.0 * t2 + h * t3
        r[a + 2] = (-h * g) * t0 + 0.0 * t1 + (h * g) * t2 + 0.0 * t3
        r[a + 3] = 0.0 * t0 + (-h * g) * t1 + 0.0 * t2 + (h * g) * t3
        for k in range(6):
            t0, t1, t2, t3 = J[6 * a + k], J[6 * (a + 1) + k], J[6 * (a + 2) + k], J[6 * (a + 3) + k]
            J[6 * a + k] = h * t0 + 0.0 * t1 + h * t2 + 0.0 * t3
            J[6 * (a + 1) + k] = 0.0 * t0 + h * t1 + 0.0 * t2 + h * t3
            J[6 * (a + 2) + k] = (-h * g) * t0 + 0.0 * t1 + (h * g) * t2 + 0.0 * t3
            J[6 * (a + 3) + k] = 0.0 * t0 + (-h * g) * t1 + 0.0 * t2 + (h * g) * t3
    for i in range(P.M):
        if not isfinite(P.d[i]):
            continue
        Y[0] = P.L[3 * i] - p[3]
        Y[1] = P.L[3 * i + 1] - p[4]
        Y[2] = P.L[3 * i + 2] - p[5]
        nrm = sqrt(Y[0] * Y[0] + Y[1] * Y[1] + Y[2] * Y[2])
        t0 = 1.0 / P.sd[i]
        r[row] = (nrm - P.d[i]) * t0
        Jr = J + 6 * row
        Jr[0] = 0.0
        Jr[1] = 0.0
        Jr[2] = 0.0
        for k in range(3):
            Jr[3 + k] = -(Y[k] / nrm) * t0
        row += 1
    for a in range(3):
        r[row] = (R[3 * a + 2] - P.up[a]) / P.up_sigma
        Jr = J + 6 * row
        for k in range(3):
            Jr[k] = dR[9 * k + 3 * a + 2] / P.up_sigma
            Jr[3 + k] = 0.0
        row += 1
    for a in range(3):
        r[row] = P.W[3 * a] * (p[3] - P.Cp[0]) + P.W[3 * a + 1] * (p[4] - P.Cp[1]) + P.W[3 * a + 2] * (p[5] - P.Cp[2])
        Jr = J + 6 * row
        for k in range(3):
            Jr[k] = 0.0
            Jr[3 + k] = P.W[3 * a + k]
        row += 1
    for i in range(P.n_att):
        kind = <int>P.att[8 * i]
        v0 = P.att[8 * i + 1]
        sig = P.att[8 * i + 2]
        Jr = J + 6 * row
        for k in range(6):
            Jr[k] = 0.0
        if kind == 0:           # yaw: azimuth of the optical axis
            A0, B0 = R[6], R[7]
            n2 = A0 * A0 + B0 * B0
            if n2 < 1e-12:
                n2 = 1e-12
            r[row] = wrap_pi(atan2(B0, A0) - v0) / sig
            for k in range(3):
                Jr[k] = (A0 * dR[9 * k + 7] - B0 * dR[9 * k + 6]) / n2 / sig
        elif kind == 1:         # pitch: elevation of the optical axis
            zz = R[8]
            if zz < -1.0 + 1e-12:
                zz = -1.0 + 1e-12
            if zz > 1.0 - 1e-12:
                zz = 1.0 - 1e-12
            r[row] = (asin(zz) - v0) / sig
            for k in range(3):
                Jr[k] = dR[9 * k + 8] / sqrt(1.0 - zz * zz) / sig
        elif kind == 2:         # roll
            A0, B0 = -R[2], -R[5]
            n2 = A0 * A0 + B0 * B0
            if n2 < 1e-12:
                n2 = 1e-12
            r[row] = wrap_pi(atan2(A0, B0) - v0) / sig
            for k in range(3):
                Jr[k] = (B0 * -dR[9 * k + 2] - A0 * -dR[9 * k + 5]) / n2 / sig
        else:                   # a head's midpoint range
            Vm[0] = P.att[8 * i + 3] - p[3]
            Vm[1] = P.att[8 * i + 4] - p[4]
            Vm[2] = P.att[8 * i + 5] - p[5]
            dm = sqrt(Vm[0] * Vm[0] + Vm[1] * Vm[1] + Vm[2] * Vm[2])
            r[row] = (dm - P.att[8 * i + 6]) / P.att[8 * i + 7]
            nrm = dm if dm > 1e-9 else 1e-9
            for k in range(3):
                Jr[3 + k] = -Vm[k] / nrm / P.att[8 * i + 7]
        row += 1


cdef double soft_l1_cost(const double* r, int n, double f_scale, double* w) noexcept nogil:
    """0.5 f^2 sum 2 (sqrt(1 + z) - 1), z = (r / f)^2; w: the IRLS weights 1 / sqrt(1 + z)."""
    cdef double s = 0.0, z, q
    cdef int i
    for i in range(n):
        z = (r[i] / f_scale) * (r[i] / f_scale)
        q = sqrt(1.0 + z)
        s += 2.0 * (q - 1.0)
        w[i] = 1.0 / q
    return 0.5 * f_scale * f_scale * s


cdef inline double absmax(const double* v, int i0) noexcept nogil:
    """max |v[i0:i0 + 3]|, NaN when any is NaN (numpy's max)."""
    cdef double m = fabs(v[i0])
    cdef int k
    for k in range(i0 + 1, i0 + 3):
        if fabs(v[k]) != fabs(v[k]):
            return fabs(v[k])
        if fabs(v[k]) > m:
            m = fabs(v[k])
    return m


cdef void _check_sizes(double[:, ::1] L, double[:, ::1] uv, double[::1] d, double[::1] sd,
                       double[::1] up, double[::1] C_prior, double[:, ::1] W, int n_pairs,
                       double[:, ::1] att, double[::1] p, double[::1] r_out, double[:, ::1] J_out) except *:
    """ValueError unless every array has the shape the problem's M = len(L) points imply (the
    kernel reads them unchecked): L (M, 3), uv (M, 2), d and sd (M,), up and C_prior (3,),
    W (3, 3), 0 <= 2 n_pairs <= M, att (n_att, 8), p (6,), r_out (rows(M, n_d, n_att),),
    J_out (len(r_out), 6), n_d the finite entries of d."""
    cdef Py_ssize_t M = L.shape[0], i
    cdef int n_d = 0
    if (M < 1 or L.shape[1] != 3 or uv.shape[0] != M or uv.shape[1] != 2 or d.shape[0] != M
            or sd.shape[0] != M or up.shape[0] != 3 or C_prior.shape[0] != 3 or W.shape[0] != 3
            or W.shape[1] != 3 or n_pairs < 0 or 2 * n_pairs > M
            or (att.shape[0] > 0 and att.shape[1] != 8) or p.shape[0] != 6):
        raise ValueError("host pose kernel: needs L (M>=1, 3), uv (M, 2), d, sd (M,), up, C_prior (3,), "
                         "W (3, 3), 2 n_pairs <= M, att (n, 8), p (6,)")
    for i in range(M):
        if isfinite(d[i]):
            n_d += 1
    if r_out.shape[0] != 2 * M + n_d + 6 + att.shape[0] or J_out.shape[0] != r_out.shape[0] or J_out.shape[1] != 6:
        raise ValueError("host pose kernel: r_out needs rows(M, n_d, n_att) rows and J_out (len(r_out), 6)")


def solve(double[:, ::1] L, double[:, ::1] uv, double sigma_uv, double[::1] d, double[::1] sd,
          double[::1] up, double up_sigma, double[::1] C_prior, double[:, ::1] W, int n_pairs,
          double sep_gain, double[:, ::1] att, double f_scale, double[::1] p, int max_iter,
          double rot_tol, double pos_tol, double ftol, double lam0, double lam_max,
          double[::1] r_out, double[:, ::1] J_out):
    """The damped soft-L1 Levenberg-Marquardt (`receiver.locate.lsq.lm_batch`'s damping rule) on the module
    doc's residuals, from p (6,) (overwritten by the solution); stops after an accepted step
    smaller than rot_tol (rad) and pos_tol (m) in every component or one whose relative cost
    decrease is at most ftol, when the damping exceeds lam_max, or after max_iter steps.
    r_out (n_rows,), J_out (n_rows, 6): the residuals and Jacobian at the solution. Returns the
    number of residual evaluations."""
    cdef Problem P
    cdef int n = r_out.shape[0]
    cdef int i, j, k, it, n_eval = 0
    cdef double c, c_new, lam, t, mr, mp
    cdef double A[36]
    cdef double g[6]
    cdef double bb[6]
    cdef double dA[6]
    cdef double dp[6]
    cdef double pc[6]
    cdef double pn[6]
    cdef bint stop
    cdef double* r0
    cdef double* J0
    cdef double* w0
    cdef double* r1
    cdef double* J1
    cdef double* w1
    cdef double* tmp
    _check_sizes(L, uv, d, sd, up, C_prior, W, n_pairs, att, p, r_out, J_out)
    P.M = L.shape[0]
    P.n_pairs = n_pairs
    P.n_rows = n
    P.n_att = att.shape[0]
    P.L = &L[0, 0]
    P.uv = &uv[0, 0]
    P.d = &d[0]
    P.sd = &sd[0]
    P.up = &up[0]
    P.Cp = &C_prior[0]
    P.W = &W[0, 0]
    P.att = &att[0, 0] if P.n_att > 0 else NULL
    P.sigma_uv = sigma_uv
    P.up_sigma = up_sigma
    P.sep_gain = sep_gain
    buf = <double*>malloc(sizeof(double) * n * 16)
    if buf == NULL:
        raise MemoryError()
    r0, J0, w0 = buf, buf + n, buf + 7 * n
    r1, J1, w1 = buf + 8 * n, buf + 9 * n, buf + 15 * n
    try:
        for k in range(6):
            pc[k] = p[k]
        evaluate(&P, pc, r0, J0)
        n_eval += 1
        c = soft_l1_cost(r0, n, f_scale, w0)
        lam = lam0
        for it in range(max_iter):
            # A = J' W J, g = J' W r (w0: the loss weights at the current residuals).
            for j in range(6):
                for k in range(j, 6):
                    t = 0.0
                    for i in range(n):
                        t += J0[6 * i + j] * (J0[6 * i + k] * w0[i])
                    A[6 * j + k] = t
                    A[6 * k + j] = t
                t = 0.0
                for i in range(n):
                    t += (J0[6 * i + j] * w0[i]) * r0[i]
                g[j] = t
            lm_damping(A, dA)
            for k in range(6):
                bb[k] = -g[k]
            while True:
                lm_step(A, dA, bb, lam, pc, dp, pn)
                evaluate(&P, pn, r1, J1)
                n_eval += 1
                c_new = soft_l1_cost(r1, n, f_scale, w1)
                if c_new <= c:
                    break
                lam *= 10.0
                if lam > lam_max:
                    break
            if not c_new <= c:
                break           # damping ran out: the current point stands
            mr = absmax(dp, 0)
            mp = absmax(dp, 3)
            stop = (mr <= rot_tol and mp <= pos_tol) or c - c_new <= ftol * c
            memcpy(pc, pn, sizeof(double) * 6)
            tmp = r0; r0 = r1; r1 = tmp
            tmp = J0; J0 = J1; J1 = tmp
            tmp = w0; w0 = w1; w1 = tmp
            c = c_new
            lam = lam / 10.0
            if lam < 1e-12:
                lam = 1e-12
            if stop:
                break
        for k in range(6):
            p[k] = pc[k]
        for i in range(n):
            r_out[i] = r0[i]
            for k in range(6):
                J_out[i, k] = J0[6 * i + k]
    finally:
        free(buf)
    return n_eval


def rows(int M, int n_d, int n_att):
    """Residual rows of a problem: 2 per point, the ranges, 6 prior rows, the attitude rows."""
    return 2 * M + n_d + 6 + n_att


def covariance(double[::1] r, double[:, ::1] J, double[:, ::1] out):
    """receiver.locate.lsq.covariance_at of a full-rank solution: out (6, 6) = s^2 (J' J)^-1,
    s^2 = max(1, chi^2 / dof), the inverse by Cholesky (J' J is symmetric positive definite
    when the solve is determined; pinv then equals the inverse). Returns 0, or 1 when a
    Cholesky pivot is not positive and finite (rank-deficient: the caller's pinv decides)."""
    if r.shape[0] < 1 or J.shape[0] != r.shape[0] or J.shape[1] != 6 or out.shape[0] != 6 or out.shape[1] != 6:
        raise ValueError("covariance kernel: r (n>=1,), J (n, 6), out (6, 6) needed")
    return cov_core(&r[0], &J[0, 0], r.shape[0], &out[0, 0])


cdef int cov_core(const double* r, const double* J, int n, double* out) noexcept nogil:
    cdef int i, j, k
    cdef double A[36]
    cdef double Li[36]
    cdef double t, chi2 = 0.0, s2
    for j in range(6):
        for k in range(j, 6):
            t = 0.0
            for i in range(n):
                t += J[6 * i + j] * J[6 * i + k]
            A[6 * j + k] = t
            A[6 * k + j] = t
    # A = L L' (L in the lower triangle of A).
    for j in range(6):
        t = A[7 * j]
        for k in range(j):
            t -= A[6 * j + k] * A[6 * j + k]
        if not (t > 0.0 and t < 1e308):
            return 1
        A[7 * j] = sqrt(t)
        for i in range(j + 1, 6):
            t = A[6 * i + j]
            for k in range(j):
                t -= A[6 * i + k] * A[6 * j + k]
            A[6 * i + j] = t / A[7 * j]
    # Li = L^-1 (lower triangular).
    for i in range(36):
        Li[i] = 0.0
    for j in range(6):
        Li[7 * j] = 1.0 / A[7 * j]
        for i in range(j + 1, 6):
            t = 0.0
            for k in range(j, i):
                t -= A[6 * i + k] * Li[6 * k + j]
            Li[6 * i + j] = t / A[7 * i]
    for i in range(n):
        chi2 += r[i] * r[i]
    s2 = 1.0
    if n > 6 and chi2 / (n - 6) > 1.0:
        s2 = chi2 / (n - 6)
    # (L L')^-1 = Li' Li.
    for j in range(6):
        for k in range(j, 6):
            t = 0.0
            for i in range(k, 6):
                t += Li[6 * i + j] * Li[6 * i + k]
            out[6 * j + k] = t * s2
            out[6 * k + j] = t * s2
    return 0


def solve_pose(double[:, ::1] L, double[:, ::1] uv, double sigma_uv, double[::1] d, double[::1] sd,
               double[::1] up, double up_sigma, double[::1] C_prior, double[:, ::1] W, int n_pairs,
               double sep_gain, double[:, ::1] att, double f_scale, double[::1] p, int max_iter,
               double rot_tol, double pos_tol, double ftol, double lam0, double lam_max,
               double[::1] r_out, double[:, ::1] J_out, double[:, ::1] R_out, double[:, ::1] cov_out):
    """`solve`, then the checks of a usable fix: returns 0 with R_out (the
    solved R_cw, Rodrigues of p[:3]) and cov_out (6, 6, `covariance`); 1: p not finite; 2: the
    camera at or above the lowest point of L; 3: J' J not positive definite (R_out set; the
    caller's pinv decides from r_out, J_out); 4: the position covariance not finite."""
    cdef int i, k
    cdef double zmin
    cdef double dR[27]
    if R_out.shape[0] != 3 or R_out.shape[1] != 3 or cov_out.shape[0] != 6 or cov_out.shape[1] != 6:
        raise ValueError("host pose kernel: R_out (3, 3) and cov_out (6, 6) needed")
    solve(L, uv, sigma_uv, d, sd, up, up_sigma, C_prior, W, n_pairs, sep_gain, att, f_scale, p, max_iter,
          rot_tol, pos_tol, ftol, lam0, lam_max, r_out, J_out)
    for k in range(6):
        if not isfinite(p[k]):
            return 1
    rodrigues(&p[0], &R_out[0, 0], dR)
    zmin = L[0, 2]
    for i in range(1, L.shape[0]):
        if L[i, 2] < zmin:
            zmin = L[i, 2]
    if p[5] >= zmin:
        return 2
    if cov_core(&r_out[0], &J_out[0, 0], r_out.shape[0], &cov_out[0, 0]):
        return 3
    for i in range(3, 5):
        for k in range(3, 5):
            if not isfinite(cov_out[i, k]):
                return 4
    return 0
