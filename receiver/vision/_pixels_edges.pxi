# Stripe edge points of the blobs' boxes (receiver.vision.outline).
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

# ------------------------------------------------------------------ stripe edge points

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
    the row's own pixels at the clamped columns."""
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
    no column repeated) the level test runs on integers: the float sums of u8
    values, their halves and quarters are exact, so v >= thr is 4 v >= (the four samples'
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
    # va > vb here: d >= 1, no floor needed
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
