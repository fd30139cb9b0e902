# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled frame shift of receiver.vision.motion.vertical_shift (whose numpy form stays the
reference): the displacements' vertical parts filtered, binned, smoothed and their median near
the peak in one pass of plain loops (the numpy form: ~20 array calls per frame). The same IEEE
operations (floor(dy / bin + 0.5), integer counts, the median's middle or the mean of the two
middles), so the result is the numpy one to the last bit."""

from libc.math cimport floor, fabs, ceil
from libc.stdlib cimport malloc, free, qsort


cdef int _cmp(const void* a, const void* b) noexcept nogil:
    cdef double x = (<const double*>a)[0]
    cdef double y = (<const double*>b)[0]
    return (x > y) - (x < y)


cdef Py_ssize_t _collect(const double[:, ::1] prev, const double[:, ::1] xy, const double[:, ::1] extra,
                         double radius, double* out) noexcept nogil:
    """The vertical parts of every displacement xy[j] - prev[i] and of every extra row whose two
    parts lie within `radius` (numpy's `abs(d) <= radius`: NaN never), in `out`; returns how many."""
    cdef Py_ssize_t i, j, n = 0
    cdef double dx, dy
    for i in range(prev.shape[0]):
        for j in range(xy.shape[0]):
            dx = xy[j, 0] - prev[i, 0]
            dy = xy[j, 1] - prev[i, 1]
            if fabs(dx) <= radius and fabs(dy) <= radius:
                out[n] = dy
                n += 1
    for i in range(extra.shape[0]):
        dx = extra[i, 0]
        dy = extra[i, 1]
        if fabs(dx) <= radius and fabs(dy) <= radius:
            out[n] = dy
            n += 1
    return n


def vertical_shift(const double[:, ::1] prev, const double[:, ::1] xy, const double[:, ::1] extra,
                   double radius_px, double bin_px, double refine_px, int min_votes):
    """motion.vertical_shift over prev (N, 2), xy (M, 2) and the extra votes (K, 2): dy px, or
    None when fewer than `min_votes` agree. Raises ValueError on arrays not of 2 columns, or
    on a non-positive bin / a radius over 1e6 bins (the histogram's size)."""
    if prev.shape[1] != 2 or xy.shape[1] != 2 or extra.shape[1] != 2:
        raise ValueError("vertical_shift: points and votes need 2 columns")
    if not (bin_px > 0) or not (radius_px >= 0) or radius_px / bin_px > 1e6:
        raise ValueError("vertical_shift: bin_px > 0 and 0 <= radius_px <= 1e6 bins needed")
    cdef Py_ssize_t cap = prev.shape[0] * xy.shape[0] + extra.shape[0]
    cdef Py_ssize_t nb = <Py_ssize_t>ceil(radius_px / bin_px)
    cdef Py_ssize_t nh = 2 * nb + 1
    cdef double* d = <double*>malloc((cap + 1) * sizeof(double))
    cdef long* h = <long*>malloc((nh + 2) * sizeof(long))
    if d == NULL or h == NULL:
        free(d)
        free(h)
        raise MemoryError()
    cdef Py_ssize_t n, i, k, best, m
    cdef long s, top
    cdef double peak, res = 0.0
    cdef bint found = False
    try:
        n = _collect(prev, xy, extra, radius_px, d)
        if n < min_votes:
            return None
        for i in range(nh + 2):
            h[i] = 0
        for i in range(n):
            k = <Py_ssize_t>floor(d[i] / bin_px + 0.5) + nb
            k = 0 if k < 0 else (2 * nb if k > 2 * nb else k)
            h[k + 1] += 1                   # h[1 .. nh]: the bins, h[0] and h[nh + 1] zero
        best = 0
        top = -1
        for i in range(nh):
            s = h[i + 1] + h[i] + h[i + 2]
            if s > top:                     # the first maximum (numpy's argmax)
                top = s
                best = i
        peak = (best - nb) * bin_px
        m = 0
        for i in range(n):
            if fabs(d[i] - peak) <= refine_px:
                d[m] = d[i]
                m += 1
        if m < min_votes:
            return None
        qsort(d, m, sizeof(double), _cmp)
        if m % 2:
            res = d[m // 2]
        else:
            res = (d[m // 2 - 1] + d[m // 2]) / 2.0
        found = True
    finally:
        free(d)
        free(h)
    return res if found else None
