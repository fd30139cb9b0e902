# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled steps of the constant-velocity Kalman filter for the lighting server's devices
(`receiver.serve.devices.FastKalman`): the same equations as `receiver.locate.kalman`
(`PositionKalman._predict`, `_update`, `_mahalanobis2`: eqs. 35-39, Joseph form, H = [I 0]) on
one device's state in place, as plain loops over the 6 x 6 covariance instead of a dozen numpy
calls. Sums are taken in another order than BLAS takes them: the numbers agree to rounding (the
tests compare both).

x: (6, 1) state [m, m/s]; P: (6, 6) covariance; z (3,) a position fix [m], R (3, 3) its
covariance [m^2]; dt [s]; q the acceleration spectral density [m^2/s^3].
"""

from libc.math cimport pow


def predict(double[:, ::1] x, double[:, ::1] P, double dt, double q):
    """x = F x, P = F P F' + Q (F = [[I, dt I], [0, I]], Q of white acceleration q over dt), in place."""
    cdef int i, j
    cdef double FP[6][6]
    cdef double q3 = q * (pow(dt, 3) / 3), q2 = q * (pow(dt, 2) / 2), q1 = q * dt
    for i in range(3):
        x[i, 0] = x[i, 0] + dt * x[i + 3, 0]
    for i in range(6):
        for j in range(6):
            FP[i][j] = P[i, j] + dt * P[i + 3, j] if i < 3 else P[i, j]
    for i in range(6):
        for j in range(6):
            P[i, j] = FP[i][j] + dt * FP[i][j + 3] if j < 3 else FP[i][j]
    for i in range(3):
        P[i, i] += q3
        P[i, i + 3] += q2
        P[i + 3, i] += q2
        P[i + 3, i + 3] += q1


cdef int _inverse3(double* S, double* Si) noexcept nogil:
    """Si = S^-1 (3 x 3 row-major) by cofactors; 0 when the determinant is 0 or not finite."""
    cdef double c00 = S[4] * S[8] - S[5] * S[7]
    cdef double c01 = S[5] * S[6] - S[3] * S[8]
    cdef double c02 = S[3] * S[7] - S[4] * S[6]
    cdef double det = S[0] * c00 + S[1] * c01 + S[2] * c02
    if not (det != 0.0 and det - det == 0.0):
        return 0
    cdef double idet = 1.0 / det
    Si[0] = c00 * idet
    Si[1] = (S[2] * S[7] - S[1] * S[8]) * idet
    Si[2] = (S[1] * S[5] - S[2] * S[4]) * idet
    Si[3] = c01 * idet
    Si[4] = (S[0] * S[8] - S[2] * S[6]) * idet
    Si[5] = (S[2] * S[3] - S[0] * S[5]) * idet
    Si[6] = c02 * idet
    Si[7] = (S[1] * S[6] - S[0] * S[7]) * idet
    Si[8] = (S[0] * S[4] - S[1] * S[3]) * idet
    return 1


def update(double[:, ::1] x, double[:, ::1] P, const double[:] z, const double[:, :] R):
    """Measurement update with the fix z of covariance R (Joseph form), in place. Returns False
    (nothing changed) when P[:3, :3] + R is singular."""
    cdef double S[9]
    cdef double Si[9]
    cdef double K[6][3]
    cdef double y[3]
    cdef double IKH[6][6]
    cdef double T[6][6]
    cdef double KR[6][3]
    cdef double t
    cdef int i, j, k
    for i in range(3):
        y[i] = z[i] - x[i, 0]
        for j in range(3):
            S[3 * i + j] = P[i, j] + R[i, j]
    if not _inverse3(S, Si):
        return False
    for i in range(6):
        for j in range(3):
            K[i][j] = P[i, 0] * Si[j] + P[i, 1] * Si[3 + j] + P[i, 2] * Si[6 + j]
    for i in range(6):
        x[i, 0] = x[i, 0] + (K[i][0] * y[0] + K[i][1] * y[1] + K[i][2] * y[2])
    for i in range(6):
        for j in range(6):
            IKH[i][j] = (1.0 if i == j else 0.0) - (K[i][j] if j < 3 else 0.0)
    for i in range(6):                       # T = (I - K H) P
        for j in range(6):
            t = 0.0
            for k in range(6):
                t += IKH[i][k] * P[k, j]
            T[i][j] = t
    for i in range(6):                       # K R
        for j in range(3):
            KR[i][j] = K[i][0] * R[0, j] + K[i][1] * R[1, j] + K[i][2] * R[2, j]
    for i in range(6):                       # P = T (I - K H)' + K R K'
        for j in range(6):
            t = 0.0
            for k in range(6):
                t += T[i][k] * IKH[j][k]
            P[i, j] = t + (KR[i][0] * K[j][0] + KR[i][1] * K[j][1] + KR[i][2] * K[j][2])
    return True


def mahalanobis2(double[:, ::1] x, double[:, ::1] P, const double[:] z, const double[:, :] R):
    """(z - x[:3])' (P[:3, :3] + R)^-1 (z - x[:3]); NaN when that matrix is singular."""
    cdef double S[9]
    cdef double Si[9]
    cdef double r[3]
    cdef int i, j
    cdef double out = 0.0
    for i in range(3):
        r[i] = z[i] - x[i, 0]
        for j in range(3):
            S[3 * i + j] = P[i, j] + R[i, j]
    if not _inverse3(S, Si):
        return float("nan")
    for i in range(3):
        for j in range(3):
            out += r[i] * Si[3 * i + j] * r[j]
    return out
