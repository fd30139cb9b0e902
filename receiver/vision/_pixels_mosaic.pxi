# The mosaic of the lit groups and the contours placed back (detect._search_mosaic).
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

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
