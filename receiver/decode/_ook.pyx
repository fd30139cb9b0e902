# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled kernels of receiver.decode.ook, the decoder's one implementation of these steps (they save
over 5 % of a frame: docs/kernels.md); tests/engine/test_decode_native.py checks them.

`frame_chips`: trim rows + chip grid at a learned period + soft chips of one row profile, the
numbers of `trim_rows`, `chip_grid(..., segment_chips=0)` and `soft_chips` bit for bit: sums
follow numpy's pairwise summation (`_pw_sum`, `_pw_csum` from receiver/decode/_npsum.pxd: numpy's DOUBLE / CDOUBLE
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
from receiver.core._npsum cimport pw_sum as _pw_sum, pw_csum as _pw_csum

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
        c = _pyfloordiv(<double>(m - 1) - phase, period)
        if not (-1e15 < c < 1e15):  # NaN in the profile: the pure path's int() raises too
            raise ValueError("cannot convert float NaN to integer")
        n = <Py_ssize_t>c
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


# ---------------------------------------------------------------- packet accumulator

cdef double[6] _SYNC_T = [1.0, 1.0, 1.0, -1.0, -1.0, -1.0]


cdef inline Py_ssize_t _best_shift(const double* corr, double* bv, double* second) noexcept nogil:
    """The shift of the largest of corr[0:54] (the first on ties), that value in bv and the
    largest of the other shifts in second (the alignment's and the template match's margin)."""
    cdef Py_ssize_t sh, best = 0
    for sh in range(1, PACKET_LEN):
        if corr[sh] > corr[best]:
            best = sh
    bv[0] = corr[best]
    second[0] = -1e308
    for sh in range(PACKET_LEN):
        if sh != best and corr[sh] > second[0]:
            second[0] = corr[sh]
    return best


cdef inline double _clip1(double v) noexcept nogil:
    """np.minimum(np.maximum(v, -1.0), 1.0) (NaN stays NaN)."""
    if v < -1.0:
        v = -1.0
    if v > 1.0:
        v = 1.0
    return v


def find_sync(const double[::1] soft, double margin):
    """`ook.find_sync`: (index or None, margin of the weakest sync chip)."""
    cdef Py_ssize_t n = soft.shape[0], k, j, first = -1, best = -1
    cdef double sc, bsc = 0.0, v
    cdef bint ok
    if n < 6:
        return None, 0.0
    for k in range(n - 5):
        ok = True
        for j in range(6):
            v = soft[k + j]
            # the chip's sign code of the pure path: (v > margin) - (v < -margin)
            if ((v > margin) - (v < -margin)) != (1 if j < 3 else -1):
                ok = False
                break
        if not ok:
            continue
        if first < 0:
            first = k
        elif (k - first) % PACKET_LEN:
            return None, 0.0  # inconsistent syncs
        sc = soft[k] * _SYNC_T[0]
        for j in range(1, 6):
            v = soft[k + j] * _SYNC_T[j]
            if v < sc:
                sc = v
        if best < 0 or sc > bsc:
            best, bsc = k, sc
    if best < 0:
        return None, 0.0
    return best, bsc


def decay4(double[:, ::1] acc4, double f):
    """`OokDecoder.step`'s decay: every accumulator (acc, acc_w, trust_w, timed_w, the rows of
    one (4, 54) array) times f."""
    cdef Py_ssize_t r, i
    for r in range(acc4.shape[0]):
        for i in range(acc4.shape[1]):
            acc4[r, i] = acc4[r, i] * f


def add4(double[:, ::1] acc4, Py_ssize_t extra, const double[::1] soft, const double[::1] cw,
         Py_ssize_t shift):
    """`OokDecoder._add`: frame chip k at packet position (k + shift) % 54, weighted sums formed
    per position first (np.bincount's order), then added to the rows of acc4 (acc, acc_w,
    trust_w, timed_w); `extra` 2 or 3 names the row that gets the weights too, -1 none."""
    cdef double tv[PACKET_LEN]
    cdef double tw[PACKET_LEN]
    cdef Py_ssize_t i, p
    if acc4.shape[0] != 4 or acc4.shape[1] != PACKET_LEN or cw.shape[0] < soft.shape[0]:
        raise ValueError("add4: a (4, 54) accumulator and one weight per chip")
    for i in range(PACKET_LEN):
        tv[i] = 0.0
        tw[i] = 0.0
    shift = shift % PACKET_LEN
    if shift < 0:
        shift += PACKET_LEN
    for i in range(soft.shape[0]):
        p = (i + shift) % PACKET_LEN
        tv[p] += cw[i] * soft[i]
        tw[p] += cw[i]
    for i in range(PACKET_LEN):
        acc4[0, i] = acc4[0, i] + tv[i]
        acc4[1, i] = acc4[1, i] + tw[i]
    if extra == 2 or extra == 3:
        for i in range(PACKET_LEN):
            acc4[extra, i] = acc4[extra, i] + tw[i]


def any_nonzero(const double[::1] acc_w):
    """bool(acc_w.any()) (NaN counts, as numpy's)."""
    cdef Py_ssize_t i
    for i in range(acc_w.shape[0]):
        if acc_w[i] != 0.0:
            return True
    return False


def known_count(const double[::1] acc_w):
    """np.count_nonzero(acc_w > 0)."""
    cdef Py_ssize_t i, n = 0
    for i in range(acc_w.shape[0]):
        if acc_w[i] > 0:
            n += 1
    return n


def decode_acc(const double[::1] acc, const double[::1] acc_w, double min_margin,
               const unsigned char[::1] crc_table):
    """`OokDecoder._decode`'s packet: None when a data chip is unknown, else (id or None,
    confidence) of the mean packet m (0 where unknown). Bit i comes from the Manchester pair
    (m[6+2i], m[7+2i]) as sign(a - b), its reliability |a - b| / 2; the ID is accepted only when
    every pair and every sync chip is right by `min_margin` and the CRC-8 matches."""
    cdef double m[PACKET_LEN]
    cdef double r, conf = 0.0, sync = 0.0, v
    cdef Py_ssize_t i
    cdef long value = 0
    for i in range(6, PACKET_LEN):
        if not (acc_w[i] > 0):
            return None
    for i in range(PACKET_LEN):
        m[i] = acc[i] / acc_w[i] if acc_w[i] > 0 else 0.0
    for i in range(24):
        r = 0.5 * (m[6 + 2 * i] - m[7 + 2 * i])
        v = fabs(r)
        if i == 0 or v < conf or v != v:
            if not (conf != conf):
                conf = v
        value = (value << 1) | (1 if r > 0 else 0)
    for i in range(6):
        v = m[i] * _SYNC_T[i]
        if i == 0 or v < sync or v != v:
            if not (sync != sync):
                sync = v
    if conf < min_margin or not (sync >= min_margin):
        return None, conf
    if crc_table[value >> 8] != (value & 0xFF):
        return None, conf
    return <long>(value >> 8), conf


cdef int _parity(const double *x, Py_ssize_t n, bint cyclic, double gap) noexcept nogil:
    """Which chips of already clipped chips x start Manchester pairs: 0 (even indices), 1 (odd)
    or -1 (unclear). Inside Manchester data a pair's two chips are opposite, while chips across a
    pair boundary are equal whenever two successive bits are, so the right grid scores about +1
    per pair and the wrong one about 0; a score gap of `gap` pairs is needed (alternating bits
    are Manchester-consistent on both grids and stay unclear)."""
    cdef Py_ssize_t np_ = n if cyclic else n - 1, i, n0 = 0, n1 = 0
    cdef double *p0
    cdef double *p1
    cdef double s0, s1
    p0 = <double *>malloc((np_ + 2) * sizeof(double))
    p1 = <double *>malloc((np_ + 2) * sizeof(double))
    if p0 == NULL or p1 == NULL:
        free(p0); free(p1)
        return -2
    for i in range(np_):
        if i % 2 == 0:
            p0[n0] = x[i] * x[(i + 1) % n]
            n0 += 1
        else:
            p1[n1] = x[i] * x[(i + 1) % n]
            n1 += 1
    s0 = -(0.0 + _pw_sum(p0, n0))
    s1 = -(0.0 + _pw_sum(p1, n1))
    free(p0); free(p1)
    if fabs(s0 - s1) < gap:
        return -1
    return 0 if s0 > s1 else 1


def align(const double[::1] acc, const double[::1] acc_w, const double[::1] soft, bint anchored,
          Py_ssize_t min_chips, double parity_gap, double align_min, double align_gap):
    """`OokDecoder._align`: (shift or None, complete). The correlations are summed in chip
    order (numpy's BLAS product may sum in another): equal to ~1e-15, decisions the same."""
    cdef Py_ssize_t n = soft.shape[0], i, k, sh, p, nk = 0, ov, ovmin = PACKET_LEN + n, best = 0
    cdef double m[PACKET_LEN]
    cdef double am[PACKET_LEN]
    cdef double corr[PACKET_LEN]
    cdef double corr_m[PACKET_LEN]
    cdef bint known[PACKET_LEN]
    cdef double num, den, bv, second
    cdef double *s = NULL
    cdef int pf, pa
    for i in range(PACKET_LEN):
        known[i] = acc_w[i] > 0
        nk += known[i]
    if nk < min_chips:
        return None, False
    if n == 0:
        return None, False
    for i in range(PACKET_LEN):
        m[i] = acc[i] / acc_w[i] if known[i] else 0.0
        am[i] = fabs(m[i])
    s = <double *>malloc(n * sizeof(double))
    if s == NULL:
        raise MemoryError()
    try:
        for k in range(n):
            s[k] = _clip1(soft[k])
        for sh in range(PACKET_LEN):
            num = 0.0
            den = 0.0
            ov = 0
            p = sh
            for k in range(n):
                num += m[p] * s[k]
                den += am[p] * fabs(s[k])
                ov += known[p]
                p += 1
                if p == PACKET_LEN:
                    p = 0
            if ov < ovmin:
                ovmin = ov
            corr[sh] = num / (den if den > 1e-12 else 1e-12) if (den > 0 and ov >= min_chips) else -1.0
        pf = _parity(s, n, False, parity_gap)
        if pf == -2:
            raise MemoryError()
        if pf >= 0:
            if anchored:
                pa = 0
            else:
                for i in range(PACKET_LEN):
                    corr_m[i] = _clip1(m[i])
                pa = _parity(corr_m, PACKET_LEN, True, parity_gap)
            if pa == -2:
                raise MemoryError()
            if pa >= 0:
                sh = (pa - pf + 1) % 2
                while sh < PACKET_LEN:
                    corr[sh] = -1.0
                    sh += 2
        best = _best_shift(corr, &bv, &second)
        complete = ovmin >= min_chips
        if bv >= align_min and bv - second >= align_gap:
            return best, complete
        return None, complete
    finally:
        free(s)


def best_two(const double[::1] tpl, const double[::1] soft):
    """Normalised cyclic correlation sum(t[(s + k) % 54] * clip(soft[k])) / sum(|clip(soft)|) of
    a +-1 packet template over the 54 shifts s: (best shift, best, runner-up), or None when the
    chips are all 0. (`row0_coordinate`, `best_cyclic_match`; chip-order sums.)"""
    cdef Py_ssize_t n = soft.shape[0], k, sh, p, best = 0
    cdef double den = 0.0, num, bv, second, c
    cdef double corr[PACKET_LEN]
    cdef double *s = <double *>malloc((n + 1) * sizeof(double))
    if s == NULL:
        raise MemoryError()
    try:
        for k in range(n):
            s[k] = _clip1(soft[k])
            den += fabs(s[k])
        if not (den > 0):
            return None
        for sh in range(PACKET_LEN):
            num = 0.0
            p = sh
            for k in range(n):
                num += tpl[p] * s[k]
                p += 1
                if p == PACKET_LEN:
                    p = 0
            corr[sh] = num / den
        best = _best_shift(corr, &bv, &second)
        return best, bv, second
    finally:
        free(s)


def corr_at(const double[::1] tpl, const double[::1] soft, Py_ssize_t shift):
    """sum(t[(k + shift) % 54] * clip(soft[k])) / sum(|clip(soft)|), or None when that is 0."""
    cdef Py_ssize_t n = soft.shape[0], k, p
    cdef double den = 0.0, num = 0.0, v
    shift = shift % PACKET_LEN
    if shift < 0:
        shift += PACKET_LEN
    p = shift
    for k in range(n):
        v = _clip1(soft[k])
        den += fabs(v)
        num += tpl[p] * v
        p += 1
        if p == PACKET_LEN:
            p = 0
    if not (den > 0):
        return None
    return num / den


def overlap_corr(const double[::1] acc, const double[::1] acc_w, const double[::1] trust_w,
                 const double[::1] timed_w, const double[::1] soft, Py_ssize_t shift):
    """`_timed_shift`'s check: (overlapping surely placed chips, their normalised correlation
    m.x / |m|.|x| or None when that denominator is 0)."""
    cdef Py_ssize_t n = soft.shape[0], k, p, cnt = 0
    cdef double num = 0.0, den = 0.0, m, x
    shift = shift % PACKET_LEN
    if shift < 0:
        shift += PACKET_LEN
    p = shift
    for k in range(n):
        if trust_w[p] + timed_w[p] > 0.5 * acc_w[p]:
            cnt += 1
            m = acc[p] / acc_w[p]
            x = _clip1(soft[k])
            num += m * x
            den += fabs(m) * fabs(x)
        p += 1
        if p == PACKET_LEN:
            p = 0
    return cnt, (num / den if den > 0 else None)


def line_predict(obs, double k, Py_ssize_t window):
    """`ook.line_predict` (numpy's pairwise sums for the means and moments, so the same
    numbers) of a sequence of (k_i, v_i)."""
    cdef Py_ssize_t n_all = len(obs), n, i, j
    cdef double ks[64]
    cdef double vs[64]
    cdef double t1[64]
    cdef double t2[64]
    cdef double km, vm, slope
    n = window if window < n_all else n_all
    if n <= 0:
        raise IndexError("no observations")
    if n > 64:
        return None  # caller falls back to the pure function
    j = 0
    for i in range(n_all - n, n_all):
        pt = obs[i]
        ks[j] = <double>pt[0]
        vs[j] = <double>pt[1]
        j += 1
    if n == 1 or ks[n - 1] - ks[0] < 2:
        return obs[n_all - 1][1]
    km = (0.0 + _pw_sum(ks, n)) / <double>n
    vm = (0.0 + _pw_sum(vs, n)) / <double>n
    for i in range(n):
        t1[i] = ks[i] - km
        t2[i] = t1[i] * (vs[i] - vm)
        t1[i] = t1[i] * t1[i]
    slope = (0.0 + _pw_sum(t2, n)) / (0.0 + _pw_sum(t1, n))
    return vm + slope * (k - km)
