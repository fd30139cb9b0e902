# Components by runs: union-find labelling of the closed mask (detect._label).
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

# ------------------------------------------------------------------ components by runs

from libc.stdlib cimport qsort


cdef int _cmp_u64(const void *a, const void *b) noexcept nogil:
    """qsort's order of two uint64 keys."""
    cdef uint64_t x = (<const uint64_t *>a)[0], y = (<const uint64_t *>b)[0]
    return (x > y) - (x < y)


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
    (the caller's `_pooled_boxes_exact` decides)."""
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
        qsort(keys, n, sizeof(uint64_t), _cmp_u64)
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
