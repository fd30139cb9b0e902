# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled kernels of receiver.decode.tone (the pure numpy `_peak_cycles_per_row` is the
reference): the detrended, windowed profile before the FFT and the spectrum's band peak and
median after it, the same numbers (numpy's pairwise sum for the mean, numpy's own product for
the trend; the median is a selected element, whatever the selection order). The FFT and the
three logarithms stay numpy's."""

from libc.stdlib cimport malloc, free
from receiver.core._npsum cimport pw_sum as _pw_sum

import numpy as np

ctypedef fused real_x:
    float
    double

def windowed(const real_x[::1] profile, Py_ssize_t a, Py_ssize_t b, r, double rr, const double[::1] win):
    """profile[a:b] as float64, its mean and its linear trend along the centred ramp `r`
    removed, times the window `win` (all of length b - a)."""
    cdef Py_ssize_t n = b - a, i
    cdef double mean, c
    cdef const double[::1] rv = r
    x = np.empty(n)
    cdef double[::1] xv = x
    for i in range(n):
        xv[i] = profile[a + i]
    mean = (0.0 + _pw_sum(&xv[0], n)) / <double>n
    for i in range(n):
        xv[i] = xv[i] - mean
    c = <double>(r @ x) / rr
    for i in range(n):
        xv[i] = (xv[i] - rv[i] * c) * win[i]
    return x


cdef double _select(double *v, Py_ssize_t n, Py_ssize_t k) noexcept nogil:
    """The k-th smallest of v[0:n] (v is reordered)."""
    cdef Py_ssize_t lo = 0, hi = n - 1, i, j
    cdef double p, t
    while lo < hi:
        p = v[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while v[i] < p:
                i += 1
            while v[j] > p:
                j -= 1
            if i <= j:
                t = v[i]; v[i] = v[j]; v[j] = t
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return v[k]
    return v[k]


def band_peak(const double complex[::1] z, Py_ssize_t k0, Py_ssize_t k1):
    """Power spectrum |z|^2: None when the band [k0, k1] (k1 clipped to the last bin) is under
    4 bins or its maximum sits on an edge; else (kp, quality, p[kp-1], p[kp], p[kp+1]) with kp
    the first maximum in the band (kept inside [1, size-2]) and quality = p[kp] / the median
    of p[k0:] (`_peak_cycles_per_row`)."""
    cdef Py_ssize_t size = z.shape[0], i, kp, m
    cdef double best, floor, q, pw
    cdef double *tail
    if k1 > size - 1:
        k1 = size - 1
    if k1 - k0 < 3 or k0 < 0:
        return None
    kp = k0
    best = z[k0].real * z[k0].real + z[k0].imag * z[k0].imag
    for i in range(k0 + 1, k1 + 1):
        pw = z[i].real * z[i].real + z[i].imag * z[i].imag
        if pw > best:
            best, kp = pw, i
    if kp == k0 or kp == k1:
        return None
    m = size - k0
    tail = <double *>malloc(m * sizeof(double))
    if tail == NULL:
        raise MemoryError()
    for i in range(m):
        tail[i] = z[k0 + i].real * z[k0 + i].real + z[k0 + i].imag * z[k0 + i].imag
    floor = _select(tail, m, m // 2)
    free(tail)
    q = best / (floor if not (1e-30 > floor) else 1e-30)
    if kp < 1:
        kp = 1
    if kp > size - 2:
        kp = size - 2
    return (kp, q, z[kp - 1].real * z[kp - 1].real + z[kp - 1].imag * z[kp - 1].imag,
            z[kp].real * z[kp].real + z[kp].imag * z[kp].imag,
            z[kp + 1].real * z[kp + 1].real + z[kp + 1].imag * z[kp + 1].imag)
