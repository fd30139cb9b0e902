# The search: sampled histogram, pooled threshold mask and lit cells, full-resolution boxes of a pooled search.
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

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
    last row. Returns False when a box holds no such pixel (the caller's numpy loop then finds
    its rows)."""
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
