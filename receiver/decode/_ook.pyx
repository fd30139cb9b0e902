# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled kernels of receiver.decode.ook (the pure numpy functions there are the reference).

`frame_chips`: trim rows + chip grid at a learned period + soft chips of one row profile, the
numbers of `trim_rows`, `chip_grid(..., segment_chips=0)` and `soft_chips` bit for bit: sums
follow numpy's pairwise summation (`_pw_sum`, `_pw_csum`: numpy's DOUBLE / CDOUBLE
pairwise_sum, 8 accumulators, blocks of 128 scalars) and running sums its sequential
accumulate; `np.interp` on the integer row grid is slope * (x - j) + y[j]; the phase angle is numpy's own
arctan2 (a SIMD routine on some CPUs, which can differ from libm's in the last bit). Built with
-ffp-contract=off so no product-sum is fused (numpy's loops round every product).

The other kernels (cyclic correlations) replace a (54, n) gather and a BLAS product whose
summation order is BLAS's own: their values equal numpy's to ~1e-15 relative, and only the
index of the best shift and threshold decisions are taken from them.
"""

from libc.math cimport hypot, fmod, floor, copysign, fabs
from libc.stdlib cimport malloc, free

import numpy as np

_arctan2 = np.arctan2

ctypedef fused real_x:
    float
    double

ctypedef fused real_w:
    float
    double

cdef enum:
    PACKET_LEN = 54
    PW_BLOCKSIZE = 128


cdef double _pw_sum(const double *a, Py_ssize_t n) noexcept nogil:
    """numpy's DOUBLE_pairwise_sum (contiguous)."""
    cdef double res, r0, r1, r2, r3, r4, r5, r6, r7
    cdef Py_ssize_t i, n2
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[i]
        return res
    elif n <= PW_BLOCKSIZE:
        r0 = a[0]; r1 = a[1]; r2 = a[2]; r3 = a[3]
        r4 = a[4]; r5 = a[5]; r6 = a[6]; r7 = a[7]
        i = 8
        while i < n - (n % 8):
            r0 += a[i]; r1 += a[i + 1]; r2 += a[i + 2]; r3 += a[i + 3]
            r4 += a[i + 4]; r5 += a[i + 5]; r6 += a[i + 6]; r7 += a[i + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pw_sum(a, n2) + _pw_sum(a + n2, n - n2)


cdef void _pw_csum(const double *a, Py_ssize_t n, double *rr, double *ri) noexcept nogil:
    """numpy's CDOUBLE_pairwise_sum over n scalars (n / 2 complex numbers, interleaved)."""
    cdef double r0, r1, r2, r3, r4, r5, r6, r7, rr1, ri1, rr2, ri2
    cdef Py_ssize_t i, n2
    if n < 8:
        rr[0] = -0.0
        ri[0] = -0.0
        i = 0
        while i < n:
            rr[0] += a[i]
            ri[0] += a[i + 1]
            i += 2
        return
    elif n <= PW_BLOCKSIZE:
        r0 = a[0]; r1 = a[1]; r2 = a[2]; r3 = a[3]
        r4 = a[4]; r5 = a[5]; r6 = a[6]; r7 = a[7]
        i = 8
        while i < n - (n % 8):
            r0 += a[i]; r1 += a[i + 1]; r2 += a[i + 2]; r3 += a[i + 3]
            r4 += a[i + 4]; r5 += a[i + 5]; r6 += a[i + 6]; r7 += a[i + 7]
            i += 8
        rr[0] = (r0 + r2) + (r4 + r6)
        ri[0] = (r1 + r3) + (r5 + r7)
        while i < n:
            rr[0] += a[i]
            ri[0] += a[i + 1]
            i += 2
        return
    n2 = n // 2
    n2 -= n2 % 8
    _pw_csum(a, n2, &rr1, &ri1)
    _pw_csum(a + n2, n - n2, &rr2, &ri2)
    rr[0] = rr1 + rr2
    ri[0] = ri1 + ri2


cdef inline double _pymod(double a, double b) noexcept nogil:
    """Python's (and numpy's) float remainder: the sign of b."""
    cdef double mod = fmod(a, b)
    if mod != 0.0:
        if (b < 0) != (mod < 0):
            mod += b
    else:
        mod = copysign(0.0, b)
    return mod


cdef inline double _pyfloordiv(double a, double b) noexcept nogil:
    """Python's float floor division a // b (CPython's float_floor_div)."""
    cdef double mod = fmod(a, b)
    cdef double div = (a - mod) / b
    cdef double fd
    if mod != 0.0:
        if (b < 0) != (mod < 0):
            div -= 1.0
    if div != 0.0:
        fd = floor(div)
        if div - fd > 0.5:
            fd += 1.0
    else:
        fd = copysign(0.0, a / b)
    return fd


cdef inline double _interp_grid(const double *y, Py_ssize_t n, double xv) noexcept nogil:
    """np.interp(xv, arange(n), y) (n >= 2)."""
    cdef Py_ssize_t j
    cdef double slope, r
    if xv != xv:
        return xv
    if xv < 0.0:
        return y[0]
    if xv >= <double>(n - 1):
        return y[n - 1]
    j = <Py_ssize_t>xv
    if <double>j == xv:
        return y[j]
    slope = y[j + 1] - y[j]
    r = slope * (xv - <double>j) + y[j]
    if r != r:
        r = slope * (xv - <double>(j + 1)) + y[j + 1]
        if r != r and y[j] == y[j + 1]:
            r = y[j]
    return r


def trim(const real_w[::1] w, double min_frac):
    """`trim_rows(w, w.size, min_frac)`: (start, stop)."""
    cdef Py_ssize_t n = w.shape[0], i, first = -1, last = -1
    cdef real_w mx, thr
    if n == 0:
        return 0, 0
    mx = w[0]
    for i in range(1, n):
        if w[i] > mx or w[i] != w[i]:
            mx = w[i]
    thr = <real_w>min_frac * mx
    for i in range(n):
        if w[i] >= thr:
            if first < 0:
                first = i
            last = i
    if first < 0:
        return 0, 0
    return first, last + 1


def frame_chips(const real_x[::1] profile, const real_w[::1] weights, Py_ssize_t a, Py_ssize_t b,
                const double complex[::1] phasor, double period, double exposure_rows,
                Py_ssize_t norm_chips, double min_coherence):
    """Chip grid at the fixed `period` (phasor: exp(-2j pi (r + 0.5) / period), at least
    b - a - 1 long) and soft chips of profile[a:b] (weights[a:b], or None).

    Returns (phase, coherence, soft, cw): soft / cw are None when the coherence is below
    `min_coherence` (then nothing else is computed), empty when no whole chip fits.
    """
    cdef Py_ssize_t m = b - a, i, k, n, win, half, lo
    cdef double *x = NULL
    cdef double *z = NULL
    cdef double *cs = NULL
    cdef double *v = NULL
    cdef double *wv = NULL
    cdef double d, e, etot, zr, zi, coh, phase, c0, h, cmx, scale, inv_win, c, mean, mad, s
    cdef double[::1] soft_v, cw_v
    if m < 2 or phasor.shape[0] < m - 1:
        raise ValueError("profile too short for the chip grid")
    x = <double *>malloc(m * sizeof(double))
    z = <double *>malloc(2 * (m - 1) * sizeof(double))
    if x == NULL or z == NULL:
        free(x); free(z)
        raise MemoryError()
    try:
        for i in range(m):
            x[i] = profile[a + i]
        # chip_grid, learned period: e = diff(x)^2, z = e * phasor, sums pairwise
        for i in range(m - 1):
            d = x[i + 1] - x[i]
            e = d * d
            z[2 * i] = e * phasor[i].real - 0.0 * phasor[i].imag
            z[2 * i + 1] = e * phasor[i].imag + 0.0 * phasor[i].real
        _pw_csum(z, 2 * (m - 1), &zr, &zi)
        zr = 0.0 + zr
        zi = 0.0 + zi
        # etot: the pairwise sum of e, recomputed into z's first half (z no longer needed)
        for i in range(m - 1):
            d = x[i + 1] - x[i]
            z[i] = d * d
        etot = 0.0 + _pw_sum(z, m - 1)
        coh = hypot(zr, zi) / etot if etot > 0 else 0.0
        # numpy's arctan2 (SIMD on some CPUs, not always libm's last bit), as the pure path
        phase = _pymod(-<double>_arctan2(zi, zr) * period / 6.283185307179586, period)
        if coh < min_coherence:
            return phase, coh, None, None
        # soft_chips
        n = <Py_ssize_t>_pyfloordiv(<double>(m - 1) - phase, period)
        if n <= 0:
            return phase, coh, np.zeros(0), np.zeros(0)
        soft = np.empty(n)
        cw = np.empty(n)
        soft_v = soft
        cw_v = cw
        c0 = phase + 0.5 * period
        h = period - exposure_rows
        h = 0.25 * (h if h > 0.0 else 0.0)
        v = <double *>malloc(n * sizeof(double))
        cs = <double *>malloc((n + 1) * sizeof(double))
        if v == NULL or cs == NULL:
            raise MemoryError()
        for k in range(n):
            c = <double>k * period + c0
            v[k] = ((_interp_grid(x, m, c - h) + _interp_grid(x, m, c)) + _interp_grid(x, m, c + h)) * (1.0 / 3.0)
        if weights is None:
            for k in range(n):
                cw_v[k] = 1.0
        else:
            wv = x  # x no longer needed: the weights as doubles
            for i in range(m):
                wv[i] = weights[a + i]
            cmx = 0.0
            for k in range(n):
                cw_v[k] = _interp_grid(wv, m, <double>k * period + c0)
                if k == 0 or cw_v[k] > cmx or cw_v[k] != cw_v[k]:
                    cmx = cw_v[k]
            scale = 1.0 / (cmx if not (1e-9 > cmx) else 1e-9)
            for k in range(n):
                cw_v[k] = cw_v[k] * scale
        win = norm_chips if norm_chips < n else n
        half = win // 2
        inv_win = 1.0 / <double>win
        cs[0] = 0.0
        cs[1] = v[0]
        for k in range(1, n):
            cs[k + 1] = cs[k] + v[k]
        for k in range(n):
            lo = k - half
            if lo < 0:
                lo = 0
            if lo > n - win:
                lo = n - win
            soft_v[k] = v[k] - (cs[lo + win] - cs[lo]) * inv_win
        cs[1] = fabs(soft_v[0])
        for k in range(1, n):
            cs[k + 1] = cs[k] + fabs(soft_v[k])
        for k in range(n):
            lo = k - half
            if lo < 0:
                lo = 0
            if lo > n - win:
                lo = n - win
            mad = (cs[lo + win] - cs[lo]) * inv_win
            if not (mad >= 1e-9) and mad == mad:
                mad = 1e-9
            s = soft_v[k] / mad
            if s > 2.0:
                s = 2.0
            if s < -2.0:
                s = -2.0
            soft_v[k] = s
        return phase, coh, soft, cw
    finally:
        free(x)
        free(z)
        free(v)
        free(cs)
