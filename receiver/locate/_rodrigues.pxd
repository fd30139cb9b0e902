# cython: language_level=3
"""cv2.Rodrigues with its Jacobian for the locate kernels (receiver.locate._outline, _pnp,
_vehicle_pose), and a world point moved into the camera frame (`cam_point`)."""

from libc.math cimport sqrt, cos, sin
from libc.float cimport DBL_EPSILON


cdef inline void rodrigues(const double* rv, double* R, double* dR) noexcept nogil:
    """cv2.Rodrigues of a rotation vector: R (3x3 row-major) and dR[k*9 + a*3 + b] = dR_ab / d rv_k
    (OpenCV's formulas)."""
    cdef double rx = rv[0], ry = rv[1], rz = rv[2]
    cdef double theta = sqrt(rx * rx + ry * ry + rz * rz)
    cdef int i, k
    cdef double c, s, c1, itheta, ri, a0, a1, a2, a3, a4
    cdef double I[9]
    cdef double rrt[9]
    cdef double r_x[9]
    cdef double drrt[27]
    cdef double d_r_x_[27]
    for k in range(9):
        I[k] = 0.0
    I[0] = I[4] = I[8] = 1.0
    if theta < DBL_EPSILON:
        for k in range(9):
            R[k] = I[k]
        for k in range(27):
            dR[k] = 0.0
        dR[5] = dR[15] = dR[19] = -1.0
        dR[7] = dR[11] = dR[21] = 1.0
        return
    c = cos(theta)
    s = sin(theta)
    c1 = 1.0 - c
    itheta = 1.0 / theta
    rx = rx * itheta
    ry = ry * itheta
    rz = rz * itheta
    rrt[0] = rx * rx; rrt[1] = rx * ry; rrt[2] = rx * rz
    rrt[3] = rx * ry; rrt[4] = ry * ry; rrt[5] = ry * rz
    rrt[6] = rx * rz; rrt[7] = ry * rz; rrt[8] = rz * rz
    r_x[0] = 0.0; r_x[1] = -rz; r_x[2] = ry
    r_x[3] = rz; r_x[4] = 0.0; r_x[5] = -rx
    r_x[6] = -ry; r_x[7] = rx; r_x[8] = 0.0
    for k in range(9):
        R[k] = c * I[k] + c1 * rrt[k] + s * r_x[k]
    for k in range(27):
        drrt[k] = 0.0
        d_r_x_[k] = 0.0
    drrt[0] = rx + rx; drrt[1] = ry; drrt[2] = rz; drrt[3] = ry; drrt[6] = rz
    drrt[10] = rx; drrt[12] = rx; drrt[13] = ry + ry; drrt[14] = rz; drrt[16] = rz
    drrt[20] = rx; drrt[23] = ry; drrt[24] = rx; drrt[25] = ry; drrt[26] = rz + rz
    d_r_x_[5] = -1.0; d_r_x_[7] = 1.0
    d_r_x_[11] = 1.0; d_r_x_[15] = -1.0
    d_r_x_[19] = -1.0; d_r_x_[21] = 1.0
    for i in range(3):
        ri = rx if i == 0 else (ry if i == 1 else rz)
        a0 = -s * ri
        a1 = (s - 2.0 * c1 * itheta) * ri
        a2 = c1 * itheta
        a3 = (c - s * itheta) * ri
        a4 = s * itheta
        for k in range(9):
            dR[i * 9 + k] = a0 * I[k] + a1 * rrt[k] + a2 * drrt[i * 9 + k] + a3 * r_x[k] + a4 * d_r_x_[i * 9 + k]


cdef inline void cam_point(const double* L, const double* C, const double* R, double* Y, double* X) noexcept nogil:
    """Y = L - C (world, m) and X = R Y: the point in the camera frame (R = R_cw, row-major)."""
    Y[0] = L[0] - C[0]
    Y[1] = L[1] - C[1]
    Y[2] = L[2] - C[2]
    X[0] = Y[0] * R[0] + Y[1] * R[1] + Y[2] * R[2]
    X[1] = Y[0] * R[3] + Y[1] * R[4] + Y[2] * R[5]
    X[2] = Y[0] * R[6] + Y[1] * R[7] + Y[2] * R[8]
