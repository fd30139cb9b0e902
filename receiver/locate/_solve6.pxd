# cython: language_level=3
"""A 6 x 6 linear solve for the locate kernels' Levenberg-Marquardt steps (receiver.locate._outline,
_pnp, _vehicle_pose): Gaussian elimination with partial pivoting, LAPACK gesv's method; and the
damped step built on it (`lm_damping`, `lm_step`: receiver.locate.lsq.lm_batch's damping)."""

from libc.math cimport fabs


cdef inline int solve6(const double* A, const double* b, double* x) noexcept nogil:
    """x = A^-1 b by Gaussian elimination with partial pivoting (LAPACK gesv's method); 1 when a
    pivot is exactly zero (singular: numpy raises LinAlgError)."""
    cdef double M[36]
    cdef double y[6]
    cdef int i, j, k, piv
    cdef double mx, f, tmp
    for i in range(36):
        M[i] = A[i]
    for i in range(6):
        y[i] = b[i]
    for k in range(6):
        piv = k
        mx = fabs(M[6 * k + k])
        for i in range(k + 1, 6):
            if fabs(M[6 * i + k]) > mx:
                mx = fabs(M[6 * i + k])
                piv = i
        if M[6 * piv + k] == 0.0:
            return 1
        if piv != k:
            for j in range(6):
                tmp = M[6 * k + j]; M[6 * k + j] = M[6 * piv + j]; M[6 * piv + j] = tmp
            tmp = y[k]; y[k] = y[piv]; y[piv] = tmp
        for i in range(k + 1, 6):
            f = M[6 * i + k] / M[6 * k + k]
            if f != 0.0:
                for j in range(k + 1, 6):
                    M[6 * i + j] -= f * M[6 * k + j]
                y[i] -= f * y[k]
    for i in range(5, -1, -1):
        tmp = y[i]
        for j in range(i + 1, 6):
            tmp -= M[6 * i + j] * x[j]
        x[i] = tmp / M[6 * i + i]
    return 0


cdef inline void lm_damping(const double* A, double* dA) noexcept nogil:
    """dA = np.maximum(diag(A), 1e-12) of a 6 x 6 row-major A (a NaN diagonal stays NaN, as there)."""
    cdef int k
    for k in range(6):
        dA[k] = A[7 * k] if A[7 * k] > 1e-12 else 1e-12
        if A[7 * k] != A[7 * k]:
            dA[k] = A[7 * k]


cdef inline void lm_step(const double* A, const double* dA, const double* mg, double lam, const double* p,
                         double* dp, double* p_new) noexcept nogil:
    """p_new = p + dp, (A + lam diag(dA)) dp = mg (dp = 0 when the damped matrix is singular)."""
    cdef double Ad[36]
    cdef int k
    for k in range(36):
        Ad[k] = A[k]
    for k in range(6):
        Ad[7 * k] += lam * dA[k]
    if solve6(Ad, mg, dp):
        for k in range(6):
            dp[k] = 0.0
    for k in range(6):
        p_new[k] = p[k] + dp[k]
