# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Kept: a numpy path of these loops costs 79-208 % more instructions per whole frame on every bundled case (docs/kernels.md).
"""Compiled pixel loops of the detection stage (receiver.vision.detect, outline, profile): per-row
scans of the blobs' boxes, the search mask, the components' labelling and the envelopes of
isolated blobs. One extension module, one file per concern (Cython `include`):

- this file: imports, the byte scans (row maximum, first / last pixel at or above a level, SSE2
  on every x86-64, AVX2 chosen at run time), masked row sums (`profile.row_profile`);
- `_pixels_edges.pxi`: stripe edge points (`outline`);
- `_pixels_search.pxi`: sampled histogram, pooled threshold mask and lit cells, pooled boxes;
- `_pixels_mosaic.pxi`: the lit groups packed into one small image for the close;
- `_pixels_label.pxi`: the closed mask's components from its pixel runs (union-find);
- `_pixels_hull.pxi`: convex hulls of integer points and their stats;
- `_pixels_refine.pxi`: envelopes of isolated blobs in one pass, box isolation.

Each function names the receiver/vision function it serves.
"""

from receiver.core._buf cimport fresh_data
from libc.math cimport ceilf, sqrt, floor, isfinite, isnan, NAN, hypot
from libc.stdlib cimport malloc, free, realloc
from libc.string cimport memset, memcpy
from libc.stdint cimport int64_t, int32_t, uint32_t, uint64_t
from cpython.buffer cimport (PyBUF_C_CONTIGUOUS, PyBUF_FORMAT, PyBUF_STRIDES, PyBUF_WRITABLE, PyBuffer_Release,
                             PyObject_CheckBuffer, PyObject_GetBuffer)
from libc.math cimport ceil

import numpy as np

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



# ------------------------------------------------------------------ the kernels, one file per concern

include "_pixels_edges.pxi"
include "_pixels_search.pxi"
include "_pixels_mosaic.pxi"
include "_pixels_hull.pxi"
include "_pixels_refine.pxi"
include "_pixels_label.pxi"
