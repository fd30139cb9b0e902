# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled pixel loops of the image side (receiver.core.native): per-row scans of the blobs'
boxes that the pure numpy paths do as strips of whole-array operations.

Every function here has a pure numpy reference in receiver/vision (named in its doc) and must
give the same numbers bit for bit: the float arithmetic is written in the same precision and
order as numpy evaluates it there (float32 where the reference computes in float32).

The byte scans (row maximum, first / last pixel at or above a level) use SSE2 where the compiler
targets it (every x86-64), 16 pixels per step, and plain loops elsewhere.
"""

from libc.math cimport ceilf, sqrt, NAN
from libc.stdlib cimport malloc, free
from libc.string cimport memset
from libc.stdint cimport int64_t, int32_t

cdef extern from *:
    """
    #include <stdint.h>
    #if defined(__SSE2__) && defined(__GNUC__)
    #include <emmintrin.h>
    #define OCC_SSE2 1
    #endif

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

cdef enum:
    MIN_RUN_PX = 9  # outline.MIN_RUN_PX (2 * SIDE_PX + 5, SIDE_PX = 2: the offsets of _edge_point)


cdef inline Py_ssize_t _clampi(Py_ssize_t v, Py_ssize_t hi) noexcept nogil:
    if v < 0:
        return 0
    if v > hi:
        return hi
    return v


cdef inline bint _edge_point(const unsigned char *p, Py_ssize_t start, int side, Py_ssize_t w1,
                             float min_contrast, double *pos, float *contrast) noexcept nogil:
    """One end of a lit run (outline.stripe_edge_points_batch, per point): the sub-pixel
    crossing (box column, pos) and the plateau - outside contrast; False when no pixel pair
    straddles the half level."""
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
    cdef Py_ssize_t k, r, i, nrows, wb, w1, first, last, nbin, b, side_i, m = 0
    cdef Py_ssize_t maxrows = 0
    cdef int side
    cdef unsigned char rmax, on
    cdef float bgf, thr_lit, contrast
    cdef double pos, x, y, s, half, lo_b = <double>border_px
    cdef double hi_x = <double>(w - 1 - border_px), hi_y = <double>(h - 1 - border_px)
    cdef const unsigned char *row
    cdef Py_ssize_t *fl
    cdef double *acc
    for k in range(nb):
        if by1[k] - by0[k] > maxrows:
            maxrows = by1[k] - by0[k]
    fl = <Py_ssize_t *>malloc(2 * (maxrows + 1) * sizeof(Py_ssize_t))
    acc = <double *>malloc(4 * (maxrows + 1) * sizeof(double))
    if fl == NULL or acc == NULL:
        free(fl)
        free(acc)
        raise MemoryError()
    try:
        ends[0] = 0
        for k in range(nb):
            nrows = by1[k] - by0[k]
            wb = bx1[k] - bx0[k]
            w1 = wb - 1
            bgf = bg[k]
            # the run of every row: first and last lit pixel (-1: no run)
            for r in range(nrows):
                fl[2 * r] = -1
                row = &gray[by0[k] + r, bx0[k]]
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
                last = occ_u8_last_ge(row, wb, on)
                if first < 0 or last - first + 1 < MIN_RUN_PX:
                    continue
                fl[2 * r] = first
                fl[2 * r + 1] = last
            nbin = (nrows + bin_rows - 1) // bin_rows if bin_rows > 1 else 0
            for side_i in range(2):
                side = -1 if side_i == 0 else 1
                if bin_rows > 1:
                    for b in range(4 * nbin):
                        acc[b] = 0.0
                for r in range(nrows):
                    if fl[2 * r] < 0:
                        continue
                    row = &gray[by0[k] + r, bx0[k]]
                    if not _edge_point(row, fl[2 * r + side_i], side, w1, min_contrast, &pos, &contrast):
                        continue
                    if not (contrast >= min_contrast):
                        continue
                    x = pos + <double>bx0[k]
                    y = <double>(r + by0[k])
                    if not (x >= lo_b and x <= hi_x and y >= lo_b and y <= hi_y):
                        continue
                    if not (x > <double>(bx0[k] + 1) and x < <double>(bx1[k] - 2)):
                        continue
                    half = <double>(<float>0.5 * contrast if <float>0.5 * contrast > <float>1e-3 else <float>1e-3)
                    s = sigma_num / half
                    if s < min_sigma:
                        s = min_sigma
                    if bin_rows > 1:
                        b = 4 * (r // bin_rows)
                        acc[b] += 1.0
                        acc[b + 1] += x
                        acc[b + 2] += y
                        acc[b + 3] += s * s
                    else:
                        pts[m, 0] = x
                        pts[m, 1] = y
                        sig[m] = s
                        m += 1
                if bin_rows > 1:
                    for b in range(nbin):
                        if acc[4 * b] > 0:
                            pts[m, 0] = acc[4 * b + 1] / acc[4 * b]
                            pts[m, 1] = acc[4 * b + 2] / acc[4 * b]
                            sig[m] = sqrt(acc[4 * b + 3]) / acc[4 * b]
                            m += 1
            ends[k + 1] = m
    finally:
        free(fl)
        free(acc)
    return m


# ------------------------------------------------------------------ detection: blob envelopes

def box_max(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, double[::1] peak):
    """peak[i] = the largest gray value in box i (x, y, w, h) of `gray` (cv2.minMaxLoc's maximum
    over the ROI, `detect._refine_alone_batch`); True, or False (nothing written) when a box
    is not inside the frame."""
    cdef Py_ssize_t i, r, x, y, w, h
    cdef unsigned char m, v
    if not _boxes_inside(rects, gray.shape[0], gray.shape[1]):
        return False
    for i in range(rects.shape[0]):
        x, y, w, h = rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3]
        m = 0
        for r in range(h):
            v = occ_u8_max(&gray[y + r, x], w)
            if v > m:
                m = v
        peak[i] = m
    return True


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


def row_extremes(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, const int64_t[::1] first_on,
                 int32_t[:, ::1] pts, int64_t[::1] seg):
    """The leftmost and rightmost pixel >= first_on[i] of every row of box i (x, y, w, h) that
    has one (`detect._refine_alone_batch`): box i's points, in box coordinates (column, row),
    are pts[seg[i]:seg[i + 1]], its rows' left ends top to bottom, then their right ends.
    first_on[i] > 255: nothing is lit. `pts` needs 2 * (sum of heights) rows."""
    cdef Py_ssize_t i, r, x, y, w, h, first, m = 0, n0, nrow, j
    cdef unsigned char on
    if not _boxes_inside(rects, gray.shape[0], gray.shape[1]) or pts.shape[0] < 2 * _total_rows(rects):
        raise ValueError("boxes outside the frame, or pts too short")
    seg[0] = 0
    for i in range(rects.shape[0]):
        x, y, w, h = rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3]
        n0 = m
        if first_on[i] <= 255:
            on = <unsigned char>first_on[i]
            for r in range(h):
                first = occ_u8_first_ge(&gray[y + r, x], w, on)
                if first >= 0:
                    pts[m, 0] = <int32_t>first
                    pts[m, 1] = <int32_t>r
                    m += 1
            nrow = m - n0
            for j in range(nrow):
                r = pts[n0 + j, 1]
                pts[m, 0] = <int32_t>occ_u8_last_ge(&gray[y + r, x], w, on)
                pts[m, 1] = <int32_t>r
                m += 1
        seg[i + 1] = m


def pooled_boxes(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, int on, int pool,
                 int reach, int64_t[:, ::1] out):
    """`detect._pooled_boxes_exact` (boxes found on `pool`-row maxima -> the full-resolution
    search's): out[i] = x, first row, w, rows of the box's first to last row with a pixel >= on,
    a first row within `reach` of the top moved to 0, a last within `reach` of the bottom to the
    last row. Returns False when a box holds no such pixel (the caller's reference path then
    reports it)."""
    cdef Py_ssize_t h = gray.shape[0], i, x, y, w, hh, y1, top, bottom, r
    cdef unsigned char o = <unsigned char>on
    for i in range(rects.shape[0]):
        if rects[i, 0] < 0 or rects[i, 2] < 0 or rects[i, 0] + rects[i, 2] > gray.shape[1] or rects[i, 1] < 0:
            return False
    for i in range(rects.shape[0]):
        x, w = rects[i, 0], rects[i, 2]
        y = rects[i, 1] * pool
        y1 = (rects[i, 1] + rects[i, 3]) * pool
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
        out[i, 0] = x
        out[i, 1] = top
        out[i, 2] = w
        out[i, 3] = bottom - top + 1
    return True


# ------------------------------------------------------------------ detection: the search

def sample_hist(const unsigned char[:, ::1] gray, int step, float[::1] hist):
    """hist (256,) = the histogram of gray[::step, ::step] (cv2.calcHist's counts, float32),
    without the strided copy (`detect.auto_level`)."""
    cdef Py_ssize_t r, c, h = gray.shape[0], w = gray.shape[1]
    cdef int64_t counts[256]
    cdef const unsigned char *row
    if step < 1:
        raise ValueError("step must be positive")
    for r in range(256):
        counts[r] = 0
    r = 0
    while r < h:  # (a range with a run-time step would be a Python loop)
        row = &gray[r, 0]
        c = 0
        while c < w:
            counts[row[c]] += 1
            c += step
        r += step
    for r in range(256):
        hist[r] = <float>counts[r]


cdef extern from *:
    """
    /* mask[0..n) = 255 where max(a[i], b[i]) >= on (b may equal a), else 0; returns nonzero
       when any pixel is lit. on in 0..255. */
    static inline int occ_pool_thresh_row(const unsigned char *a, const unsigned char *b, Py_ssize_t n,
                                          unsigned char on, unsigned char *mask) {
        Py_ssize_t i = 0;
        unsigned char any = 0;
    #ifdef OCC_SSE2
        if (n >= 16) {
            const __m128i tv = _mm_set1_epi8((char)on);
            __m128i acc = _mm_setzero_si128();
            for (; i + 32 <= n; i += 32) {
                __m128i m0 = _mm_max_epu8(_mm_loadu_si128((const __m128i *)(a + i)),
                                          _mm_loadu_si128((const __m128i *)(b + i)));
                __m128i m1 = _mm_max_epu8(_mm_loadu_si128((const __m128i *)(a + i + 16)),
                                          _mm_loadu_si128((const __m128i *)(b + i + 16)));
                __m128i l0 = _mm_cmpeq_epi8(_mm_max_epu8(m0, tv), m0);
                __m128i l1 = _mm_cmpeq_epi8(_mm_max_epu8(m1, tv), m1);
                _mm_storeu_si128((__m128i *)(mask + i), l0);
                _mm_storeu_si128((__m128i *)(mask + i + 16), l1);
                acc = _mm_or_si128(acc, _mm_or_si128(l0, l1));
            }
            while (i < n) {
                if (i + 16 > n) i = n - 16;  /* the last 16 bytes, overlapping: the same values again */
                __m128i m = _mm_max_epu8(_mm_loadu_si128((const __m128i *)(a + i)),
                                         _mm_loadu_si128((const __m128i *)(b + i)));
                __m128i lit = _mm_cmpeq_epi8(_mm_max_epu8(m, tv), m);
                _mm_storeu_si128((__m128i *)(mask + i), lit);
                acc = _mm_or_si128(acc, lit);
                i += 16;
            }
            return _mm_movemask_epi8(acc) != 0;
        }
    #endif
        for (; i < n; i++) {
            unsigned char v = a[i] > b[i] ? a[i] : b[i];
            unsigned char l = v >= on ? 255 : 0;
            mask[i] = l;
            any |= l;
        }
        return any != 0;
    }
    """
    int occ_pool_thresh_row(const unsigned char *a, const unsigned char *b, Py_ssize_t n,
                            unsigned char on, unsigned char *mask) nogil


def search_mask(const unsigned char[:, ::1] gray, int pool, int on, unsigned char[:, ::1] mask):
    """The thresholded search image and its lit pixels' bounding box in one pass
    (`detect._components`): mask (ceil(H / pool), W) = 255 where the maximum over each run of
    `pool` (1 or 2) rows of `gray` is >= on (cv2.threshold's `> level` for on = floor(level) + 1),
    else 0. Returns cv2.boundingRect(mask): (x, y, w, h), zeros when nothing is lit."""
    cdef Py_ssize_t h = gray.shape[0], w = gray.shape[1], ho = mask.shape[0], i, c
    cdef Py_ssize_t y0 = -1, y1 = -1, x0 = w, x1 = -1
    cdef const unsigned char *a
    cdef const unsigned char *b
    cdef unsigned char *m
    cdef unsigned char o
    if on > 255:
        for i in range(ho):
            memset(&mask[i, 0], 0, w)
        return 0, 0, 0, 0
    o = <unsigned char>(on if on > 0 else 0)
    for i in range(ho):
        a = &gray[i * pool, 0]
        b = &gray[i * pool + 1, 0] if pool == 2 and i * pool + 1 < h else a
        m = &mask[i, 0]
        if occ_pool_thresh_row(a, b, w, o, m):
            if y0 < 0:
                y0 = i
            y1 = i
            # the columns' extent: only the part of the row outside the extent so far
            if x0 > 0:
                c = occ_u8_first_ge(m, x0, 255)
                if c >= 0:
                    x0 = c
            if x1 < w - 1:
                c = occ_u8_last_ge(m + x1 + 1, w - x1 - 1, 255)
                if c >= 0:
                    x1 = x1 + 1 + c
    if y0 < 0:
        return 0, 0, 0, 0
    return x0, y0, x1 - x0 + 1, y1 - y0 + 1


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
