# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled steps of the road-frame filter (receiver.locate.road_kalman.RoadKalman, whose numpy
forms stay the reference): the prediction `_model` and the linear update `_update` on the 5-state
[x, y, psi, v, omega] with 1-3 measurement rows. Plain loops over 5x5 matrices: the numpy form
spent its time in ~25 small-array calls and an inverse per update. Products are summed in index
order (numpy's BLAS may fuse or reorder them): the numbers agree to a few ulps."""

from libc.math cimport sin, cos, fmod, M_PI


cdef inline double wrap_pi(double a) noexcept nogil:
    """road_kalman.wrap_pi: -((-a + pi) mod 2 pi - pi), Python's floored mod."""
    cdef double x = -a + M_PI
    cdef double m = fmod(x, 2 * M_PI)
    if m != 0.0 and m < 0.0:
        m += 2 * M_PI
    return -(m - M_PI)


def model(double[::1] s, double[:, ::1] P, double dt, double qa, double qw, double[::1] s2, double[:, ::1] P2):
    """RoadKalman._model: s2 = f(s, dt), P2 = F P F' + Q (white accelerations integrated over dt)."""
    cdef double x = s[0], y = s[1], psi = s[2], v = s[3], w = s[4]
    cdef double c = cos(psi), sn = sin(psi)
    cdef double F[25]
    cdef double G[10]
    cdef double FP[25]
    cdef double q0 = 0.0, q1 = 0.0, t
    cdef int i, j, k
    s2[0] = x + v * c * dt
    s2[1] = y + v * sn * dt
    s2[2] = psi + w * dt
    s2[3] = v
    s2[4] = w
    for i in range(25):
        F[i] = 0.0
    for i in range(5):
        F[6 * i] = 1.0
    F[2] = -v * sn * dt
    F[3] = c * dt
    F[7] = v * c * dt
    F[8] = sn * dt
    F[14] = dt
    G[:] = [0.5 * c * dt * dt, 0.0, 0.5 * sn * dt * dt, 0.0, 0.0, 0.5 * dt * dt, dt, 0.0, 0.0, dt]
    if dt > 0:
        q0 = qa / dt
        q1 = qw / dt
    for i in range(5):
        for j in range(5):
            t = 0.0
            for k in range(5):
                t += F[5 * i + k] * P[k, j]
            FP[5 * i + j] = t
    for i in range(5):
        for j in range(5):
            t = 0.0
            for k in range(5):
                t += FP[5 * i + k] * F[5 * j + k]
            if dt > 0:
                t += G[2 * i] * q0 * G[2 * j] + G[2 * i + 1] * q1 * G[2 * j + 1]
            P2[i, j] = t


cdef int inverse(double* S, int m, double* Si) noexcept nogil:
    """Si = S^-1 (m <= 3, Gauss-Jordan with partial pivoting); 1 when singular."""
    cdef double A[18]
    cdef int i, j, k, piv
    cdef double t, f
    for i in range(m):
        for j in range(m):
            A[2 * m * i + j] = S[m * i + j]
            A[2 * m * i + m + j] = 1.0 if i == j else 0.0
    for k in range(m):
        piv = k
        for i in range(k + 1, m):
            if abs(A[2 * m * i + k]) > abs(A[2 * m * piv + k]):
                piv = i
        if A[2 * m * piv + k] == 0.0:
            return 1
        if piv != k:
            for j in range(2 * m):
                t = A[2 * m * k + j]
                A[2 * m * k + j] = A[2 * m * piv + j]
                A[2 * m * piv + j] = t
        f = A[2 * m * k + k]
        for j in range(2 * m):
            A[2 * m * k + j] /= f
        for i in range(m):
            if i != k:
                f = A[2 * m * i + k]
                for j in range(2 * m):
                    A[2 * m * i + j] -= f * A[2 * m * k + j]
    for i in range(m):
        for j in range(m):
            Si[m * i + j] = A[2 * m * i + m + j]
    return 0


def update(double[::1] s, double[:, ::1] P, double[::1] z, double[:, ::1] H, double[:, ::1] R,
           int angle_row, double[::1] s_out, double[:, ::1] P_out):
    """RoadKalman._update: innovation y = z - H s (row `angle_row` wrapped, -1: none),
    S = H P H' + R, K = P H' S^-1, s_out = s + K y (heading wrapped), P_out = (I - K H) P
    (I - K H)' + K R K' (Joseph form). Returns (True, the innovation's Mahalanobis^2), or
    (False, 0.0) when S is singular (nothing written)."""
    cdef int m = z.shape[0], i, j, k
    cdef double y[3]
    cdef double HP[15]
    cdef double S[9]
    cdef double Si[9]
    cdef double K[15]
    cdef double PHt[15]
    cdef double IKH[25]
    cdef double A[25]
    cdef double KR[15]
    cdef double t, m2
    for i in range(m):
        t = 0.0
        for k in range(5):
            t += H[i, k] * s[k]
        y[i] = z[i] - t
        if i == angle_row:
            y[i] = wrap_pi(y[i])
    for i in range(m):
        for j in range(5):
            t = 0.0
            for k in range(5):
                t += H[i, k] * P[k, j]
            HP[5 * i + j] = t
    for i in range(m):
        for j in range(m):
            t = 0.0
            for k in range(5):
                t += HP[5 * i + k] * H[j, k]
            S[m * i + j] = t + R[i, j]
    if inverse(S, m, Si):
        return False, 0.0
    m2 = 0.0
    for i in range(m):
        t = 0.0
        for j in range(m):
            t += Si[m * i + j] * y[j]
        m2 += y[i] * t
    for i in range(5):
        for j in range(m):
            t = 0.0
            for k in range(5):
                t += P[i, k] * H[j, k]
            PHt[m * i + j] = t
    for i in range(5):
        for j in range(m):
            t = 0.0
            for k in range(m):
                t += PHt[m * i + k] * Si[m * k + j]
            K[m * i + j] = t
    for i in range(5):
        t = 0.0
        for j in range(m):
            t += K[m * i + j] * y[j]
        s_out[i] = s[i] + t
    s_out[2] = wrap_pi(s_out[2])
    for i in range(5):
        for j in range(5):
            t = 0.0
            for k in range(m):
                t += K[m * i + k] * H[k, j]
            IKH[5 * i + j] = (1.0 if i == j else 0.0) - t
    for i in range(5):
        for j in range(5):
            t = 0.0
            for k in range(5):
                t += IKH[5 * i + k] * P[k, j]
            A[5 * i + j] = t
    for i in range(5):
        for j in range(m):
            t = 0.0
            for k in range(m):
                t += K[m * i + k] * R[k, j]
            KR[m * i + j] = t
    for i in range(5):
        for j in range(5):
            t = 0.0
            for k in range(5):
                t += A[5 * i + k] * IKH[5 * j + k]
            P_out[i, j] = t
            t = 0.0
            for k in range(m):
                t += KR[m * i + k] * K[m * j + k]
            P_out[i, j] += t
    return True, m2
