# cython: language_level=3
"""The robust losses of the locate kernels (scipy.optimize.least_squares' rho(z) of z = (r / f)^2
and the IRLS weight rho'(z)), shared by receiver.locate._pnp and _outline. Codes: pose.KERNEL_LOSSES
and outline_pose.LOSS_CODES (0 linear, 1 soft_l1, 2 cauchy, 3 huber)."""

from libc.math cimport sqrt, log1p

cdef enum:
    LOSS_LINEAR = 0
    LOSS_SOFT_L1 = 1
    LOSS_CAUCHY = 2
    LOSS_HUBER = 3


cdef inline double loss_rho(int loss, double z) noexcept nogil:
    """rho(z) of the loss `loss`."""
    if loss == LOSS_SOFT_L1:
        return 2.0 * (sqrt(1.0 + z) - 1.0)
    if loss == LOSS_CAUCHY:
        return log1p(z)
    if loss == LOSS_HUBER:
        return z if z <= 1.0 else 2.0 * sqrt(z) - 1.0
    return z


cdef inline double loss_w(int loss, double z) noexcept nogil:
    """rho'(z) of the loss `loss` (the weight of a residual's square)."""
    if loss == LOSS_SOFT_L1:
        return 1.0 / sqrt(1.0 + z)
    if loss == LOSS_CAUCHY:
        return 1.0 / (1.0 + z)
    if loss == LOSS_HUBER:
        return 1.0 if z <= 1.0 else 1.0 / sqrt(z if z > 1.0 else 1.0)
    return 1.0
