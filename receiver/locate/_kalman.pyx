# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Kept: without it the lighting server spends 71 % more CPU per reply (docs/kernels.md).
"""The steps of the constant-velocity Kalman filter of the receiver's positioner and the lighting
server's devices (`receiver.locate.kalman.PositionKalman`; eqs. 35-39, Joseph form, H = [I 0]) on
one device's state in place, as plain loops over the 6 x 6 covariance instead of a dozen numpy
calls. tests/locate/test_kalman.py compares them with filterpy's `KalmanFilter` (to rounding).

x: (6, 1) state [m, m/s]; P: (6, 6) covariance; z (3,) a position fix [m], R (3, 3) its
covariance [m^2]; dt [s]; q the acceleration spectral density [m^2/s^3].
"""

from libc.math cimport pow

from receiver.core._buf cimport load, store


def predict(x, P, double dt, double q):
    """x = F x, P = F P F' + Q (F = [[I, dt I], [0, I]], Q of white acceleration q over dt), in place."""
    cdef int i, j
    cdef double xb[6]
    cdef double Pb[36]
    cdef double FP[6][6]
    cdef double q3 = q * (pow(dt, 3) / 3), q2 = q * (pow(dt, 2) / 2), q1 = q * dt
    load(x, xb, 6, 1)
    load(P, Pb, 6, 6)
    for i in range(3):
        xb[i] = xb[i] + dt * xb[i + 3]
    for i in range(6):
        for j in range(6):
            FP[i][j] = Pb[6 * i + j] + dt * Pb[6 * (i + 3) + j] if i < 3 else Pb[6 * i + j]
    for i in range(6):
        for j in range(6):
            Pb[6 * i + j] = FP[i][j] + dt * FP[i][j + 3] if j < 3 else FP[i][j]
    for i in range(3):
        Pb[7 * i] += q3
        Pb[6 * i + i + 3] += q2
        Pb[6 * (i + 3) + i] += q2
        Pb[7 * (i + 3)] += q1
    store(x, xb, 6, 1)
    store(P, Pb, 6, 6)


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


cdef int _innovation(x, P, z, R, double* xb, double* Pb, double* Rb, double* y, double* Si) except -1:
    """Load x (6,), P (6, 6), R (3, 3) into xb, Pb, Rb; y = z - x[:3] and Si = (P[:3, :3] + R)^-1.
    Returns 0 (Si not set) when that matrix is singular, else 1."""
    cdef double zb[3]
    cdef double S[9]
    cdef int i, j
    load(x, xb, 6, 1)
    load(P, Pb, 6, 6)
    load(z, zb, 3, 0)
    load(R, Rb, 3, 3)
    for i in range(3):
        y[i] = zb[i] - xb[i]
        for j in range(3):
            S[3 * i + j] = Pb[6 * i + j] + Rb[3 * i + j]
    return _inverse3(S, Si)


def update(x, P, z, R):
    """Measurement update with the fix z of covariance R (Joseph form), in place. Returns False
    (nothing changed) when P[:3, :3] + R is singular."""
    cdef double xb[6]
    cdef double Pb[36]
    cdef double Rb[9]
    cdef double Si[9]
    cdef double K[6][3]
    cdef double y[3]
    cdef double IKH[6][6]
    cdef double T[6][6]
    cdef double KR[6][3]
    cdef double t
    cdef int i, j, k
    if not _innovation(x, P, z, R, xb, Pb, Rb, y, Si):
        return False
    for i in range(6):
        for j in range(3):
            K[i][j] = Pb[6 * i] * Si[j] + Pb[6 * i + 1] * Si[3 + j] + Pb[6 * i + 2] * Si[6 + j]
    for i in range(6):
        xb[i] = xb[i] + (K[i][0] * y[0] + K[i][1] * y[1] + K[i][2] * y[2])
    for i in range(6):
        for j in range(6):
            IKH[i][j] = (1.0 if i == j else 0.0) - (K[i][j] if j < 3 else 0.0)
    for i in range(6):                       # T = (I - K H) P
        for j in range(6):
            t = 0.0
            for k in range(6):
                t += IKH[i][k] * Pb[6 * k + j]
            T[i][j] = t
    for i in range(6):                       # K R
        for j in range(3):
            KR[i][j] = K[i][0] * Rb[j] + K[i][1] * Rb[3 + j] + K[i][2] * Rb[6 + j]
    for i in range(6):                       # P = T (I - K H)' + K R K'
        for j in range(6):
            t = 0.0
            for k in range(6):
                t += T[i][k] * IKH[j][k]
            Pb[6 * i + j] = t + (KR[i][0] * K[j][0] + KR[i][1] * K[j][1] + KR[i][2] * K[j][2])
    store(x, xb, 6, 1)
    store(P, Pb, 6, 6)
    return True


def mahalanobis2(x, P, z, R):
    """(z - x[:3])' (P[:3, :3] + R)^-1 (z - x[:3]); NaN when that matrix is singular."""
    cdef double xb[6]
    cdef double Pb[36]
    cdef double Rb[9]
    cdef double Si[9]
    cdef double r[3]
    cdef int i, j
    cdef double out = 0.0
    if not _innovation(x, P, z, R, xb, Pb, Rb, r, Si):
        return float("nan")
    for i in range(3):
        for j in range(3):
            out += r[i] * Si[3 * i + j] * r[j]
    return out
