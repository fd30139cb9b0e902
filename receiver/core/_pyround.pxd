# cython: language_level=3
"""Python's and numpy's decimal rounding of a C double, for kernels that build output numbers
(receiver/locate/_position.pyx, _ranging.pyx): the same values as the Python code they replace.

* Python's `round(v, n)` (the double nearest to v's correctly rounded n-decimal value) is
  rint(v * 10^n) / 10^n wherever v * 10^n, as computed, is below 1e9 in magnitude and at least
  1e-6 away from a half-integer: then the computed product is within 1.2e-7 of the exact one and
  rounds to the same integer, and the division (both operands exact) is correctly rounded. Any
  other value (near a tie, large, not finite) is handed to Python's `round`.
* numpy's `round` (`ndarray.round`) is rint(v * 10^n) / 10^n by definition.
n: 0 to 22 decimals (10^n exact)."""

from libc.math cimport fabs, floor, isfinite, rint


cdef inline double pow10(int n) noexcept nogil:
    """10.0 ** n, exact for 0 <= n <= 22."""
    cdef double p = 1.0
    cdef int i
    for i in range(n):
        p *= 10.0
    return p


cdef inline bint rint_is_round(double y) noexcept nogil:
    """Is rint(y) / 10^n Python's round(v, n) for y = v * 10^n as computed (module doc)?"""
    return isfinite(y) and fabs(y) < 1e9 and fabs((y - floor(y)) - 0.5) > 1e-6


cdef inline object py_round(double v, int n):
    """Python's round(v, n)."""
    cdef double s = pow10(n)
    cdef double y = v * s
    if rint_is_round(y):
        return rint(y) / s
    return round(v, n)


cdef inline double np_round(double v, int n) noexcept nogil:
    """numpy's round(v, n)."""
    cdef double s = pow10(n)
    return rint(v * s) / s
