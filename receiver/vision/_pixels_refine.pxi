# Envelopes of isolated blobs in one pass (detect._refine_alone_batch) and box isolation.
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

cdef Py_ssize_t _refine_alone_c(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, double bg,
                                double level, double refine_frac, double saturated_gray, double saturated_frac,
                                double min_refine_contrast, double *peak, double *blob_level, int64_t *found,
                                double *stats, int64_t *bounds, double[:, ::1] poly, int64_t *pstart) except -2:
    """`refine_alone_blobs`' pass into n peaks, levels, found, (n, 3) stats, (n, 4) bounds and n + 1 pstart;
    -1 where it declines."""
    cdef Py_ssize_t n = rects.shape[0], i, r, x0, y0, bw, bh, m, k, j, hmax = 0, nf = 0, pos = 0
    cdef unsigned char on
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
    cdef int *st = <int *>malloc((4 * hmax + 4) * sizeof(int))
    cdef double *hx = <double *>malloc((4 * hmax + 4) * sizeof(double))
    cdef int32_t *px
    cdef int32_t *py
    cdef double *hy
    if iw32 == NULL or st == NULL or hx == NULL:
        free(iw32); free(st); free(hx)
        raise MemoryError()
    # px: the rows' left ends, then their right ends; py: the rows (box coordinates)
    px, py = iw32, iw32 + 2 * hmax + 2
    hy = hx + 2 * hmax + 2
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
                px[m + j] = <int32_t>occ_u8_last_ge(&gray[y0 + py[j], x0], bw, on)
            k = occ_row_hull(px, px + m, py, <int>m, iw32 + 4 * hmax + 4, iw32 + 6 * hmax + 6, st, hx, hy)
            occ_hull_stats(hx, hy, k, &stats[3 * nf], &stats[3 * nf + 1], &stats[3 * nf + 2])
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
        free(iw32); free(st); free(hx)
    return nf


_object_new = object.__new__


cdef extern from "Python.h":
    int PyObject_GenericSetDict(object o, object value, void *context) except -1


def refine_alone_blobs(const unsigned char[:, ::1] gray, const int64_t[:, ::1] rects, double bg, double level,
                       double refine_frac, double saturated_gray, double saturated_frac, double min_refine_contrast,
                       object blob_type, object empty):
    """`detect._refine_alone_batch` of N isolated boxes (x, y, w, h) in one pass: each box's peak
    and blob level, the convex hull of its rows' leftmost and rightmost pixels above that level
    (`occ_row_hull`) and the hull's centroid and area (`occ_hull_stats`). A list of N
    `blob_type` records (receiver.core.records.Blob; None where a box has no lit pixel), each
    built as `records.frozen_record` builds one (a new object of the class and its field dict),
    the hulls (K, 2) float64 views of one array from `empty` (numpy.empty). None (declined)
    when a box is not inside the frame or is 2^20 px or more, or a blob level is negative or
    not finite."""
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
