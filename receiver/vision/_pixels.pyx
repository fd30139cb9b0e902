# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled pixel loops of the image side (receiver.core.native): per-row scans of the blobs'
boxes that the pure numpy paths do as strips of whole-array operations.

Every function here has a pure numpy reference in receiver/vision (named in its doc) and must
give the same numbers bit for bit: the float arithmetic is written in the same precision and
order as numpy evaluates it there (float32 where the reference computes in float32).

The byte scans (row maximum, first / last pixel at or above a level) use SSE2 where the compiler
targets it (every x86-64), 16 pixels per step, and plain loops elsewhere.
"""

from receiver.core._buf cimport fresh_data
from libc.math cimport ceilf, sqrt, floor, isfinite, isnan, NAN, hypot
from libc.stdlib cimport malloc, free, realloc
from libc.string cimport memset, memcpy
from libc.stdint cimport int64_t, int32_t, uint32_t, uint64_t

cdef extern from *:
    """
    #include <stdint.h>
    #if defined(__SSE2__) && defined(__GNUC__)
    #include <emmintrin.h>
    #define OCC_SSE2 1
    #endif
    /* AVX2 versions of the frame-sized byte loops, compiled for that target only and chosen at
       run time (occ_use_avx2) on x86-64 with GCC or clang; integer-exact: the same bytes. */
    #if defined(__x86_64__) && defined(__GNUC__)
    #include <immintrin.h>
    #define OCC_AVX2 1
    static int occ_avx2_state = -1;  /* -1: not asked yet, 0: off (absent or turned off), 1: on */
    static inline int occ_use_avx2(void) {
        if (occ_avx2_state < 0) {
            __builtin_cpu_init();
            occ_avx2_state = __builtin_cpu_supports("avx2") ? 1 : 0;
        }
        return occ_avx2_state;
    }
    static int occ_set_avx2(int on) {
        occ_avx2_state = -1;
        if (on) return occ_use_avx2();
        occ_avx2_state = 0;
        return 0;
    }
    #else
    static inline int occ_use_avx2(void) { return 0; }
    static int occ_set_avx2(int on) { (void)on; return 0; }
    #endif

    /* the lowest and the highest set bit of x != 0 */
    static inline int occ_low_bit(uint32_t x) {
    #ifdef __GNUC__
        return __builtin_ctz(x);
    #else
        int j = 0;
        while (!((x >> j) & 1u)) j++;
        return j;
    #endif
    }
    static inline int occ_high_bit(uint32_t x) {
    #ifdef __GNUC__
        return 31 - __builtin_clz(x);
    #else
        int j = 31;
        while (!((x >> j) & 1u)) j--;
        return j;
    #endif
    }

    /* largest value of p[0..n) (0 for n <= 0) */
    static inline unsigned char occ_u8_max(const unsigned char *p, Py_ssize_t n) {
        Py_ssize_t i = 0;
        unsigned char m = 0;
    #ifdef OCC_SSE2
        if (n >= 16) {
            __m128i acc = _mm_setzero_si128();
            for (; i + 16 <= n; i += 16)
                acc = _mm_max_epu8(acc, _mm_loadu_si128((const __m128i *)(p + i)));
            /* the last (overlapping) 16 bytes: no scalar tail */
            acc = _mm_max_epu8(acc, _mm_loadu_si128((const __m128i *)(p + n - 16)));
            i = n;
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 8));
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 4));
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 2));
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 1));
            m = (unsigned char)(_mm_cvtsi128_si32(acc) & 0xff);
        }
    #endif
        for (; i < n; i++)
            if (p[i] > m) m = p[i];
        return m;
    }

    /* largest value of the (rows, n) box p (rows `stride` bytes apart; 0 when empty): one vector
       maximum over all its rows, reduced once */
    static inline unsigned char occ_u8_max_box(const unsigned char *p, Py_ssize_t stride, Py_ssize_t rows,
                                               Py_ssize_t n) {
        unsigned char m = 0;
        Py_ssize_t r, i;
    #ifdef OCC_SSE2
        if (n >= 16) {
            __m128i acc = _mm_setzero_si128();
            for (r = 0; r < rows; r++) {
                const unsigned char *q = p + r * stride;
                for (i = 0; i + 16 <= n; i += 16)
                    acc = _mm_max_epu8(acc, _mm_loadu_si128((const __m128i *)(q + i)));
                acc = _mm_max_epu8(acc, _mm_loadu_si128((const __m128i *)(q + n - 16)));
            }
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 8));
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 4));
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 2));
            acc = _mm_max_epu8(acc, _mm_srli_si128(acc, 1));
            return (unsigned char)(_mm_cvtsi128_si32(acc) & 0xff);
        }
    #endif
        for (r = 0; r < rows; r++) {
            unsigned char v = occ_u8_max(p + r * stride, n);
            if (v > m) m = v;
        }
        return m;
    }
    #ifdef OCC_AVX2
    __attribute__((target("avx2")))
    static unsigned char occ_u8_max_box_avx2(const unsigned char *p, Py_ssize_t stride, Py_ssize_t rows,
                                             Py_ssize_t n) {
        if (n < 32)
            return occ_u8_max_box(p, stride, rows, n);
        __m256i acc = _mm256_setzero_si256();
        for (Py_ssize_t r = 0; r < rows; r++) {
            const unsigned char *q = p + r * stride;
            Py_ssize_t i;
            for (i = 0; i + 32 <= n; i += 32)
                acc = _mm256_max_epu8(acc, _mm256_loadu_si256((const __m256i *)(q + i)));
            acc = _mm256_max_epu8(acc, _mm256_loadu_si256((const __m256i *)(q + n - 32)));
        }
        __m128i a = _mm_max_epu8(_mm256_castsi256_si128(acc), _mm256_extracti128_si256(acc, 1));
        a = _mm_max_epu8(a, _mm_srli_si128(a, 8));
        a = _mm_max_epu8(a, _mm_srli_si128(a, 4));
        a = _mm_max_epu8(a, _mm_srli_si128(a, 2));
        a = _mm_max_epu8(a, _mm_srli_si128(a, 1));
        return (unsigned char)(_mm_cvtsi128_si32(a) & 0xff);
    }
    #endif
    static inline unsigned char occ_u8_max_box_any(const unsigned char *p, Py_ssize_t stride, Py_ssize_t rows,
                                                   Py_ssize_t n) {
    #ifdef OCC_AVX2
        if (occ_use_avx2()) return occ_u8_max_box_avx2(p, stride, rows, n);
    #endif
        return occ_u8_max_box(p, stride, rows, n);
    }

    /* first i in [0, n) with p[i] >= t, or -1 */
    static inline Py_ssize_t occ_u8_first_ge(const unsigned char *p, Py_ssize_t n, unsigned char t) {
        Py_ssize_t i = 0;
    #ifdef OCC_SSE2
        const __m128i tv = _mm_set1_epi8((char)t);
        for (; i + 16 <= n; i += 16) {
            __m128i x = _mm_loadu_si128((const __m128i *)(p + i));
            int m = _mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(x, tv), x));
            if (m) return i + __builtin_ctz((unsigned)m);
        }
        if (i < n && n >= 16) {  /* the last 16 bytes, overlapping the ones seen */
            __m128i x = _mm_loadu_si128((const __m128i *)(p + n - 16));
            int m = _mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(x, tv), x));
            return m ? n - 16 + __builtin_ctz((unsigned)m) : -1;
        }
    #endif
        for (; i < n; i++)
            if (p[i] >= t) return i;
        return -1;
    }

    /* last i in [0, n) with p[i] >= t, or -1 */
    static inline Py_ssize_t occ_u8_last_ge(const unsigned char *p, Py_ssize_t n, unsigned char t) {
        Py_ssize_t i = n;
    #ifdef OCC_SSE2
        const __m128i tv = _mm_set1_epi8((char)t);
        for (; i >= 16; i -= 16) {
            __m128i x = _mm_loadu_si128((const __m128i *)(p + i - 16));
            int m = _mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(x, tv), x));
            if (m) return i - 16 + 31 - __builtin_clz((unsigned)m);
        }
        if (i > 0 && n >= 16) {  /* the first 16 bytes, overlapping the ones seen */
            __m128i x = _mm_loadu_si128((const __m128i *)p);
            int m = _mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(x, tv), x));
            return m ? 31 - __builtin_clz((unsigned)m) : -1;
        }
    #endif
        for (; i > 0; i--)
            if (p[i - 1] >= t) return i - 1;
        return -1;
    }
    """
    unsigned char occ_u8_max(const unsigned char *p, Py_ssize_t n) nogil
    Py_ssize_t occ_u8_first_ge(const unsigned char *p, Py_ssize_t n, unsigned char t) nogil
    Py_ssize_t occ_u8_last_ge(const unsigned char *p, Py_ssize_t n, unsigned char t) nogil
    unsigned char occ_u8_max_box_any(const unsigned char *p, Py_ssize_t stride, Py_ssize_t rows, Py_ssize_t n) nogil
    int occ_use_avx2() nogil
    int occ_low_bit(uint32_t x) nogil
    int occ_high_bit(uint32_t x) nogil
    int occ_set_avx2(int on) nogil


def avx2(on=None):
    """Whether the AVX2 versions of the byte loops run (this CPU has AVX2; x86-64 builds
    only). `on` False turns them off (the SSE2 / plain loops then run), True back on where the
    CPU has them: for the tests, which compare both."""
    if on is not None:
        occ_set_avx2(1 if on else 0)
    return bool(occ_use_avx2())


# ------------------------------------------------------------------ scans (tests, helpers)

def u8_scan(const unsigned char[::1] row, int t):
    """(max, first index >= t, last index >= t) of a uint8 row (-1 when none): the byte scans
    the kernels below use, exposed for their tests."""
    cdef const unsigned char *p = &row[0] if row.shape[0] else NULL
    cdef Py_ssize_t n = row.shape[0]
    if n == 0:
        return 0, -1, -1
    return (int(occ_u8_max(p, n)), int(occ_u8_first_ge(p, n, <unsigned char>t)),
            int(occ_u8_last_ge(p, n, <unsigned char>t)))


# ------------------------------------------------------------------ stripe edge points

from cpython.buffer cimport (PyBUF_C_CONTIGUOUS, PyBUF_FORMAT, PyBUF_STRIDES, PyBUF_WRITABLE, PyBuffer_Release,
                             PyObject_CheckBuffer, PyObject_GetBuffer)
from libc.math cimport ceil

import numpy as np

cdef enum:
    MIN_RUN_PX = 9  # outline.MIN_RUN_PX (2 * SIDE_PX + 5, SIDE_PX = 2: the offsets of _edge_point)


cdef inline Py_ssize_t _clampi(Py_ssize_t v, Py_ssize_t hi) noexcept nogil:
    if v < 0:
        return 0
    if v > hi:
        return hi
    return v


cdef bint _edge_point_clamped(const unsigned char *p, Py_ssize_t start, int side, Py_ssize_t w1,
                              double *pos, float *contrast) noexcept nogil:
    """`_edge_point` with its samples clamped into the row [0, w1] (a run near the box's edge),
    as the reference gathers them."""
    cdef float plateau = (<float>p[_clampi(start - 2 * side, w1)] + <float>p[_clampi(start - 3 * side, w1)]) / <float>2.0
    cdef float outside = (<float>p[_clampi(start + 3 * side, w1)] + <float>p[_clampi(start + 4 * side, w1)]) / <float>2.0
    cdef float thr = <float>0.5 * (plateau + outside)
    cdef Py_ssize_t a[5]
    cdef float v[5]
    cdef int j, k = -1
    for j in range(5):
        a[j] = _clampi(start + (j - 1) * side, w1)
        v[j] = <float>p[a[j]]
    for j in range(4):
        if v[j] >= thr and v[j + 1] < thr and a[j] != a[j + 1]:
            k = j
            break
    contrast[0] = plateau - outside
    if k < 0:
        return False
    cdef float d = v[k] - v[k + 1]
    if d < <float>1e-6:
        d = <float>1e-6
    cdef float frac = (v[k] - thr) / d
    pos[0] = <double>a[k] + <double>side * <double>frac
    return True


cdef inline bint _edge_point(const unsigned char *p, Py_ssize_t start, int side, Py_ssize_t w1,
                             double *pos, float *contrast) noexcept nogil:
    """One end of a lit run (outline.stripe_edge_points_batch, per point): the sub-pixel
    crossing (box column, pos) and the plateau - outside contrast; False when no pixel pair
    straddles the half level.

    Where every sample lies inside the row (start - 4 >= 0 and start + 4 <= w1: none clamped,
    no column repeated) the level test runs on integers: the reference's float sums of u8
    values, their halves and quarters are exact, so its v >= thr is 4 v >= (the four samples'
    sum) and the plateau - outside contrast is half the sums' difference; the crossing's
    fraction is then the same float division of the same exact numbers. Elsewhere
    `_edge_point_clamped`."""
    cdef int P, O, S, k, q0, q1, q2, q3, q4, va, vb
    cdef float thr, frac
    if not (start >= 4 and start + 4 <= w1):
        return _edge_point_clamped(p, start, side, w1, pos, contrast)
    P = <int>p[start - 2 * side] + <int>p[start - 3 * side]
    O = <int>p[start + 3 * side] + <int>p[start + 4 * side]
    contrast[0] = <float>(P - O) * <float>0.5
    S = P + O
    q0 = p[start - side]
    q1 = p[start]
    q2 = p[start + side]
    q3 = p[start + 2 * side]
    q4 = p[start + 3 * side]
    if 4 * q0 >= S and 4 * q1 < S:
        k, va, vb = -1, q0, q1
    elif 4 * q1 >= S and 4 * q2 < S:
        k, va, vb = 0, q1, q2
    elif 4 * q2 >= S and 4 * q3 < S:
        k, va, vb = 1, q2, q3
    elif 4 * q3 >= S and 4 * q4 < S:
        k, va, vb = 2, q3, q4
    else:
        return False
    # va > vb here: d >= 1, never the reference's 1e-6 floor
    thr = <float>S * <float>0.25
    frac = (<float>va - thr) / <float>(va - vb)
    pos[0] = <double>(start + k * side) + <double>side * <double>frac
    return True


cdef inline double _sigma(float contrast, double sigma_num, double min_sigma) noexcept nogil:
    """A point's 1-sigma, px: sigma_num / (half the contrast, at least 1e-3), at least min_sigma."""
    cdef float hc = <float>0.5 * contrast
    cdef double s = sigma_num / <double>(hc if hc > <float>1e-3 else <float>1e-3)
    return min_sigma if s < min_sigma else s


cdef Py_ssize_t _edge_box(const unsigned char *g, Py_ssize_t stride, Py_ssize_t x0, Py_ssize_t x1,
                          Py_ssize_t y0, Py_ssize_t y1, float bgf, double lo_b, double hi_x, double hi_y,
                          float min_contrast, int bin_rows, double min_sigma, double sigma_num,
                          double *pts, double *sig, Py_ssize_t m, double *acc) noexcept nogil:
    """The points of one box (`edge_points`): columns [x0, x1), rows [y0, y1) of the frame `g`
    (`stride` bytes a row, the box inside it), background bgf; written as rows m, m + 1, ... of
    pts ((., 2) x, y) and sig, the left side's first. Returns the next free row. acc: work of
    8 * (y1 - y0 + 1) doubles. Rows outside [lo_b, hi_y] hold no point and are skipped."""
    cdef Py_ssize_t nrows = y1 - y0, wb = x1 - x0, w1 = wb - 1, r, first, last, b, nbin = 0, nr = 0
    cdef int side_i
    cdef const unsigned char *row
    cdef unsigned char rmax, on
    cdef float thr_lit, contrast
    cdef double pos, x, y, s, ox = <double>x0, xlo = <double>(x0 + 1), xhi = <double>(x1 - 2)
    cdef double *a = acc
    if bin_rows > 1:
        nbin = (nrows + bin_rows - 1) // bin_rows
        memset(acc, 0, 8 * nbin * sizeof(double))
    for r in range(nrows):
        y = <double>(r + y0)
        if not (y >= lo_b and y <= hi_y):
            continue
        row = g + (y0 + r) * stride + x0
        # the lit run: first and last pixel at or above the half level of the row's maximum
        rmax = occ_u8_max(row, wb)
        if not (<float>rmax - bgf >= min_contrast):
            continue
        thr_lit = ceilf(bgf + <float>0.5 * (<float>rmax - bgf))
        if thr_lit < 0:
            thr_lit = 0
        elif thr_lit > 255:
            thr_lit = 255
        on = <unsigned char>thr_lit
        first = occ_u8_first_ge(row, wb, on)
        if first < 0:
            continue
        last = occ_u8_last_ge(row, wb, on)
        if last - first + 1 < MIN_RUN_PX:
            continue
        if bin_rows > 1:
            a = acc + 8 * (r // bin_rows)
        for side_i in range(2):  # the left end (side -1), then the right end (+1)
            if not _edge_point(row, last if side_i else first, 2 * side_i - 1, w1, &pos, &contrast):
                continue
            if not (contrast >= min_contrast):
                continue
            x = pos + ox
            # inside the image's border and clear of the box's own border
            if not (x >= lo_b and x <= hi_x and x > xlo and x < xhi):
                continue
            s = _sigma(contrast, sigma_num, min_sigma)
            if bin_rows > 1:
                a[4 * side_i] += 1.0
                a[4 * side_i + 1] += x
                a[4 * side_i + 2] += y
                a[4 * side_i + 3] += s * s
            elif side_i == 0:
                pts[2 * m] = x
                pts[2 * m + 1] = y
                sig[m] = s
                m += 1
            else:  # the right side's points wait in acc
                acc[3 * nr] = x
                acc[3 * nr + 1] = y
                acc[3 * nr + 2] = s
                nr += 1
    if bin_rows > 1:
        for side_i in range(2):
            for b in range(nbin):
                a = acc + 8 * b + 4 * side_i
                if a[0] > 0:
                    pts[2 * m] = a[1] / a[0]
                    pts[2 * m + 1] = a[2] / a[0]
                    sig[m] = sqrt(a[3]) / a[0]
                    m += 1
    else:
        for b in range(nr):
            pts[2 * m] = acc[3 * b]
            pts[2 * m + 1] = acc[3 * b + 1]
            sig[m] = acc[3 * b + 2]
            m += 1
    return m


def edge_points(const unsigned char[:, ::1] gray, const int64_t[::1] bx0, const int64_t[::1] bx1,
                const int64_t[::1] by0, const int64_t[::1] by1, const float[::1] bg,
                int border_px, float min_contrast, int bin_rows, double min_sigma, double sigma_num,
                double[:, ::1] pts, double[::1] sig, int64_t[::1] ends):
    """`outline.stripe_edge_points_batch` after its boxes (`_boxes`): box k is columns
    [bx0, bx1) and rows [by0, by1) of `gray` with background bg[k]. Writes each box's points
    (left side, then right side; binned by `bin_rows` when > 1) into `pts` (x, y) and `sig`,
    box k's being rows ends[k]:ends[k + 1]; `pts` / `sig` need 2 * (total box rows) rows.
    `sigma_num`: NOISE_GRAY * sqrt(2); `min_sigma`: MIN_SIGMA_PX."""
    cdef Py_ssize_t h = gray.shape[0], w = gray.shape[1]
    cdef Py_ssize_t nb = bx0.shape[0]
    cdef Py_ssize_t k, m = 0, maxrows = 0, total = 0
    cdef double *acc
    if bx1.shape[0] != nb or by0.shape[0] != nb or by1.shape[0] != nb or bg.shape[0] < nb or ends.shape[0] < nb + 1:
        raise ValueError("edge_points: bx0, bx1, by0, by1 (n,), bg (n,), ends (n + 1,) needed")
    for k in range(nb):
        if not (0 <= bx0[k] <= bx1[k] <= w and 0 <= by0[k] <= by1[k] <= h):
            raise ValueError("edge_points: a box is not inside the frame")
        total += by1[k] - by0[k]
        if by1[k] - by0[k] > maxrows:
            maxrows = by1[k] - by0[k]
    if pts.shape[0] < 2 * total or pts.shape[1] != 2 or sig.shape[0] < 2 * total:
        raise ValueError("edge_points: pts (2 * total box rows, 2) and sig (2 * total box rows,) needed")
    ends[0] = 0
    if total == 0:
        for k in range(nb):
            ends[k + 1] = 0
        return 0
    acc = <double *>malloc(8 * (maxrows + 1) * sizeof(double))
    if acc == NULL:
        raise MemoryError()
    for k in range(nb):
        if by1[k] > by0[k] and bx1[k] > bx0[k]:
            m = _edge_box(&gray[0, 0], w, bx0[k], bx1[k], by0[k], by1[k], bg[k], <double>border_px,
                          <double>(w - 1 - border_px), <double>(h - 1 - border_px), min_contrast, bin_rows,
                          min_sigma, sigma_num, &pts[0, 0], &sig[0], m, acc)
        ends[k + 1] = m
    free(acc)
    return m


cdef int _hull_box(object hull, long long pad, long long w, long long h, long long *box) except -1:
    """The box `outline._boxes` gives a Blob's (K, 2) float64 hull (K >= 1; box = x0, x1, y0, y1):
    columns [floor(min x) - pad, ceil(max x) + pad + 1), rows [floor(min y) - 1, ceil(max y) + 2),
    clipped to the (h, w) frame. False (no box) when `hull` is not such an array."""
    cdef Py_buffer b
    cdef const char *p
    cdef Py_ssize_t j, s0, s1
    cdef double lox, hix, loy, hiy, vx, vy
    if not PyObject_CheckBuffer(hull):
        return False
    PyObject_GetBuffer(hull, &b, PyBUF_STRIDES | PyBUF_FORMAT)
    if (b.ndim != 2 or b.itemsize != 8 or b.format == NULL or b.format[0] != b'd' or b.format[1] != 0
            or b.shape[1] != 2 or b.shape[0] < 1):
        PyBuffer_Release(&b)
        return False
    p = <const char *>b.buf
    s0 = b.strides[0]
    s1 = b.strides[1]
    lox = hix = (<const double *>p)[0]
    loy = hiy = (<const double *>(p + s1))[0]
    for j in range(1, b.shape[0]):
        vx = (<const double *>(p + j * s0))[0]
        vy = (<const double *>(p + j * s0 + s1))[0]
        # np.minimum / np.maximum: a NaN wins
        if vx < lox or vx != vx:
            lox = vx
        if vx > hix or vx != vx:
            hix = vx
        if vy < loy or vy != vy:
            loy = vy
        if vy > hiy or vy != vy:
            hiy = vy
    PyBuffer_Release(&b)
    box[0] = <long long>floor(lox) - pad
    box[1] = <long long>ceil(hix) + pad + 1
    box[2] = <long long>floor(loy) - 1
    box[3] = <long long>ceil(hiy) + 2
    if box[0] < 0:
        box[0] = 0
    if box[2] < 0:
        box[2] = 0
    if box[1] > w:
        box[1] = w
    if box[3] > h:
        box[3] = h
    return True



def edge_points_blobs(object gray, list blobs, long long pad, int border_px, double min_contrast, int bin_rows,
                      double min_sigma, double sigma_num, long long min_width):
    """`outline.stripe_edge_points_batch` of Blobs in one call: each blob's box from its hull
    (`_hull_box`, kept when at least `min_width` wide and a row tall), its background
    (`background`, 0.0 when it has none, as float32) and the box's points (`edge_points`).
    Returns [(points (N, 2) float64, sigma (N,) float64)] per blob, views of one array each,
    (zeros((0, 2)), zeros(0)) where a blob has none; or None when this call does not apply
    (gray not a C-contiguous (H, W) uint8 array, a blob without a (K >= 1, 2) float64 hull,
    min_contrast not a float32): the caller's general path then handles it."""
    cdef Py_buffer gb
    cdef Py_ssize_t n = len(blobs), i, k, nk = 0, m = 0, maxrows = 0, total = 0, h, w
    cdef long long *box = NULL
    cdef float *bgs
    cdef Py_ssize_t *idx
    cdef Py_ssize_t *ends
    cdef double *acc = NULL
    cdef double *pp
    cdef double *sp
    cdef float mc = <float>min_contrast
    if <double>mc != min_contrast or n == 0:
        return None
    if not PyObject_CheckBuffer(gray):
        return None
    PyObject_GetBuffer(gray, &gb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
    if gb.ndim != 2 or gb.itemsize != 1 or gb.format == NULL or gb.format[0] != b'B' or gb.format[1] != 0:
        PyBuffer_Release(&gb)
        return None
    h = gb.shape[0]
    w = gb.shape[1]
    # per blob 8 slots of 8 bytes: its box (4), background (a float in one), index; then ends (n + 1)
    box = <long long *>malloc((8 * n + 2) * sizeof(long long))
    if box == NULL:
        PyBuffer_Release(&gb)
        raise MemoryError()
    bgs = <float *>(box + 4 * n)
    idx = <Py_ssize_t *>(box + 5 * n)
    ends = <Py_ssize_t *>(box + 6 * n)
    try:
        for i in range(n):
            blob = blobs[i]
            hull = getattr(blob, "hull", None)
            if hull is None or not _hull_box(hull, pad, w, h, box + 4 * nk):
                return None
            if box[4 * nk + 1] - box[4 * nk] >= min_width and box[4 * nk + 3] > box[4 * nk + 2]:
                bgs[nk] = <float><double>getattr(blob, "background", 0.0)
                idx[nk] = i
                total += box[4 * nk + 3] - box[4 * nk + 2]
                if box[4 * nk + 3] - box[4 * nk + 2] > maxrows:
                    maxrows = box[4 * nk + 3] - box[4 * nk + 2]
                nk += 1
        empty = None
        out = [None] * n
        if nk:
            pts = np.empty((2 * total, 2))
            sig = np.empty(2 * total)
            pp = fresh_data(pts)
            sp = fresh_data(sig)
            acc = <double *>malloc(8 * (maxrows + 1) * sizeof(double))
            if acc == NULL:
                raise MemoryError()
            ends[0] = 0
            for k in range(nk):
                m = _edge_box(<const unsigned char *>gb.buf, w, box[4 * k], box[4 * k + 1], box[4 * k + 2],
                              box[4 * k + 3], bgs[k], <double>border_px, <double>(w - 1 - border_px),
                              <double>(h - 1 - border_px), mc, bin_rows, min_sigma, sigma_num, pp, sp, m, acc)
                ends[k + 1] = m
            for k in range(nk):
                if ends[k + 1] > ends[k]:
                    out[idx[k]] = (pts[ends[k]:ends[k + 1]], sig[ends[k]:ends[k + 1]])
        for i in range(n):
            if out[i] is None:
                if empty is None:
                    empty = (np.zeros((0, 2)), np.zeros(0))
                out[i] = empty
        return out
    finally:
        free(acc)
        free(box)
        PyBuffer_Release(&gb)


# ------------------------------------------------------------------ detection: blob envelopes

cdef Py_ssize_t _total_rows(const int64_t[:, ::1] rects) noexcept:
    cdef Py_ssize_t i, n = 0
    for i in range(rects.shape[0]):
        n += rects[i, 3]
    return n


cdef bint _boxes_inside(const int64_t[:, ::1] rects, Py_ssize_t h, Py_ssize_t w) noexcept:
    """Every box (x, y, w, h) lies inside an (h, w) frame."""
    cdef Py_ssize_t i
    for i in range(rects.shape[0]):
        if (rects[i, 0] < 0 or rects[i, 1] < 0 or rects[i, 2] < 0 or rects[i, 3] < 0
                or rects[i, 0] + rects[i, 2] > w or rects[i, 1] + rects[i, 3] > h):
            return False
    return True


def pooled_boxes(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, int on, int pool,
                 int reach, int64_t[:, ::1] out):
    """`detect._pooled_boxes_exact` (boxes found on `pool`-row maxima -> the full-resolution
    search's): out[i] = x, first row, w, rows of the box's first to last row with a pixel >= on,
    a first row within `reach` of the top moved to 0, a last within `reach` of the bottom to the
    last row. Returns False when a box holds no such pixel (the caller's reference path then
    reports it)."""
    cdef Py_ssize_t i, n = rects.shape[0]
    if rects.shape[1] < 4 or out.shape[0] < n or out.shape[1] < 4:
        raise ValueError("pooled_boxes: rects and out (n, 4) needed")
    cdef int64_t *o = <int64_t *>malloc(max(n, 1) * 4 * sizeof(int64_t))
    if o == NULL:
        raise MemoryError()
    try:
        for i in range(n):
            o[4 * i], o[4 * i + 1], o[4 * i + 2], o[4 * i + 3] = rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3]
        if not _pooled_core(gray, o, n, 4, on, pool, reach):
            return False
        for i in range(n):
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = o[4 * i], o[4 * i + 1], o[4 * i + 2], o[4 * i + 3]
        return True
    finally:
        free(o)


cdef bint _pooled_core(const unsigned char[:, ::1] gray, int64_t *rects, Py_ssize_t n, Py_ssize_t stride, int on,
                       int pool, int reach) noexcept:
    """`pooled_boxes` in place on the boxes x, y, w, h at rects[stride * i]; False (the boxes
    then partly changed) when a box holds no pixel >= on or is not inside the frame."""
    cdef Py_ssize_t h = gray.shape[0], i, x, y, w, y1, top, bottom, r
    cdef unsigned char o = <unsigned char>on
    cdef int64_t *b
    for i in range(n):
        b = rects + stride * i
        if b[0] < 0 or b[2] < 0 or b[0] + b[2] > gray.shape[1] or b[1] < 0:
            return False
    for i in range(n):
        b = rects + stride * i
        x, w = b[0], b[2]
        y = b[1] * pool
        y1 = (b[1] + b[3]) * pool
        if y1 > h:
            y1 = h
        top = -1
        for r in range(y, y1):
            if occ_u8_first_ge(&gray[r, x], w, o) >= 0:
                top = r
                break
        if top < 0:
            return False
        bottom = top
        for r in range(y1 - 1, top, -1):
            if occ_u8_first_ge(&gray[r, x], w, o) >= 0:
                bottom = r
                break
        if top <= reach:
            top = 0
        if h - 1 - bottom <= reach:
            bottom = h - 1
        b[1] = top
        b[3] = bottom - top + 1
    return True


# ------------------------------------------------------------------ detection: the search

cdef extern from *:
    """
    #include <string.h>
    #define OCC_COUNT4(b, j) counts[b[j]]++; counts[b[j + 1]]++; counts[b[j + 2]]++; counts[b[j + 3]]++;
    #ifdef OCC_SSE2
    /* counts[v] += the samples p[0], p[4], ..., p[4 (16 k - 1)] equal to v, n = 64 k: each 64
       bytes' 16 samples packed into one register (the low byte of each 32-bit word), stored, and
       counted from the store */
    static inline void occ_count4_sse2(const unsigned char *p, Py_ssize_t n, int64_t *counts) {
        unsigned char b[16] __attribute__((aligned(16)));
        const __m128i lo = _mm_set1_epi32(0xff);
        for (Py_ssize_t c = 0; c < n; c += 64) {
            __m128i v0 = _mm_and_si128(_mm_loadu_si128((const __m128i *)(p + c)), lo);
            __m128i v1 = _mm_and_si128(_mm_loadu_si128((const __m128i *)(p + c + 16)), lo);
            __m128i v2 = _mm_and_si128(_mm_loadu_si128((const __m128i *)(p + c + 32)), lo);
            __m128i v3 = _mm_and_si128(_mm_loadu_si128((const __m128i *)(p + c + 48)), lo);
            _mm_store_si128((__m128i *)b, _mm_packus_epi16(_mm_packs_epi32(v0, v1), _mm_packs_epi32(v2, v3)));
            OCC_COUNT4(b, 0) OCC_COUNT4(b, 4) OCC_COUNT4(b, 8) OCC_COUNT4(b, 12)
        }
    }
    #endif
    #ifdef OCC_AVX2
    /* occ_count4_sse2 with n = 128 k: 32 samples per register (in another order: they are only
       counted) */
    __attribute__((target("avx2")))
    static void occ_count4_avx2(const unsigned char *p, Py_ssize_t n, int64_t *counts) {
        unsigned char b[32] __attribute__((aligned(32)));
        const __m256i lo = _mm256_set1_epi32(0xff);
        for (Py_ssize_t c = 0; c < n; c += 128) {
            __m256i v0 = _mm256_and_si256(_mm256_loadu_si256((const __m256i *)(p + c)), lo);
            __m256i v1 = _mm256_and_si256(_mm256_loadu_si256((const __m256i *)(p + c + 32)), lo);
            __m256i v2 = _mm256_and_si256(_mm256_loadu_si256((const __m256i *)(p + c + 64)), lo);
            __m256i v3 = _mm256_and_si256(_mm256_loadu_si256((const __m256i *)(p + c + 96)), lo);
            _mm256_store_si256((__m256i *)b, _mm256_packus_epi16(_mm256_packs_epi32(v0, v1),
                                                                 _mm256_packs_epi32(v2, v3)));
            OCC_COUNT4(b, 0) OCC_COUNT4(b, 4) OCC_COUNT4(b, 8) OCC_COUNT4(b, 12)
            OCC_COUNT4(b, 16) OCC_COUNT4(b, 20) OCC_COUNT4(b, 24) OCC_COUNT4(b, 28)
        }
    }
    #endif
    /* counts[v] += number of samples p[0], p[step], p[2 step], ... < p + n equal to v */
    static inline void occ_count_row(const unsigned char *p, Py_ssize_t n, Py_ssize_t step, int64_t *counts) {
        Py_ssize_t c = 0;
        if (step == 4) {
    #ifdef OCC_AVX2
            if (occ_use_avx2()) {
                c = n & ~(Py_ssize_t)127;
                occ_count4_avx2(p, c, counts);
            }
    #endif
    #ifdef OCC_SSE2
            occ_count4_sse2(p + c, (n - c) & ~(Py_ssize_t)63, counts);
            c += (n - c) & ~(Py_ssize_t)63;
    #endif
            /* two samples per 8-byte load */
            for (; c + 8 <= n; c += 8) {
                uint64_t v;
                memcpy(&v, p + c, 8);
                counts[v & 0xff]++;
                counts[(v >> 32) & 0xff]++;
            }
        }
        for (; c < n; c += step) counts[p[c]]++;
    }
    """
    void occ_count_row(const unsigned char *p, Py_ssize_t n, Py_ssize_t step, int64_t *counts) nogil


cdef void _sample_counts(const unsigned char[:, ::1] gray, int step, int64_t *counts) noexcept:
    cdef Py_ssize_t r = 0, h = gray.shape[0], w = gray.shape[1]
    memset(counts, 0, 256 * sizeof(int64_t))
    if w == 0:
        return
    while r < h:  # (a range with a run-time step would be a Python loop)
        occ_count_row(&gray[r, 0], w, step, counts)
        r += step


def sample_hist(const unsigned char[:, ::1] gray, int step, float[::1] hist):
    """hist (256,) = the histogram of gray[::step, ::step] (cv2.calcHist's counts, float32),
    without the strided copy (`detect.auto_level`)."""
    cdef int64_t counts[256]
    cdef int i
    if step < 1:
        raise ValueError("step must be positive")
    _sample_counts(gray, step, counts)
    for i in range(256):
        hist[i] = <float>counts[i]


def sample_stats(const unsigned char[:, ::1] gray, int step, float[::1] hist):
    """`sample_hist`, and (median, MAD) of those samples as `detect.auto_level` takes them from
    the histogram: the first gray value whose cumulative count reaches half the samples, and
    the same of the counts folded around it (|x - median|); exact integer counts."""
    cdef int64_t counts[256]
    cdef int64_t dev[256]
    cdef int64_t total = 0, acc = 0
    cdef int i, med = 255, mad = 255
    if step < 1:
        raise ValueError("step must be positive")
    _sample_counts(gray, step, counts)
    for i in range(256):
        hist[i] = <float>counts[i]
        total += counts[i]
        dev[i] = 0
    # searchsorted(cumsum, total / 2): the first i with 2 * cumsum[i] >= total (256 when none:
    # an empty sample, as numpy's searchsorted past the end)
    med = 256
    for i in range(256):
        acc += counts[i]
        if 2 * acc >= total:
            med = i
            break
    if med == 256:
        return 256, 256
    for i in range(256):
        dev[abs(i - med)] += counts[i]
    acc = 0
    mad = 256
    for i in range(256):
        acc += dev[i]
        if 2 * acc >= total:
            mad = i
            break
    return med, mad


cdef extern from *:
    """
    /* mask[0..n) = 255 where max(a[i], b[i]) >= on (b may equal a), else 0; returns nonzero
       when any pixel is lit. on in 0..255. cells[k] = 1 where columns [32 k, 32 k + 32) hold a
       lit pixel (left alone where they do not), and bit j of cols[k] set where column 32 k + j
       is lit (the others left alone). */
    #define OCC_MARK(i, mm) if (mm) { cells[(i) >> 5] = 1; cols[(i) >> 5] |= (mm); any = 1; }
    static inline int occ_pool_thresh_row(const unsigned char *a, const unsigned char *b, Py_ssize_t n,
                                          unsigned char on, unsigned char *mask, unsigned char *cells,
                                          uint32_t *cols) {
        Py_ssize_t i = 0;
        int any = 0;
    #ifdef OCC_SSE2
        const __m128i tv = _mm_set1_epi8((char)on);
        for (; i + 32 <= n; i += 32) {
            __m128i m0 = _mm_max_epu8(_mm_loadu_si128((const __m128i *)(a + i)),
                                      _mm_loadu_si128((const __m128i *)(b + i)));
            __m128i m1 = _mm_max_epu8(_mm_loadu_si128((const __m128i *)(a + i + 16)),
                                      _mm_loadu_si128((const __m128i *)(b + i + 16)));
            __m128i l0 = _mm_cmpeq_epi8(_mm_max_epu8(m0, tv), m0);
            __m128i l1 = _mm_cmpeq_epi8(_mm_max_epu8(m1, tv), m1);
            _mm_storeu_si128((__m128i *)(mask + i), l0);
            _mm_storeu_si128((__m128i *)(mask + i + 16), l1);
            uint32_t mm = (uint32_t)_mm_movemask_epi8(l0) | ((uint32_t)_mm_movemask_epi8(l1) << 16);
            OCC_MARK(i, mm)
        }
    #endif
        for (; i < n; i++) {
            unsigned char v = a[i] > b[i] ? a[i] : b[i];
            unsigned char l = v >= on ? 255 : 0;
            mask[i] = l;
            uint32_t mm = (uint32_t)(l & 1) << (i & 31);
            OCC_MARK(i, mm)
        }
        return any;
    }
    #ifdef OCC_AVX2
    /* occ_pool_thresh_row, 64 pixels a step */
    __attribute__((target("avx2")))
    static int occ_pool_thresh_row_avx2(const unsigned char *a, const unsigned char *b, Py_ssize_t n,
                                        unsigned char on, unsigned char *mask, unsigned char *cells,
                                        uint32_t *cols) {
        Py_ssize_t i = 0;
        int any = 0;
        const __m256i tv = _mm256_set1_epi8((char)on);
        for (; i + 64 <= n; i += 64) {
            __m256i m0 = _mm256_max_epu8(_mm256_loadu_si256((const __m256i *)(a + i)),
                                         _mm256_loadu_si256((const __m256i *)(b + i)));
            __m256i m1 = _mm256_max_epu8(_mm256_loadu_si256((const __m256i *)(a + i + 32)),
                                         _mm256_loadu_si256((const __m256i *)(b + i + 32)));
            __m256i l0 = _mm256_cmpeq_epi8(_mm256_max_epu8(m0, tv), m0);
            __m256i l1 = _mm256_cmpeq_epi8(_mm256_max_epu8(m1, tv), m1);
            _mm256_storeu_si256((__m256i *)(mask + i), l0);
            _mm256_storeu_si256((__m256i *)(mask + i + 32), l1);
            uint32_t mm0 = (uint32_t)_mm256_movemask_epi8(l0), mm1 = (uint32_t)_mm256_movemask_epi8(l1);
            if (mm0 | mm1) {
                OCC_MARK(i, mm0)
                OCC_MARK(i + 32, mm1)
            }
        }
        for (; i + 32 <= n; i += 32) {
            __m256i m0 = _mm256_max_epu8(_mm256_loadu_si256((const __m256i *)(a + i)),
                                         _mm256_loadu_si256((const __m256i *)(b + i)));
            __m256i l0 = _mm256_cmpeq_epi8(_mm256_max_epu8(m0, tv), m0);
            _mm256_storeu_si256((__m256i *)(mask + i), l0);
            uint32_t mm = (uint32_t)_mm256_movemask_epi8(l0);
            OCC_MARK(i, mm)
        }
        return any | occ_pool_thresh_row(a + i, b + i, n - i, on, mask + i, cells + (i >> 5), cols + (i >> 5));
    }
    #else
    #define occ_pool_thresh_row_avx2 occ_pool_thresh_row
    #endif
    """
    int occ_pool_thresh_row(const unsigned char *a, const unsigned char *b, Py_ssize_t n,
                            unsigned char on, unsigned char *mask, unsigned char *cells, uint32_t *cols) nogil
    int occ_pool_thresh_row_avx2(const unsigned char *a, const unsigned char *b, Py_ssize_t n,
                                 unsigned char on, unsigned char *mask, unsigned char *cells, uint32_t *cols) nogil


cdef extern from *:
    """
    /* dst[i] |= src[i], i < n */
    static inline void occ_or_bytes(unsigned char *dst, const unsigned char *src, Py_ssize_t n) {
        Py_ssize_t i = 0;
        for (; i + 8 <= n; i += 8) {
            uint64_t a, b;
            memcpy(&a, dst + i, 8);
            memcpy(&b, src + i, 8);
            a |= b;
            memcpy(dst + i, &a, 8);
        }
        for (; i < n; i++) dst[i] |= src[i];
    }
    """
    void occ_or_bytes(unsigned char *dst, const unsigned char *src, Py_ssize_t n) nogil


cdef tuple _search_mask(const unsigned char[:, ::1] gray, int pool, int on, unsigned char[:, ::1] mask,
                        unsigned char *cells, Py_ssize_t cells_stride):
    """`search_mask_cells` (cells NULL: `search_mask`): the rows' thresholds, and the lit box from
    the rows with a lit pixel and the lit columns' bits (cols: one bit a column, OR-ed over the
    rows)."""
    cdef Py_ssize_t h = gray.shape[0], w = gray.shape[1], ho = mask.shape[0], i, k
    cdef Py_ssize_t nch = (w + 31) // 32, y0 = -1, y1 = -1, x0 = -1, x1 = -1
    cdef const unsigned char *a
    cdef const unsigned char *b
    cdef unsigned char o
    cdef int avx = occ_use_avx2(), lit
    cdef uint32_t *cols
    cdef unsigned char *own = NULL
    if on > 255:
        for i in range(ho):
            memset(&mask[i, 0], 0, w)
        return 0, 0, 0, 0
    o = <unsigned char>(on if on > 0 else 0)
    cols = <uint32_t *>malloc(nch * sizeof(uint32_t) + (nch if cells == NULL else 0) + 1)
    if cols == NULL:
        raise MemoryError()
    memset(cols, 0, nch * sizeof(uint32_t))
    if cells == NULL:  # the cells go to a dummy row
        own = <unsigned char *>(cols + nch)
        cells_stride = 0
        cells = own
    try:
        for i in range(ho):
            a = &gray[i * pool, 0]
            b = &gray[i * pool + 1, 0] if pool == 2 and i * pool + 1 < h else a
            if avx:
                lit = occ_pool_thresh_row_avx2(a, b, w, o, &mask[i, 0], cells + i * cells_stride, cols)
            else:
                lit = occ_pool_thresh_row(a, b, w, o, &mask[i, 0], cells + i * cells_stride, cols)
            if lit:
                if y0 < 0:
                    y0 = i
                y1 = i
        if y0 < 0:
            return 0, 0, 0, 0
        for k in range(nch):
            if cols[k]:
                x0 = 32 * k + occ_low_bit(cols[k])
                break
        for k in range(nch - 1, -1, -1):
            if cols[k]:
                x1 = 32 * k + occ_high_bit(cols[k])
                break
        return x0, y0, x1 - x0 + 1, y1 - y0 + 1
    finally:
        free(cols)


def search_mask(const unsigned char[:, ::1] gray, int pool, int on, unsigned char[:, ::1] mask):
    """The thresholded search image and its lit pixels' bounding box in one pass
    (`detect._components`): mask (ceil(H / pool), W) = 255 where the maximum over each run of
    `pool` (1 or 2) rows of `gray` is >= on (cv2.threshold's `> level` for on = floor(level) + 1),
    else 0. Returns cv2.boundingRect(mask): (x, y, w, h), zeros when nothing is lit."""
    return _search_mask(gray, pool, on, mask, NULL, 0)


def search_mask_cells(const unsigned char[:, ::1] gray, int pool, int on, unsigned char[:, ::1] mask,
                      unsigned char[:, ::1] cells):
    """`search_mask`, and cells[i, k] = 1 where mask row i has a lit pixel in columns
    [32 k, 32 k + 32), else 0 (cells: (mask rows, >= ceil(W / 32)) uint8), for `mosaic`."""
    if cells.shape[0] < mask.shape[0] or cells.shape[1] * 32 < mask.shape[1]:
        raise ValueError("cells too small")
    memset(&cells[0, 0], 0, cells.shape[0] * cells.shape[1])
    return _search_mask(gray, pool, on, mask, &cells[0, 0], cells.shape[1])


cdef int _uf_root(int *parent, int i) noexcept nogil:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def mosaic(const unsigned char[:, ::1] mask, const unsigned char[:, ::1] cells, int bx, int by, int bw, int bh,
           int ky, int kx, int64_t[:, ::1] crops, unsigned char[::1] out, double max_fill=1.0):
    """The lit groups of `mask` (0 / 255, lit box bx, by, bw, bh; `cells` from `search_mask_cells`)
    packed side by side into one small image for the close and the contour search
    (`detect._search_mosaic`, which says why that is exact). Groups: the 8-connected sets of
    (ky rows x 32 columns) cells holding lit pixels; two groups are at least ky rows or 32 >= kx
    columns apart, farther than the (ky, kx) close reaches. Each group's crop is its lit pixels'
    box grown by ky rows and kx columns (clipped to the mask), holding only that group's pixels.
    Crops are laid out left to right, the one at the mask's left edge first and the one at its
    right edge last, top-aligned (bottom-aligned when at the mask's bottom edge only), so each
    crop keeps its mask-edge sides on the image's edges. crops[k] = x0, y0, x1, y1 (the crop in
    the mask, half-open), x, y (its place in the mosaic), in layout order. Writes the (Hm, Wm)
    mosaic into out[:Hm * Wm] and returns (groups, Hm, Wm); (-1, 0, 0) when the packing is not
    worth it or not possible (kx > 32, more groups than crops has rows, two crops at the same
    left or right edge, a mosaic no smaller than the grown box, or one larger than out), and
    early when more than `max_fill` of the lit box's (ky x 32) cells hold lit pixels (the
    mosaic could then save little of the close and would cost more than that)."""
    cdef Py_ssize_t ho = mask.shape[0], w = mask.shape[1], nch = cells.shape[1]
    cdef Py_ssize_t R0, R1, C0, C1, nR, nC, R, C, r, ra, rb, c0, ln, i, k, n = 0, f, l
    cdef Py_ssize_t cap = crops.shape[0], hm = 0, wm = 0, gx0, gy0, gx1, gy1, nleft = 0, nright = 0
    cdef int *parent
    cdef int *gid
    cdef int *oi
    cdef Py_ssize_t no = 0, jo
    cdef unsigned char *occ
    cdef int64_t *box
    cdef int64_t *cb
    cdef int ra_, rb_
    cdef Py_ssize_t x0, y0, x1, y1, px, py
    if kx > 32 or ky < 1 or kx < 1 or bw <= 0 or bh <= 0 or cells.shape[0] < ho or nch * 32 < w:
        return -1, 0, 0
    R0, R1 = by // ky, (by + bh - 1) // ky + 1
    C0, C1 = bx // 32, (bx + bw - 1) // 32 + 1
    nR, nC = R1 - R0, C1 - C0
    parent = <int *>malloc(nR * nC * sizeof(int))
    gid = <int *>malloc(nR * nC * sizeof(int))
    oi = <int *>malloc(nR * nC * sizeof(int))
    occ = <unsigned char *>malloc(nR * nC)
    box = <int64_t *>malloc(8 * (cap + 1) * sizeof(int64_t))
    if parent == NULL or gid == NULL or oi == NULL or occ == NULL or box == NULL:
        free(parent); free(gid); free(oi); free(occ); free(box)
        raise MemoryError()
    cb = box + 4 * (cap + 1)  # each group's box of cells: first and last cell column and row
    try:
        memset(occ, 0, nR * nC)
        for R in range(nR):
            ra, rb = max((R0 + R) * ky, by), min((R0 + R + 1) * ky, by + bh)
            for r in range(ra, rb):
                occ_or_bytes(occ + R * nC, &cells[r, C0], nC)
        # the occupied cells in raster order (oi[:no]): the loops below visit only these
        for i in range(nR * nC):
            if occ[i]:
                oi[no] = <int>i
                no += 1
        if no > max_fill * nR * nC:
            return -1, 0, 0
        # union-find over the 8-connected occupied cells
        for jo in range(no):
            parent[oi[jo]] = oi[jo]
        for jo in range(no):
            i = oi[jo]
            R, C = i // nC, i % nC
            if C > 0 and occ[i - 1]:
                ra_, rb_ = _uf_root(parent, <int>i), _uf_root(parent, <int>(i - 1))
                parent[max(ra_, rb_)] = min(ra_, rb_)
            if R > 0:
                for k in range(max(C - 1, 0), min(C + 2, nC)):
                    if occ[i - nC - C + k]:
                        ra_, rb_ = _uf_root(parent, <int>i), _uf_root(parent, <int>(i - nC - C + k))
                        parent[max(ra_, rb_)] = min(ra_, rb_)
        # group ids in raster order of their first cell, and each group's box of cells
        for jo in range(no):
            i = oi[jo]
            gid[i] = -1
            k = _uf_root(parent, <int>i)
            if k == i:
                if n >= cap:
                    return -1, 0, 0
                gid[i] = <int>n
                cb[4 * n], cb[4 * n + 1], cb[4 * n + 2], cb[4 * n + 3] = nC, nR, -1, -1
                n += 1
            else:
                gid[i] = gid[k]
            k = gid[i]
            R, C = i // nC, i % nC
            cb[4 * k] = min(cb[4 * k], C)
            cb[4 * k + 1] = min(cb[4 * k + 1], R)
            cb[4 * k + 2] = max(cb[4 * k + 2], C)
            cb[4 * k + 3] = max(cb[4 * k + 3], R)
        # each group's lit box: the lit pixels at its box's edges are in its edge cells
        for k in range(n):
            box[4 * k], box[4 * k + 1], box[4 * k + 2], box[4 * k + 3] = w, ho, -1, -1
        for jo in range(no):
            i = oi[jo]
            k = gid[i]
            R, C = i // nC, i % nC
            if C != cb[4 * k] and C != cb[4 * k + 2] and R != cb[4 * k + 1] and R != cb[4 * k + 3]:
                continue
            c0 = (C0 + C) * 32
            ln = min(32, w - c0)
            ra, rb = max((R0 + R) * ky, by), min((R0 + R + 1) * ky, by + bh)
            for r in range(ra, rb):
                if not cells[r, C0 + C]:
                    continue
                if C == cb[4 * k]:
                    f = occ_u8_first_ge(&mask[r, c0], ln, 255)
                    if c0 + f < box[4 * k]:
                        box[4 * k] = c0 + f
                if C == cb[4 * k + 2]:
                    l = occ_u8_last_ge(&mask[r, c0], ln, 255)
                    if c0 + l > box[4 * k + 2]:
                        box[4 * k + 2] = c0 + l
                if r < box[4 * k + 1]:
                    box[4 * k + 1] = r
                if r > box[4 * k + 3]:
                    box[4 * k + 3] = r
        # crops and their layout
        for k in range(n):
            gx0, gy0 = max(box[4 * k] - kx, 0), max(box[4 * k + 1] - ky, 0)
            gx1, gy1 = min(box[4 * k + 2] + 1 + kx, w), min(box[4 * k + 3] + 1 + ky, ho)
            box[4 * k], box[4 * k + 1], box[4 * k + 2], box[4 * k + 3] = gx0, gy0, gx1, gy1
            nleft += gx0 == 0
            nright += gx1 == w
            if gx0 == 0 and gx1 == w and n > 1:
                return -1, 0, 0
            hm = max(hm, gy1 - gy0)
            wm += gx1 - gx0
        if nleft > 1 or nright > 1:
            return -1, 0, 0
        gx0, gy0 = max(bx - kx, 0), max(by - ky, 0)
        gx1, gy1 = min(bx + bw + kx, w), min(by + bh + ky, ho)
        if hm * wm >= (gx1 - gx0) * (gy1 - gy0) or hm * wm > out.shape[0]:
            return -1, 0, 0
        # layout order: the left-edge crop, the inner ones by group id, the right-edge crop
        i = 0
        for f in range(3):
            for k in range(n):
                l = 0 if box[4 * k] == 0 else (2 if box[4 * k + 2] == w else 1)
                if l != f:
                    continue
                crops[k, 6] = i  # group k's row in crops
                crops[i, 0], crops[i, 1], crops[i, 2], crops[i, 3] = box[4 * k], box[4 * k + 1], box[4 * k + 2], box[4 * k + 3]
                i += 1
        f = 0
        for i in range(n):
            crops[i, 4] = f
            f += crops[i, 2] - crops[i, 0]
            if crops[i, 1] == 0 or crops[i, 3] != ho:
                crops[i, 5] = 0
            else:
                crops[i, 5] = hm - (crops[i, 3] - crops[i, 1])
        # the mosaic: each crop's rows of the mask, the rest zeros, then the pixels of other
        # groups' cells inside a crop cleared
        for i in range(n):
            x0, y0, x1, y1, px, py = crops[i, 0], crops[i, 1], crops[i, 2], crops[i, 3], crops[i, 4], crops[i, 5]
            for r in range(hm):
                if r < py or r >= py + y1 - y0:
                    memset(&out[r * wm + px], 0, x1 - x0)
                else:
                    memcpy(&out[r * wm + px], &mask[y0 + r - py, x0], x1 - x0)
        # crops overlapping another crop (box[4 k]: 1 for layout row k); only their groups'
        # cells can put pixels into a foreign crop (a group's lit pixels lie inside its crop)
        for k in range(n):
            box[4 * k] = 0
            for l in range(n):
                if l != k and crops[k, 0] < crops[l, 2] and crops[l, 0] < crops[k, 2] \
                        and crops[k, 1] < crops[l, 3] and crops[l, 1] < crops[k, 3]:
                    box[4 * k] = 1
                    break
        for jo in range(no):
            i = oi[jo]
            if not box[4 * crops[gid[i], 6]]:
                continue
            R, C = i // nC, i % nC
            ra, rb = max((R0 + R) * ky, by), min((R0 + R + 1) * ky, by + bh)
            c0, c1 = (C0 + C) * 32, min((C0 + C + 1) * 32, w)
            for k in range(n):
                if k == crops[gid[i], 6]:
                    continue
                x0, y0, x1, y1 = max(crops[k, 0], c0), max(crops[k, 1], ra), min(crops[k, 2], c1), min(crops[k, 3], rb)
                if x0 >= x1 or y0 >= y1:
                    continue
                for r in range(y0, y1):
                    memset(&out[(crops[k, 5] + r - crops[k, 1]) * wm + crops[k, 4] + x0 - crops[k, 0]], 0, x1 - x0)
        return n, hm, wm
    finally:
        free(parent); free(gid); free(oi); free(occ); free(box)


def place_contours(int32_t[:, ::1] pts, const int64_t[::1] starts, const int64_t[:, ::1] crops, int n_crops,
                   int64_t[:, ::1] rects, double[::1] areas, int64_t[::1] keys):
    """The contours found in a `mosaic` (all their points `pts` (N, 2), contour i's rows
    starts[i]:starts[i + 1]) moved back to the mask's coordinates in place; rects[i] = their
    cv2.boundingRect, areas[i] = cv2.contourArea (exact: integer vertices), keys[i] = their first
    point's y * 2^31 + x (findContours returns its contours by descending first point)."""
    cdef Py_ssize_t nc = starts.shape[0] - 1, i, j, k, lo, hi, mid
    cdef int64_t dx, dy, x0, y0, x1, y1, a, px, py
    for i in range(nc):
        if starts[i + 1] <= starts[i]:
            raise ValueError("empty contour")
        # the crop holding the first point: crops are laid out left to right
        lo, hi = 0, n_crops - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if crops[mid, 4] <= pts[starts[i], 0]:
                lo = mid
            else:
                hi = mid - 1
        dx, dy = crops[lo, 0] - crops[lo, 4], crops[lo, 1] - crops[lo, 5]
        x0 = y0 = 1 << 62
        x1 = y1 = -(1 << 62)
        a = 0
        px, py = pts[starts[i + 1] - 1, 0] + dx, pts[starts[i + 1] - 1, 1] + dy
        for j in range(starts[i], starts[i + 1]):
            pts[j, 0] += <int32_t>dx
            pts[j, 1] += <int32_t>dy
            a += px * pts[j, 1] - py * pts[j, 0]
            px, py = pts[j, 0], pts[j, 1]
            x0, y0, x1, y1 = min(x0, px), min(y0, py), max(x1, px), max(y1, py)
        rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3] = x0, y0, x1 - x0 + 1, y1 - y0 + 1
        areas[i] = abs(<double>a * 0.5)
        keys[i] = pts[starts[i], 1] * (<int64_t>1 << 31) + pts[starts[i], 0]


# ------------------------------------------------------------------ row profiles

cdef extern from *:
    """
    /* sum of p[i] where m[i] != 0 (m 0/1 or 0/255) and the count of such i, over [0, n) */
    static inline void occ_masked_sum(const unsigned char *p, const unsigned char *m, Py_ssize_t n,
                                      int64_t *sum, int64_t *cnt) {
        Py_ssize_t i = 0;
        int64_t s = 0, c = 0;
    #ifdef OCC_SSE2
        const __m128i z = _mm_setzero_si128();
        __m128i vs = z, vc = z;
        for (; i + 16 <= n; i += 16) {
            __m128i on = _mm_xor_si128(_mm_cmpeq_epi8(_mm_loadu_si128((const __m128i *)(m + i)), z),
                                       _mm_set1_epi8((char)0xff));
            __m128i v = _mm_and_si128(_mm_loadu_si128((const __m128i *)(p + i)), on);
            vs = _mm_add_epi64(vs, _mm_sad_epu8(v, z));
            vc = _mm_add_epi64(vc, _mm_sad_epu8(_mm_and_si128(on, _mm_set1_epi8(1)), z));
        }
        s = _mm_cvtsi128_si64(vs) + _mm_cvtsi128_si64(_mm_unpackhi_epi64(vs, vs));
        c = _mm_cvtsi128_si64(vc) + _mm_cvtsi128_si64(_mm_unpackhi_epi64(vc, vc));
    #endif
        for (; i < n; i++)
            if (m[i]) { s += p[i]; c++; }
        *sum = s;
        *cnt = c;
    }
    """
    void occ_masked_sum(const unsigned char *p, const unsigned char *m, Py_ssize_t n,
                        int64_t *sum, int64_t *cnt) nogil


def masked_row_sums(const unsigned char[:, :] roi, const unsigned char[:, ::1] mask,
                    float[::1] sums, float[::1] weights):
    """Per row of the (R, C) `roi`: the sum of its pixels where `mask` is nonzero, and their
    count, as float32 (exact integers: `profile.row_profile`'s cv2.reduce sums)."""
    if roi.shape[1] > 1 and roi.strides[1] != 1:
        raise ValueError("roi rows must be contiguous")
    if mask.shape[0] != roi.shape[0] or mask.shape[1] != roi.shape[1] or sums.shape[0] < roi.shape[0] \
            or weights.shape[0] < roi.shape[0]:
        raise ValueError("mask, sums and weights must match roi")
    cdef Py_ssize_t r, n = roi.shape[1]
    cdef int64_t s, c
    for r in range(roi.shape[0]):
        occ_masked_sum(&roi[r, 0], &mask[r, 0], n, &s, &c)
        sums[r] = <float>s
        weights[r] = <float>c


def masked_sum(const unsigned char[:, :] roi, const unsigned char[:, ::1] mask):
    """(sum of the `roi` pixels where `mask` is nonzero, their count) (`profile.mean_in_mask`)."""
    if roi.shape[1] > 1 and roi.strides[1] != 1:
        raise ValueError("roi rows must be contiguous")
    if mask.shape[0] != roi.shape[0] or mask.shape[1] != roi.shape[1]:
        raise ValueError("mask must match roi")
    cdef Py_ssize_t r, n = roi.shape[1]
    cdef int64_t s, c, ts = 0, tc = 0
    for r in range(roi.shape[0]):
        occ_masked_sum(&roi[r, 0], &mask[r, 0], n, &s, &c)
        ts += s
        tc += c
    return ts, tc


# ------------------------------------------------------------------ detection: hulls of isolated blobs

cdef extern from *:
    """
    #include <math.h>
    #include <stdint.h>

    /* numpy's pairwise summation (np.add.reduce of float64, PW_BLOCKSIZE 128), a[0..n) */
    static double occ_pw_sum(const double *a, Py_ssize_t n) {
        Py_ssize_t i;
        if (n < 8) {
            double res = -0.0;
            for (i = 0; i < n; i++) res += a[i];
            return res;
        }
        if (n <= 128) {
            double r[8], res;
            for (i = 0; i < 8; i++) r[i] = a[i];
            for (i = 8; i < n - (n % 8); i += 8) {
                r[0] += a[i + 0]; r[1] += a[i + 1]; r[2] += a[i + 2]; r[3] += a[i + 3];
                r[4] += a[i + 4]; r[5] += a[i + 5]; r[6] += a[i + 6]; r[7] += a[i + 7];
            }
            res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
            for (; i < n; i++) res += a[i];
            return res;
        }
        {
            Py_ssize_t n2 = n / 2;
            n2 -= n2 % 8;
            return occ_pw_sum(a, n2) + occ_pw_sum(a + n2, n - n2);
        }
    }

    /* one segment of np.add.reduceat (n >= 1): its first element plus the pairwise sum of the rest */
    static inline double occ_seg_sum(const double *a, Py_ssize_t n) {
        double s = a[0];
        if (n > 1) s += occ_pw_sum(a + 1, n - 1);
        return s;
    }

    /* ascending sort of distinct keys (quicksort, median of three; insertion sort below 17) */
    static void occ_sort_u64(uint64_t *a, Py_ssize_t n) {
        while (n > 16) {
            uint64_t x = a[0], y = a[n / 2], z = a[n - 1], p, t;
            Py_ssize_t i = -1, j = n;
            p = x < y ? (y < z ? y : (x < z ? z : x)) : (x < z ? x : (y < z ? z : y));
            for (;;) {
                do i++; while (a[i] < p);
                do j--; while (a[j] > p);
                if (i >= j) break;
                t = a[i]; a[i] = a[j]; a[j] = t;
            }
            /* [0, j] and [j + 1, n): recurse into the smaller */
            if (j + 1 < n - j - 1) {
                occ_sort_u64(a, j + 1);
                a += j + 1;
                n -= j + 1;
            } else {
                occ_sort_u64(a + j + 1, n - j - 1);
                n = j + 1;
            }
        }
        for (Py_ssize_t i = 1; i < n; i++) {
            uint64_t v = a[i];
            Py_ssize_t j = i;
            while (j > 0 && a[j - 1] > v) { a[j] = a[j - 1]; j--; }
            a[j] = v;
        }
    }

    #define OCC_SIGN(v) (((v) > 0) - ((v) < 0))

    /* OpenCV's Sklansky_ (imgproc/src/convhull.cpp) on the sorted points (px[k], py[k]) */
    static int occ_sklansky(const int32_t *px, const int32_t *py, int start, int end, int *stack,
                            int nsign, int sign2) {
        int incr = end > start ? 1 : -1;
        int pprev = start, pcur = pprev + incr, pnext = pcur + incr;
        int stacksize = 3;
        if (start == end || (px[start] == px[end] && py[start] == py[end])) {
            stack[0] = start;
            return 1;
        }
        stack[0] = pprev;
        stack[1] = pcur;
        stack[2] = pnext;
        end += incr;
        while (pnext != end) {
            int cury = py[pcur], nexty = py[pnext], by = nexty - cury;
            if (OCC_SIGN(by) != nsign) {
                int ax = px[pcur] - px[pprev], ay = cury - py[pprev];
                int bx = px[pnext] - px[pcur];
                int64_t convexity = (int64_t)ay * bx - (int64_t)ax * by;
                if (OCC_SIGN(convexity) == sign2 && (ax != 0 || ay != 0)) {
                    pprev = pcur;
                    pcur = pnext;
                    pnext += incr;
                    stack[stacksize] = pnext;
                    stacksize++;
                } else if (pprev == start) {
                    pcur = pnext;
                    stack[1] = pcur;
                    pnext += incr;
                    stack[2] = pnext;
                } else {
                    stack[stacksize - 2] = pnext;
                    pcur = pprev;
                    pprev = stack[stacksize - 4];
                    stacksize--;
                }
            } else {
                pnext += incr;
                stack[stacksize - 1] = pnext;
            }
        }
        return --stacksize;
    }

    /* cv2.convexHull(points, clockwise=False) of the integer points (x[i], y[i]), i < total
       (0 <= x, y, total < 2^21): the indices of its vertices, in OpenCV's order, into hull;
       returns their count. Work space: keys (total), ord, px, py (total), stack (2 total + 4).
       keys NULL: ord holds the indices already sorted by (x, y, index).
       A port of OpenCV 5.0's convexHull for integer points: points sorted by (x, y, index)
       (its comparator's order, a total one: any sort gives its order), the upper and lower
       chains by Sklansky's scan (equal points are not skipped), and the cyclic shift that makes
       the indices ascending or descending where it can. tests/engine/test_detect_kernels.py checks
       it against cv2.convexHull on random point sets with many equal points. */
    static int occ_convex_hull(const int32_t *x, const int32_t *y, int total, uint64_t *keys,
                               int *ord, int32_t *px, int32_t *py, int *stack, int *hull) {
        int i, nout = 0, miny_ind = 0, maxy_ind = 0;
        if (keys != NULL) {
            for (i = 0; i < total; i++)
                keys[i] = ((uint64_t)x[i] << 42) | ((uint64_t)y[i] << 21) | (uint64_t)i;
            occ_sort_u64(keys, total);
            for (i = 0; i < total; i++) ord[i] = (int)(keys[i] & 0x1FFFFF);
        }
        for (i = 0; i < total; i++) {
            px[i] = x[ord[i]];
            py[i] = y[ord[i]];
        }
        for (i = 1; i < total; i++) {
            if (py[miny_ind] > py[i]) miny_ind = i;
            if (py[maxy_ind] < py[i]) maxy_ind = i;
        }
        if (px[0] == px[total - 1] && py[0] == py[total - 1]) {
            hull[nout++] = 0;
            return nout;
        }
        {
            /* upper half (clockwise = false: the two stacks swapped) */
            int *tr_stack = stack;
            int tr_count = occ_sklansky(px, py, 0, maxy_ind, tr_stack, -1, 1);
            int *tl_stack = stack + tr_count;
            int tl_count = occ_sklansky(px, py, total - 1, maxy_ind, tl_stack, -1, -1);
            for (i = 0; i < tl_count - 1; i++) hull[nout++] = ord[tl_stack[i]];
            for (i = tr_count - 1; i > 0; i--) hull[nout++] = ord[tr_stack[i]];
            int stop_idx = tr_count > 2 ? tr_stack[1] : tl_count > 2 ? tl_stack[tl_count - 2] : -1;
            /* lower half */
            int *bl_stack = stack;
            int bl_count = occ_sklansky(px, py, 0, miny_ind, bl_stack, 1, -1);
            int *br_stack = stack + bl_count;
            int br_count = occ_sklansky(px, py, total - 1, miny_ind, br_stack, 1, 1);
            if (stop_idx >= 0) {
                int check_idx = bl_count > 2 ? bl_stack[1] :
                                bl_count + br_count > 2 ? br_stack[2 - bl_count] : -1;
                if (check_idx == stop_idx || (check_idx >= 0 && px[check_idx] == px[stop_idx]
                                              && py[check_idx] == py[stop_idx])) {
                    if (bl_count > 2) bl_count = 2;
                    if (br_count > 2) br_count = 2;
                }
            }
            for (i = 0; i < bl_count - 1; i++) hull[nout++] = ord[bl_stack[i]];
            for (i = br_count - 1; i > 0; i--) hull[nout++] = ord[br_stack[i]];
        }
        if (nout >= 3) {
            int min_idx = 0, max_idx = 0, lt = 0;
            for (i = 1; i < nout; i++) {
                int idx = hull[i];
                lt += hull[i - 1] < idx;
                if (lt > 1 && lt <= i - 2) break;
                if (idx < hull[min_idx]) min_idx = i;
                if (idx > hull[max_idx]) max_idx = i;
            }
            int mmdist = abs(max_idx - min_idx);
            if ((mmdist == 1 || mmdist == nout - 1) && (lt <= 1 || lt >= nout - 2)) {
                int ascending = (max_idx + 1) % nout == min_idx;
                int i0 = ascending ? min_idx : max_idx, j = i0;
                if (i0 > 0) {
                    for (i = 0; i < nout; i++) {
                        int curr_idx = stack[i] = hull[j];
                        int next_j = j + 1 < nout ? j + 1 : 0;
                        int next_idx = hull[next_j];
                        if (i < nout - 1 && (ascending != (curr_idx < next_idx))) break;
                        j = next_j;
                    }
                    if (i == nout) memcpy(hull, stack, nout * sizeof(hull[0]));
                }
            }
        }
        return nout;
    }

    /* hypot of small integer differences from a table of hypot's own results (the same bits:
       glibc's hypot takes |x| and |y| first), hypot itself for the rest; the hull's vertices are
       integer pixel centres. occ_hypot_init fills the table once, at the module's import. */
    #define OCC_HYP_N 64
    static double occ_hyp_tab[OCC_HYP_N * OCC_HYP_N];
    static int occ_hyp_ready = 0;
    static void occ_hypot_init(void) {
        for (int a = 0; a < OCC_HYP_N; a++)
            for (int b = 0; b < OCC_HYP_N; b++)
                occ_hyp_tab[a * OCC_HYP_N + b] = hypot((double)a, (double)b);
        occ_hyp_ready = 1;
    }
    static inline double occ_hypot(double dx, double dy) {
        double ax = fabs(dx), ay = fabs(dy);
        if (occ_hyp_ready && ax < (double)OCC_HYP_N && ay < (double)OCC_HYP_N) {
            int ix = (int)ax, iy = (int)ay;
            if ((double)ix == ax && (double)iy == ay)
                return occ_hyp_tab[ix * OCC_HYP_N + iy];
        }
        return hypot(dx, dy);
    }

    /* `detect._hull_stats_points` of one polygon (x[i], y[i]), i < k, k >= 1: centroid (cx, cy)
       and area plus half-pixel rim, with numpy's operations in numpy's order (reduceat sums).
       w: work space of 4 k doubles. */
    static void occ_hull_stats(const double *x, const double *y, Py_ssize_t k, double *w,
                               double *cx, double *cy, double *area) {
        double *cr = w, *sxv = w + k, *syv = w + 2 * k, *pv = w + 3 * k;
        Py_ssize_t i;
        for (i = 0; i < k; i++) {
            Py_ssize_t j = i + 1 < k ? i + 1 : 0;
            double xn = x[j], yn = y[j];
            double c = x[i] * yn - xn * y[i];
            cr[i] = c;
            sxv[i] = (x[i] + xn) * c;
            syv[i] = (y[i] + yn) * c;
            pv[i] = occ_hypot(xn - x[i], yn - y[i]);
        }
        double a2 = occ_seg_sum(cr, k), sx = occ_seg_sum(sxv, k), sy = occ_seg_sum(syv, k);
        double perim = occ_seg_sum(pv, k);
        double m00 = 0.5 * fabs(a2);
        if (m00 <= 1e-6) {
            *cx = occ_seg_sum(x, k) / (double)k;
            *cy = occ_seg_sum(y, k) / (double)k;
        } else {
            *cx = sx / (3.0 * a2);
            *cy = sy / (3.0 * a2);
        }
        *area = (m00 + 0.5 * perim) + 0.78539816339744830962;
    }
    """
    int occ_convex_hull(const int32_t *x, const int32_t *y, int total, uint64_t *keys, int *ord,
                        int32_t *px, int32_t *py, int *stack, int *hull) nogil
    void occ_hull_stats(const double *x, const double *y, Py_ssize_t k, double *w, double *cx,
                        double *cy, double *area) nogil
    double occ_seg_sum(const double *a, Py_ssize_t n) nogil
    void occ_sort_u64(uint64_t *a, Py_ssize_t n) nogil
    void occ_hypot_init() nogil
    double occ_hypot(double dx, double dy) nogil


occ_hypot_init()


def hypot_table_equals_hypot():
    """Whether the hull perimeter's table of hypot(a, b), 0 <= a, b < 64, and its look-up
    (negative, fractional and large differences included) give hypot's own bits (for the
    tests)."""
    cdef int a, b
    cdef double x, y
    for a in range(-70, 71):
        for b in range(-70, 71):
            for x, y in ((a, b), (a + 0.5, b), (a, b - 0.25), (-0.0 * a, b)):
                if occ_hypot(x, y) != hypot(x, y):
                    return False
    return True



def convex_hull(const int32_t[:, ::1] pts):
    """cv2.convexHull of (N, 2) int32 points (0 <= x, y < 2^21, N < 2^21): (K, 2) int32
    vertices in OpenCV's order (`occ_convex_hull`; for the kernel's tests)."""
    cdef int n = pts.shape[0], i, k
    if n == 0:
        return []
    if n >= (1 << 21):
        raise ValueError("too many points")
    for i in range(n):
        if pts[i, 0] < 0 or pts[i, 1] < 0 or pts[i, 0] >= (1 << 21) or pts[i, 1] >= (1 << 21):
            raise ValueError("points outside [0, 2^21)")
    cdef int32_t *x = <int32_t *>malloc(4 * n * sizeof(int32_t))
    cdef uint64_t *keys = <uint64_t *>malloc(n * sizeof(uint64_t))
    cdef int *iw = <int *>malloc((4 * n + 8) * sizeof(int))
    if x == NULL or keys == NULL or iw == NULL:
        free(x); free(keys); free(iw)
        raise MemoryError()
    try:
        for i in range(n):
            x[i] = pts[i, 0]
            x[n + i] = pts[i, 1]
        k = occ_convex_hull(x, x + n, n, keys, iw, x + 2 * n, x + 3 * n, iw + n, iw + 3 * n + 4)
        return [(int(x[iw[3 * n + 4 + i]]), int(x[n + iw[3 * n + 4 + i]])) for i in range(k)]
    finally:
        free(x); free(keys); free(iw)


def hull_stats(const double[:, ::1] poly, const int64_t[::1] starts, double[:, ::1] out):
    """out[i] = (cx, cy, area_px) of polygon i, rows starts[i]:starts[i + 1] of `poly` (x, y)
    (`detect._hull_stats_points`, bit for bit)."""
    cdef Py_ssize_t n = starts.shape[0] - 1, i, j, k, kmax = 0
    for i in range(n):
        if starts[i + 1] - starts[i] > kmax:
            kmax = starts[i + 1] - starts[i]
    cdef double *w = <double *>malloc((7 * kmax + 1) * sizeof(double))
    if w == NULL:
        raise MemoryError()
    try:
        for i in range(n):
            k = starts[i + 1] - starts[i]
            for j in range(k):
                w[5 * kmax + j] = poly[starts[i] + j, 0]
                w[6 * kmax + j] = poly[starts[i] + j, 1]
            occ_hull_stats(w + 5 * kmax, w + 6 * kmax, k, w, &out[i, 0], &out[i, 1], &out[i, 2])
    finally:
        free(w)


cdef Py_ssize_t _refine_alone_c(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, double bg,
                                double level, double refine_frac, double saturated_gray, double saturated_frac,
                                double min_refine_contrast, double *peak, double *blob_level, int64_t *found,
                                double *stats, int64_t *bounds, double[:, ::1] poly, int64_t *pstart) except -2:
    """`refine_alone` into n peaks, levels, found, (n, 3) stats, (n, 4) bounds and n + 1 pstart."""
    cdef Py_ssize_t n = rects.shape[0], i, r, x0, y0, bw, bh, m, k, j, hmax = 0, wmax = 0, nf = 0, pos = 0
    cdef unsigned char mx, v, on
    cdef double pk, bl, u, lv, clipped, sat = saturated_frac * (255.0 - bg), fo
    cdef Py_ssize_t first
    if not _boxes_inside(rects, gray.shape[0], gray.shape[1]) or poly.shape[0] < 2 * _total_rows(rects):
        return -1
    # the clipped level: bg + Python's max(saturated_frac * (255 - bg), min_refine_contrast)
    clipped = bg + (min_refine_contrast if min_refine_contrast > sat else sat)
    for i in range(n):
        x0, y0, bw, bh = rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3]
        if bw >= (1 << 20) or bh >= (1 << 20):
            return -1
        if bh > hmax:
            hmax = bh
        if bw > wmax:
            wmax = bw
        pk = occ_u8_max_box_any(&gray[y0, x0], gray.shape[1], bh, bw) if bh > 0 else 0
        # np.maximum(bg + refine_frac * (peak - bg), np.minimum(level, peak - 1)), NaN-propagating
        u = bg + refine_frac * (pk - bg)
        lv = level if (level <= pk - 1 or isnan(level)) else pk - 1
        bl = clipped if pk >= saturated_gray else (u if (u >= lv or isnan(u)) else lv)
        if not isfinite(bl) or bl < 0:
            return -1
        peak[i] = pk
        blob_level[i] = bl
    cdef int32_t *iw32 = <int32_t *>malloc((8 * hmax + 8) * sizeof(int32_t))
    cdef uint64_t *keys = <uint64_t *>malloc((2 * hmax + 2) * sizeof(uint64_t))
    cdef int *iw = <int *>malloc((8 * hmax + 16) * sizeof(int))
    cdef double *dw = <double *>malloc((14 * hmax + 8) * sizeof(double))
    cdef int *cnt = <int *>malloc((wmax + 2) * sizeof(int))
    cdef int32_t *px
    cdef int32_t *py
    cdef int *hull
    cdef double *hx
    cdef double *hy
    if iw32 == NULL or keys == NULL or iw == NULL or dw == NULL or cnt == NULL:
        free(iw32); free(keys); free(iw); free(dw); free(cnt)
        raise MemoryError()
    px, py = iw32, iw32 + 2 * hmax + 2
    hull = iw + 6 * hmax + 8
    hx, hy = dw + 10 * hmax + 4, dw + 12 * hmax + 6
    try:
        pstart[0] = 0
        for i in range(n):
            x0, y0, bw, bh = rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3]
            # gray > level (cv2.threshold) is gray >= floor(level) + 1 for uint8
            fo = floor(blob_level[i]) + 1
            if fo > 255:
                continue
            on = <unsigned char>fo
            m = 0
            for r in range(bh):
                first = occ_u8_first_ge(&gray[y0 + r, x0], bw, on)
                if first >= 0:
                    px[m] = <int32_t>first
                    py[m] = <int32_t>r
                    m += 1
            if m == 0:
                continue
            for j in range(m):
                r = py[j]
                px[m + j] = <int32_t>occ_u8_last_ge(&gray[y0 + r, x0], bw, on)
                py[m + j] = <int32_t>r
            # sorted by (x, y, index) in O(points + width): the rows interleaved (left end j,
            # right end m + j: by row, then index), then a stable counting sort by column
            memset(cnt, 0, (bw + 1) * sizeof(int))
            for j in range(2 * m):
                cnt[px[j] + 1] += 1
            for j in range(bw):
                cnt[j + 1] += cnt[j]
            for j in range(m):
                iw[cnt[px[j]]] = <int>j
                cnt[px[j]] += 1
                iw[cnt[px[m + j]]] = <int>(m + j)
                cnt[px[m + j]] += 1
            k = occ_convex_hull(px, py, <int>(2 * m), NULL, iw, iw32 + 4 * hmax + 4, iw32 + 6 * hmax + 6,
                                iw + 2 * hmax + 2, hull)
            for j in range(k):
                hx[j] = px[hull[j]]
                hy[j] = py[hull[j]]
            occ_hull_stats(hx, hy, k, dw, &stats[3 * nf], &stats[3 * nf + 1], &stats[3 * nf + 2])
            stats[3 * nf + 0] += <double>x0
            stats[3 * nf + 1] += <double>y0
            bounds[4 * nf + 0] = bounds[4 * nf + 1] = 1 << 62
            bounds[4 * nf + 2] = bounds[4 * nf + 3] = -(1 << 62)
            for j in range(k):
                poly[pos + j, 0] = hx[j] + <double>x0
                poly[pos + j, 1] = hy[j] + <double>y0
                if <int64_t>poly[pos + j, 0] < bounds[4 * nf + 0]:
                    bounds[4 * nf + 0] = <int64_t>poly[pos + j, 0]
                if <int64_t>poly[pos + j, 1] < bounds[4 * nf + 1]:
                    bounds[4 * nf + 1] = <int64_t>poly[pos + j, 1]
                if <int64_t>poly[pos + j, 0] + 1 > bounds[4 * nf + 2]:
                    bounds[4 * nf + 2] = <int64_t>poly[pos + j, 0] + 1
                if <int64_t>poly[pos + j, 1] + 1 > bounds[4 * nf + 3]:
                    bounds[4 * nf + 3] = <int64_t>poly[pos + j, 1] + 1
            pos += k
            found[nf] = i
            nf += 1
            pstart[nf] = pos
    finally:
        free(iw32); free(keys); free(iw); free(dw); free(cnt)
    return nf


def refine_alone(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, double bg, double level,
                 double refine_frac, double saturated_gray, double saturated_frac, double min_refine_contrast,
                 double[::1] peak, double[::1] blob_level, int64_t[::1] found, double[:, ::1] stats,
                 int64_t[:, ::1] bounds, double[:, ::1] poly, int64_t[::1] pstart):
    """`detect._refine_alone_batch` of N isolated boxes (x, y, w, h) in one pass: each box's peak
    and blob level (peak[i], blob_level[i]), the hull of its rows' leftmost and rightmost pixels
    above that level (`occ_convex_hull`, cv2.convexHull's vertices and order) and the hull's
    stats. Blobs with a hull are found[j] (ascending), j < the returned count: stats[j] = cx,
    cy, area_px (image coordinates), bounds[j] = x0, y0, x1, y1 (the hull's floor / +1 box),
    their vertices (image coordinates) poly[pstart[j]:pstart[j + 1]]. poly needs 2 * (sum of
    heights) rows. Returns -1 (nothing else defined) when a box is not inside the frame or
    is 2^20 px or more, or a blob level is negative or not finite: the caller's numpy path."""
    cdef Py_ssize_t n = rects.shape[0]
    if pstart.shape[0] < n + 1 or peak.shape[0] < n or blob_level.shape[0] < n or found.shape[0] < n \
            or stats.shape[0] < n or stats.shape[1] != 3 or bounds.shape[0] < n or bounds.shape[1] != 4:
        return -1
    if n == 0:
        pstart[0] = 0
        return 0
    return _refine_alone_c(gray, rects, bg, level, refine_frac, saturated_gray, saturated_frac, min_refine_contrast,
                           &peak[0], &blob_level[0], &found[0], &stats[0, 0], &bounds[0, 0], poly, &pstart[0])


_object_new = object.__new__


cdef extern from "Python.h":
    int PyObject_GenericSetDict(object o, object value, void *context) except -1


def refine_alone_blobs(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, double bg, double level,
                       double refine_frac, double saturated_gray, double saturated_frac, double min_refine_contrast,
                       object blob_type, object empty):
    """`refine_alone`, and the result as `detect._refine_alone_batch` gives it: a list of N
    `blob_type` records (receiver.core.records.Blob; None where a box has no hull), each built
    as `records.frozen_record` builds one (a new object of the class and its field dict), the
    hulls (K, 2) float64 views of one array from `empty` (numpy.empty); None where
    `refine_alone` declines (-1)."""
    cdef Py_ssize_t n = rects.shape[0], nf, j, i, h = gray.shape[0], w = gray.shape[1]
    cdef int64_t x0, y0, x1, y1
    cdef double *work
    cdef int64_t *iwork
    cdef list out
    if not _boxes_inside(rects, h, w):
        return None
    poly_obj = empty((2 * _total_rows(rects), 2))
    cdef double[:, ::1] poly = poly_obj
    work = <double *>malloc((5 * n + 1) * sizeof(double))
    iwork = <int64_t *>malloc((6 * n + 2) * sizeof(int64_t))
    try:
        if work == NULL or iwork == NULL:
            raise MemoryError()
        # peak, blob level, stats (3 n); found, bounds (4 n), pstart (n + 1)
        nf = _refine_alone_c(gray, rects, bg, level, refine_frac, saturated_gray, saturated_frac,
                             min_refine_contrast, work, work + n, iwork, work + 2 * n, iwork + n, poly,
                             iwork + 5 * n)
        if nf < 0:
            return None
        out = [None] * n
        for j in range(nf):
            i = iwork[j]
            x0, y0, x1, y1 = iwork[n + 4 * j], iwork[n + 4 * j + 1], iwork[n + 4 * j + 2], iwork[n + 4 * j + 3]
            o = _object_new(blob_type)
            PyObject_GenericSetDict(o, {
                "cx": work[2 * n + 3 * j], "cy": work[2 * n + 3 * j + 1], "area_px": work[2 * n + 3 * j + 2],
                "hull": poly_obj[iwork[5 * n + j]:iwork[5 * n + j + 1]], "x0": x0, "y0": y0, "x1": x1, "y1": y1,
                "border": x0 <= 0 or y0 <= 0 or x1 >= w or y1 >= h, "peak": work[i], "level": work[n + i],
                "background": bg}, NULL)
            out[i] = o
        return out
    finally:
        free(work)
        free(iwork)


def isolated(const int64_t[:, ::1] rects, unsigned char[::1] out):
    """out[i] = 1 when box i (x, y, w, h) overlaps no other box (`detect._isolated`: half-open
    boxes, a box always overlapping itself counted once), else 0."""
    cdef Py_ssize_t n = rects.shape[0], i
    if out.shape[0] < n:
        raise ValueError("out too short")
    if n == 0:
        return
    if rects.shape[1] < 4:
        raise ValueError("rects (n, 4) needed")
    _isolated_core(&rects[0, 0], n, rects.shape[1], &out[0], 0)


cdef void _isolated_core(const int64_t *rects, Py_ssize_t n, Py_ssize_t stride, void *out, int wide) noexcept:
    """`isolated` of the boxes x, y, w, h at rects[stride * i]: into bytes (wide 0) or int64s at
    the same stride, column 0 (wide 1: out is the box row's column `out - rects` away)."""
    cdef Py_ssize_t i, j, c
    cdef const int64_t *a
    cdef const int64_t *b
    for i in range(n):
        c = 0
        a = rects + stride * i
        for j in range(n):
            b = rects + stride * j
            if a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]:
                c += 1
        if wide:
            (<int64_t *>out)[stride * i] = c == 1
        else:
            (<unsigned char *>out)[i] = c == 1


# ------------------------------------------------------------------ components by runs

cdef extern from *:
    """
    /* The runs of nonzero bytes of p[0..n): their first and last columns appended to a, b from
       index k (the caller leaves room for (n + 1) / 2 more); returns the new count. */
    static inline Py_ssize_t occ_row_runs(const unsigned char *p, Py_ssize_t n, int32_t *a, int32_t *b,
                                          Py_ssize_t k) {
        Py_ssize_t i = 0;
        uint64_t in = 0;
        int32_t start = 0;
    #ifdef OCC_SSE2
        const __m128i z = _mm_setzero_si128();
        for (; i + 64 <= n; i += 64) {
            __m128i v0 = _mm_loadu_si128((const __m128i *)(p + i));
            __m128i v1 = _mm_loadu_si128((const __m128i *)(p + i + 16));
            __m128i v2 = _mm_loadu_si128((const __m128i *)(p + i + 32));
            __m128i v3 = _mm_loadu_si128((const __m128i *)(p + i + 48));
            /* 64 pixels like the one before them (all dark after a dark one, all lit after a
               lit one): no run starts or ends here */
            if (!in) {
                if (_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_or_si128(_mm_or_si128(v0, v1), _mm_or_si128(v2, v3)), z)) == 0xFFFF)
                    continue;
            } else if (_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_min_epu8(_mm_min_epu8(v0, v1), _mm_min_epu8(v2, v3)), z)) == 0) {
                continue;
            }
            /* bit j: pixel i + j is zero */
            uint64_t m = (uint64_t)(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(v0, z))
                | ((uint64_t)(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(v1, z)) << 16)
                | ((uint64_t)(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(v2, z)) << 32)
                | ((uint64_t)(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(v3, z)) << 48);
            m = ~m;  /* bit j: pixel i + j is lit */
            /* bit j: pixel i + j differs from the pixel before it */
            uint64_t t = m ^ ((m << 1) | in);
            in = m >> 63;
            while (t) {
                int j = __builtin_ctzll(t);
                t &= t - 1;
                if ((m >> j) & 1u) {
                    start = (int32_t)(i + j);
                } else {
                    a[k] = start; b[k] = (int32_t)(i + j - 1); k++;
                }
            }
        }
        for (; i + 16 <= n; i += 16) {
            uint64_t m = (~(uint64_t)(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(
                _mm_loadu_si128((const __m128i *)(p + i)), z))) & 0xFFFFu;
            uint64_t t = (m ^ ((m << 1) | in)) & 0xFFFFu;
            in = m >> 15;
            while (t) {
                int j = __builtin_ctzll(t);
                t &= t - 1;
                if ((m >> j) & 1u) {
                    start = (int32_t)(i + j);
                } else {
                    a[k] = start; b[k] = (int32_t)(i + j - 1); k++;
                }
            }
        }
    #endif
        for (; i < n; i++) {
            if (p[i]) {
                if (!in) { start = (int32_t)i; in = 1; }
            } else if (in) {
                a[k] = start; b[k] = (int32_t)(i - 1); k++; in = 0;
            }
        }
        if (in) { a[k] = start; b[k] = (int32_t)(n - 1); k++; }
        return k;
    }
    """
    Py_ssize_t occ_row_runs(const unsigned char *p, Py_ssize_t n, int32_t *a, int32_t *b, Py_ssize_t k) nogil


cdef struct _Run:
    int32_t a, b, row, parent, links, comp
    int64_t acc


cdef inline int32_t _run_root(_Run *r, int32_t i) noexcept nogil:
    while r[i].parent != i:
        r[i].parent = r[r[i].parent].parent
        i = r[i].parent
    return i


cdef Py_ssize_t _label_core(const unsigned char[:, ::1] img, const int64_t[:, ::1] crops, int n_crops, int64_t ox,
                            int64_t oy, int64_t *out, Py_ssize_t stride, Py_ssize_t cap) except -2:
    """`label_runs` into rows of `out` (`stride` int64 apart, at most `cap`): x, y, w, h, twice
    the area, holes, first-pixel key."""
    cdef Py_ssize_t h = img.shape[0], w = img.shape[1]
    cdef Py_ssize_t y, k = 0, room = 4096, p0 = 0, p1 = 0, i, j, lo, hi, mid, nc = 0, c
    cdef _Run *r = NULL
    cdef _Run *rn
    cdef int32_t *xa = NULL
    cdef int64_t *st = NULL
    cdef int64_t *sc
    cdef int32_t ri, rj, lt, lb, rt, rb
    cdef int64_t dx, dy
    cdef int64_t *o
    if n_crops < 0 or n_crops > crops.shape[0] or (n_crops > 0 and crops.shape[1] < 6):
        raise ValueError("bad crops")
    r = <_Run *>malloc(room * sizeof(_Run))
    xa = <int32_t *>malloc(2 * ((w + 1) // 2 + 1) * sizeof(int32_t))
    st = <int64_t *>malloc(max(cap, 1) * 6 * sizeof(int64_t))
    try:
        if r == NULL or xa == NULL or st == NULL:
            raise MemoryError()
        for y in range(h):
            p0, p1 = p1, k
            # this row's runs: first columns in xa, last columns after them
            c = occ_row_runs(&img[y, 0], w, xa, xa + (w + 1) // 2 + 1, 0)
            if k + c > room:
                room = max(2 * room, k + c)
                rn = <_Run *>realloc(r, room * sizeof(_Run))
                if rn == NULL:
                    raise MemoryError()
                r = rn
            for j in range(c):
                r[k + j].a = xa[j]
                r[k + j].b = xa[(w + 1) // 2 + 1 + j]
                r[k + j].row = <int32_t>y
                r[k + j].parent = <int32_t>(k + j)
                r[k + j].links = 0
                r[k + j].acc = 0
            k += c
            # join the runs to the 8-adjacent runs of the row above (both in column order)
            i, j = p0, p1
            while i < p1 and j < k:
                if r[i].b + 1 < r[j].a:
                    i += 1
                elif r[j].b + 1 < r[i].a:
                    j += 1
                else:
                    lt, lb = max(r[i].a, r[j].a - 1), max(r[j].a, r[i].a - 1)
                    rt, rb = min(r[i].b, r[j].b + 1), min(r[j].b, r[i].b + 1)
                    r[j].acc += (rt - lt) + (rb - lb)
                    r[j].links += 1
                    ri, rj = _run_root(r, <int32_t>i), _run_root(r, <int32_t>j)
                    if ri < rj:
                        r[rj].parent = ri
                    elif rj < ri:
                        r[ri].parent = rj
                    if r[i].b < r[j].b:
                        i += 1
                    else:
                        j += 1
        # components in raster order of their first run: a run's parent is an earlier run of its
        # component (or itself: the first)
        for j in range(k):
            if r[j].parent == j:
                if nc >= cap:
                    return -1
                r[j].comp = <int32_t>nc
                sc = st + 6 * nc
                sc[0], sc[1], sc[2], sc[3], sc[4], sc[5] = r[j].a, r[j].b, r[j].row, 0, 0, j
                nc += 1
            else:
                r[j].comp = r[r[j].parent].comp
            sc = st + 6 * r[j].comp
            if r[j].a < sc[0]:
                sc[0] = r[j].a
            if r[j].b > sc[1]:
                sc[1] = r[j].b
            sc[2] = r[j].row  # rows come in order: the last one
            sc[3] += r[j].acc
            sc[4] += r[j].links - 1
        for c in range(nc):
            sc = st + 6 * c
            j = sc[5]
            if n_crops == 0:
                dx, dy = ox, oy
            else:
                # the crop holding the first pixel: crops are laid out left to right
                lo, hi = 0, n_crops - 1
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if crops[mid, 4] <= r[j].a:
                        lo = mid
                    else:
                        hi = mid - 1
                dx, dy = crops[lo, 0] - crops[lo, 4], crops[lo, 1] - crops[lo, 5]
            o = out + c * stride
            o[0], o[1] = sc[0] + dx, r[j].row + dy
            o[2], o[3] = sc[1] - sc[0] + 1, sc[2] - r[j].row + 1
            o[4] = sc[3]
            o[5] = sc[4] + 1
            o[6] = (r[j].row + dy) * (<int64_t>1 << 31) + r[j].a + dx
        return nc
    finally:
        free(r); free(xa); free(st)


def label_boxes(const unsigned char[:, ::1] img, const int64_t[:, ::1] crops, int n_crops, int64_t ox, int64_t oy,
                const unsigned char[:, ::1] gray, int on, int pool, int reach, int64_t[:, ::1] out):
    """What `detect._label` and `detect._search` take from the closed mask `img` in one call:
    `label_runs`' components in findContours' order (by descending first point), their boxes
    moved to the full-resolution search's by `pooled_boxes` (gray, on, reach) when pool > 1, and
    whether each box overlaps no other (`isolated`): out[i] = x, y, w, h, twice the outer
    contour's area, 1 if isolated else 0, and the first-point key (out: (cap, 7) int64).
    Returns the count; -1 where `label_runs` does not answer (more components than out has rows,
    a component with a hole: the caller traces the outlines), -2 where `pooled_boxes` does not
    (the caller's numpy path decides)."""
    cdef Py_ssize_t cap = out.shape[0], n, i, j, hole = 0
    cdef uint64_t *keys
    cdef int64_t *o
    cdef int64_t *tmp
    if out.shape[1] != 7:
        raise ValueError("label_boxes: out (cap, 7) needed")
    if pool > 1 and gray is None:
        raise ValueError("label_boxes: pool > 1 needs the frame")
    if cap == 0:
        return -1
    o = &out[0, 0]
    n = _label_core(img, crops, n_crops, ox, oy, o, 7, cap)
    if n <= 0:
        return n
    for i in range(n):
        if o[7 * i + 5]:
            return -1
    # findContours' order: descending keys (distinct first points), sorted as key * 2^11 + index
    if n > 2048:
        return -1
    keys = <uint64_t *>malloc(n * sizeof(uint64_t))
    tmp = <int64_t *>malloc(n * 7 * sizeof(int64_t))
    try:
        if keys == NULL or tmp == NULL:
            raise MemoryError()
        for i in range(n):
            if o[7 * i + 6] < 0 or o[7 * i + 6] >= (<int64_t>1 << 52):
                return -1
            keys[i] = ((<uint64_t>o[7 * i + 6]) << 11) | <uint64_t>i
        occ_sort_u64(keys, n)
        memcpy(tmp, o, n * 7 * sizeof(int64_t))
        for i in range(n):
            j = <Py_ssize_t>(keys[n - 1 - i] & 0x7FF)
            memcpy(o + 7 * i, tmp + 7 * j, 7 * sizeof(int64_t))
    finally:
        free(keys)
        free(tmp)
    if pool > 1 and not _pooled_core(gray, o, n, 7, on, pool, reach):
        return -2
    _isolated_core(o, n, 7, o + 5, 1)
    return n


def label_runs(const unsigned char[:, ::1] img, const int64_t[:, ::1] crops, int n_crops, int64_t ox,
               int64_t oy, int64_t[:, ::1] rects, int64_t[::1] area2, int64_t[::1] holes, int64_t[::1] keys):
    """The 8-connected components of the nonzero pixels of `img` (`detect._label`: what detect
    takes from findContours(RETR_EXTERNAL)'s outer contours, without tracing them), from the
    runs of each row joined to the 8-adjacent runs of the row above. For component i:
    rects[i] = its bounding box x, y, w, h; area2[i] = twice the area of its outer contour's
    polygon through the border pixels' centres when it has no hole (cv2.contourArea * 2: the sum
    over the links between 8-adjacent runs (a, b) above (c, d) of the trapezoid between the
    crossing edges max(a, c - 1) .. min(b, d + 1) on top and max(c, a - 1) .. min(d, b + 1)
    below); holes[i] = its holes (links - runs + 1, the run graph's independent cycles; with
    holes the outer contour's area also covers them, and area2 is not that area); keys[i] = its
    first pixel in raster order (the contour's first point), y * 2^31 + x. Coordinates are
    moved to the mask's: by (ox, oy) when n_crops is 0, else by the `mosaic` crop (crops[k] =
    x0, y0, x1, y1, x, y, laid out left to right) holding the first pixel. Components come in
    raster order of their first pixel in `img`. Returns their count, or -1 when more than
    rects has rows."""
    cdef Py_ssize_t cap = rects.shape[0], n, i
    if area2.shape[0] < cap or holes.shape[0] < cap or keys.shape[0] < cap or rects.shape[1] < 4:
        raise ValueError("outputs too short")
    cdef int64_t *o = <int64_t *>malloc(max(cap, 1) * 7 * sizeof(int64_t))
    if o == NULL:
        raise MemoryError()
    try:
        n = _label_core(img, crops, n_crops, ox, oy, o, 7, cap)
        for i in range(max(n, 0)):
            rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3] = o[7 * i], o[7 * i + 1], o[7 * i + 2], o[7 * i + 3]
            area2[i], holes[i], keys[i] = o[7 * i + 4], o[7 * i + 5], o[7 * i + 6]
        return n
    finally:
        free(o)
