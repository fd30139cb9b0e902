# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled candidate search of the S2-PSK pairer (receiver.vision.pairing): every formed pair
against every tracked blob of a frame in one call (`Pairer._explain` of all pairs, with the
claims of `Pairer._first_pass`), with the same decisions and sums as the Python reference,
bit for bit: math.hypot's own algorithm (CPython's vector_norm, not libm's hypot) where
the reference calls math.hypot, libm's hypot where it calls np.hypot, numpy's summation
orders for the shifts' means."""

from libc.math cimport sqrt, fabs, hypot, frexp, ldexp, INFINITY
from receiver.core._npsum cimport pw_sum
import numpy as np

cdef double DBL_MIN_ = 2.2250738585072014e-308


cdef inline double _norm2(double x0, double x1, double mx) noexcept nogil:
    """CPython's vector_norm of (|x0|, |x1|) with max `mx` > 0 (Dekker's exact products:
    the same error terms as fma)."""
    cdef int max_e
    cdef double scale, csum = 1.0, frac1 = 0.0, frac2 = 0.0, x, h, t, xh, xl, p, q, z, zz, s, lo
    cdef double v[2]
    cdef int i
    frexp(mx, &max_e)
    if max_e < -1023:
        return DBL_MIN_ * _norm2(x0 / DBL_MIN_, x1 / DBL_MIN_, mx / DBL_MIN_)
    scale = ldexp(1.0, -max_e)
    v[0] = x0
    v[1] = x1
    for i in range(2):
        x = v[i] * scale
        # dl_mul(x, x) by Veltkamp-Dekker splitting
        t = x * 134217729.0
        xh = t - (t - x)
        xl = x - xh
        p = xh * xh
        q = xh * xl + xl * xh
        z = p + q
        zz = p - z + q + xl * xl
        # dl_fast_sum(csum, z)
        s = csum + z
        lo = (csum - s) + z
        csum = s
        frac1 += zz
        frac2 += lo
    h = sqrt(csum - 1.0 + (frac1 + frac2))
    x = -h
    t = x * 134217729.0
    xh = t - (t - x)
    xl = x - xh
    t = h * 134217729.0
    p = t - (t - h)  # h's high part
    q = h - p
    z = xh * p
    zz = xh * q + xl * p
    s = z + zz
    zz = z - s + zz + xl * q
    z = s
    s = csum + z
    lo = (csum - s) + z
    csum = s
    frac1 += zz
    frac2 += lo
    x = csum - 1.0 + (frac1 + frac2)
    h += x / (2.0 * h)
    return h / scale


cdef inline double py_hypot(double a, double b) noexcept nogil:
    """math.hypot(a, b) of CPython (3.10+) for finite a, b, to the last bit."""
    cdef double x0 = fabs(a), x1 = fabs(b)
    cdef double mx = x0 if x0 > x1 else x1
    if mx == 0.0:
        return mx
    if mx == INFINITY:
        return mx
    return _norm2(x0, x1, mx)


def hypot_py(double a, double b):
    """math.hypot(a, b) as the kernel computes it (tests compare it with math.hypot)."""
    return py_hypot(a, b)


cdef inline int _width_class(double bw, double bh, double wa, double wb, double ha, double hb,
                             double hx, const double[::1] cfg) noexcept nogil:
    """Pairer._width_class: 1 "single", 2 "merged", 0 None."""
    cdef double hmax = bh, w1, wm, e1, em
    if ha > hmax:
        hmax = ha
    if hb > hmax:
        hmax = hb
    if cfg[8] == 0.0 or hmax > cfg[11]:
        return 0
    w1 = wb if wb > wa else wa
    wm = w1 + 2.0 * fabs(hx)
    e1 = fabs(bw - w1)
    em = fabs(bw - wm)
    if e1 <= em and e1 <= cfg[9] * w1 + 1.0:
        return 1
    if em < e1 and 2.0 * fabs(hx) >= cfg[10] and em <= cfg[9] * wm + 1.0:
        return 2
    return 0


def explain_pairs(const double[:, ::1] tr, const double[:, ::1] pp, const unsigned char[:, ::1] excl,
                  const double[::1] cfg, int[:, :, ::1] lists, double[:, ::1] res, int[::1] flat,
                  unsigned char[:, ::1] mine):
    """Pairer._explain of every pair k (row of `pp`) against every track i (row of `tr`).

    tr (N, 8): cx, cy, area_px, x0, x1, y0, y1, seen (1, 2 when saturated / 0) of each track's blob.
    pp (P, 14): the pair's predicted mx, my, hx, hy, single (px, px^2), misses, emitter A's and
        B's areas, size, A's and B's widths (x1 - x0) and heights (y1 - y0), and the claim
        tolerance (px; < 0: no claims, see below).
    excl (P, N): 1 where track i is only nearby for pair k (the `exclude` ids).
    cfg (12,): match_frac, match_min_px, match_size, miss_growth_px, vertical_known (1 / 0),
        merged_ratio, max_merged, max_cut, width_size (1 / 0), width_tol, width_min_px,
        width_max_rows (PairSettings; vertical_known: the Pairer's).
    Out: lists (3, P, N) track indices in track order: [0] nearby, [1] explaining, [2] claimed
    (seen tracks within the claim tolerance of A or B, as `_first_pass` with np.hypot);
    res (P, 10): number of shifts, their mean dx and dy (np.mean(shifts, axis=0): one sum in
    order), the mean dy as np.mean of the dys (numpy's pairwise sum), the indices of A's and
    B's own blob and of the merged blob (-1: none), the lengths of the three lists; flat: the
    three lists of pair 0, then those of pair 1, ... one after the other (`lists` is scratch);
    mine (P, N): 1 where track i is explained or claimed by pair k, else 0.
    Returns the length of `flat` used."""
    cdef Py_ssize_t n = tr.shape[0], npair = pp.shape[0], k, i, m
    cdef double mx, my, hx, hy, single, ax, ay, bx, by, tol0, tol, tol_y, reach, da, db, dm, dmin
    cdef double cx, cy, area, ratio, amax, sx, sy, ex, ey, ctol, dca, dcb
    cdef int wide, nn, ne, nc, ns, obs_a, obs_b, merged
    cdef double match_frac, match_min_px, match_size, miss_growth, merged_ratio, max_merged, max_cut
    cdef bint vertical_known, sat
    cdef double[::1] dys
    cdef Py_ssize_t pos = 0, j
    if (tr.shape[1] < 8 or pp.shape[1] < 14 or cfg.shape[0] < 12 or excl.shape[0] != npair
            or excl.shape[1] != n or lists.shape[0] < 3 or lists.shape[1] < npair or lists.shape[2] < n
            or res.shape[0] < npair or res.shape[1] < 10 or flat.shape[0] < 3 * npair * n
            or mine.shape[0] < npair or mine.shape[1] < n):
        raise ValueError("explain_pairs: array shapes do not match (N, 8) tracks and (P, 14) pairs")
    match_frac, match_min_px, match_size = cfg[0], cfg[1], cfg[2]
    miss_growth, merged_ratio, max_merged, max_cut = cfg[3], cfg[5], cfg[6], cfg[7]
    vertical_known = cfg[4] != 0.0
    dys = np.empty(max(n, 1))
    for k in range(npair):
        mx = pp[k, 0]; my = pp[k, 1]; hx = pp[k, 2]; hy = pp[k, 3]; single = pp[k, 4]
        ax = mx - hx; ay = my - hy; bx = mx + hx; by = my + hy
        tol0 = match_size * sqrt(single)
        if match_min_px > tol0:  # max(match_min_px, ...): the first on a tie
            tol0 = match_min_px
        da = match_frac * 2 * py_hypot(hx, hy)
        if da < tol0:  # min(match_frac * 2 * hypot, ...)
            tol0 = da
        tol = tol0 + miss_growth * pp[k, 5]
        tol_y = tol0 + miss_growth if vertical_known else INFINITY
        reach = tol + py_hypot(hx, hy)
        amax = pp[k, 6]
        if pp[k, 7] > amax:
            amax = pp[k, 7]
        if pp[k, 8] > amax:
            amax = pp[k, 8]
        if 1.0 > amax:
            amax = 1.0
        ctol = pp[k, 13]
        nn = ne = nc = ns = 0
        obs_a = obs_b = merged = -1
        sx = sy = 0.0
        for i in range(n):
            cx = tr[i, 0]; cy = tr[i, 1]
            if ctol >= 0.0 and tr[i, 7] != 0.0:
                dca = hypot(cx - ax, cy - ay)
                dcb = hypot(cx - bx, cy - by)
                if (dcb if dcb < dca else dca) <= ctol:
                    lists[2, k, nc] = <int>i
                    nc += 1
            if not (hypot(cx - mx, cy - my) <= reach):
                continue
            da = py_hypot(cx - ax, cy - ay)
            db = py_hypot(cx - bx, cy - by)
            dm = py_hypot(cx - mx, cy - my)
            dmin = da
            if db < dmin:
                dmin = db
            if dm < dmin:
                dmin = dm
            if dmin > tol or fabs(cy - my) > tol_y + fabs(hy):
                continue
            lists[0, k, nn] = <int>i
            nn += 1
            if tr[i, 7] == 0.0 or excl[k, i]:
                continue
            area = tr[i, 2]
            sat = tr[i, 7] == 2.0  # saturated: its area is the bloom's (no upper bound)
            wide = _width_class(tr[i, 4] - tr[i, 3], tr[i, 6] - tr[i, 5], pp[k, 9], pp[k, 10],
                                pp[k, 11], pp[k, 12], hx, cfg)
            if wide == 2 and dm <= tol:
                ex = mx; ey = my
                merged = <int>i
            elif dm < (db if db < da else da):
                if not (merged_ratio * single < area and (sat or area <= max_merged * single)):
                    continue
                ex = mx; ey = my
                merged = <int>i
            else:
                ratio = (area if area > 1.0 else 1.0) / amax
                if not ((1.0 / max_cut <= ratio and (ratio <= merged_ratio or sat)) or (wide == 1 and ratio >= 1.0)):
                    continue
                if da <= db:
                    ex = ax; ey = ay
                    if ratio >= 1.0 / merged_ratio:
                        obs_a = <int>i
                else:
                    ex = bx; ey = by
                    if ratio >= 1.0 / merged_ratio:
                        obs_b = <int>i
            sx += cx - ex  # from numpy's reduction identity 0.0, in order
            sy += cy - ey
            dys[ns] = cy - ey
            ns += 1
            lists[1, k, ne] = <int>i
            ne += 1
        res[k, 0] = ns
        if ns:
            res[k, 1] = sx / ns
            res[k, 2] = sy / ns
            res[k, 3] = (0.0 + pw_sum(&dys[0], ns)) / ns
        else:
            res[k, 1] = res[k, 2] = res[k, 3] = 0.0
        res[k, 4] = obs_a
        res[k, 5] = obs_b
        res[k, 6] = merged
        res[k, 7] = nn
        res[k, 8] = ne
        res[k, 9] = nc
        for i in range(n):
            mine[k, i] = 0
        for m in range(3):
            j = nn if m == 0 else (ne if m == 1 else nc)
            for i in range(j):
                flat[pos] = lists[m, k, i]
                if m:
                    mine[k, lists[m, k, i]] = 1
                pos += 1
    return pos


def shift_votes(const double[:, ::1] xy, const double[:, ::1] pred, double radius_px, double[:, ::1] out):
    """Pairer.shift_votes: for every pair k (pred rows: mx, my, hx, hy) the offsets d = xy - (mx, my)
    of the blobs within radius_px + |hx| horizontally and radius_px + |hy| vertically, then d +
    (hx, hy), then d - (hx, hy), each in the blobs' order, one pair after the other, into `out`
    (at least 3 N P rows). Returns the number of rows."""
    cdef Py_ssize_t n = xy.shape[0], k, i, j = 0, m, c
    cdef double mx, my, hx, hy, dx, dy, rx, ry
    if xy.shape[1] < 2 or pred.shape[1] < 4 or out.shape[1] < 2 or out.shape[0] < 3 * n * pred.shape[0]:
        raise ValueError("shift_votes: xy must be (N, 2), pred (P, 4), out (>= 3 N P, 2)")
    for k in range(pred.shape[0]):
        mx = pred[k, 0]; my = pred[k, 1]; hx = pred[k, 2]; hy = pred[k, 3]
        rx = radius_px + fabs(hx)
        ry = radius_px + fabs(hy)
        c = 0
        for i in range(n):
            dx = xy[i, 0] - mx
            dy = xy[i, 1] - my
            if fabs(dx) <= rx and fabs(dy) <= ry:
                out[j + c, 0] = dx
                out[j + c, 1] = dy
                c += 1
        for m in range(c):
            out[j + c + m, 0] = out[j + m, 0] + hx
            out[j + c + m, 1] = out[j + m, 1] + hy
            out[j + 2 * c + m, 0] = out[j + m, 0] - hx
            out[j + 2 * c + m, 1] = out[j + m, 1] - hy
        j += 3 * c
    return j


cdef _check_boxes(const unsigned char[::1] masks, const long long[:, ::1] boxes, Py_ssize_t n_out, str name):
    """ValueError unless `boxes` is (B, 5) with B <= n_out, each box upright and its mask inside
    `masks` (the arguments of masked_means and masked_peaks)."""
    cdef Py_ssize_t k
    cdef long long x0, y0, x1, y1, off
    if boxes.shape[1] < 5 or n_out < boxes.shape[0]:
        raise ValueError(f"{name}: boxes must be (B, 5), out (B,)")
    for k in range(boxes.shape[0]):
        x0 = boxes[k, 0]; y0 = boxes[k, 1]; x1 = boxes[k, 2]; y1 = boxes[k, 3]; off = boxes[k, 4]
        if x1 < x0 or y1 < y0 or off < 0 or off + (x1 - x0) * (y1 - y0) > masks.shape[0]:
            raise ValueError(f"{name}: a box is inverted or its mask lies outside `masks`")


def masked_means(const unsigned char[:, :] gray, const unsigned char[::1] masks,
                 const long long[:, ::1] boxes, double[::1] out):
    """profile.mean_in_mask of many blobs in one call: out[k] = the mean gray of `gray` (H, W)
    where blob k's envelope mask is nonzero, over the part of its box inside the frame (0.0
    without such pixels). boxes (B, 5): x0, y0, x1, y1 (the half-open box, px, may reach past
    the frame) and the offset of its (y1 - y0, x1 - x0) mask, row by row, in `masks`. The sums
    are exact integers, divided once (as `total / n` of the reference)."""
    cdef Py_ssize_t k, x, y, h = gray.shape[0], w = gray.shape[1]
    cdef long long x0, y0, x1, y1, off, bw, cx0, cy0, cx1, cy1, tot, n
    cdef const unsigned char *row
    _check_boxes(masks, boxes, out.shape[0], "masked_means")
    for k in range(boxes.shape[0]):
        x0 = boxes[k, 0]; y0 = boxes[k, 1]; x1 = boxes[k, 2]; y1 = boxes[k, 3]; off = boxes[k, 4]
        bw = x1 - x0
        cx0 = x0 if x0 > 0 else 0
        cy0 = y0 if y0 > 0 else 0
        cx1 = x1 if x1 < w else w
        cy1 = y1 if y1 < h else h
        tot = n = 0
        for y in range(cy0, cy1):
            row = &masks[off + (y - y0) * bw - x0]
            for x in range(cx0, cx1):
                if row[x]:
                    tot += gray[y, x]
                    n += 1
        out[k] = (<double>tot) / n if n else 0.0


def masked_peaks(const unsigned char[:, :] gray, const unsigned char[::1] masks,
                 const long long[:, ::1] boxes, double[::1] out):
    """profile.peak_in_mask of many blobs in one call: out[k] = the highest gray of `gray`
    where blob k's envelope mask is nonzero (0.0 without such pixels); `boxes` as `masked_means`."""
    cdef Py_ssize_t k, x, y, h = gray.shape[0], w = gray.shape[1]
    cdef long long x0, y0, x1, y1, off, bw, cx0, cy0, cx1, cy1
    cdef int best
    cdef bint any_
    cdef const unsigned char *row
    _check_boxes(masks, boxes, out.shape[0], "masked_peaks")
    for k in range(boxes.shape[0]):
        x0 = boxes[k, 0]; y0 = boxes[k, 1]; x1 = boxes[k, 2]; y1 = boxes[k, 3]; off = boxes[k, 4]
        bw = x1 - x0
        cx0 = x0 if x0 > 0 else 0
        cy0 = y0 if y0 > 0 else 0
        cx1 = x1 if x1 < w else w
        cy1 = y1 if y1 < h else h
        best = 0
        any_ = False
        for y in range(cy0, cy1):
            row = &masks[off + (y - y0) * bw - x0]
            for x in range(cx0, cx1):
                if row[x]:
                    any_ = True
                    if gray[y, x] > best:
                        best = gray[y, x]
        out[k] = <double>best if any_ else 0.0


def dx_offsets(const double[:, ::1] bl, const double[:, ::1] pp, const double[::1] cfg, double dy,
               double radius_px, double[:, ::1] out):
    """Pairer.dx_offsets of every pair (rows of `pp`, as in `explain_pairs`; misses, areas and
    the claim tolerance unused) against every blob (rows of `bl`, as `tr` of `explain_pairs`;
    seen unused), in the loop's order (pairs, then blobs): row j of `out` gets the one (merged:
    x - mx) or two (single: x - mx + hx, x - mx - hx) shifts of the j-th kept blob, the unused
    column left as it is (+inf). Returns the number of rows written."""
    cdef Py_ssize_t n = bl.shape[0], k, i, j = 0
    cdef double mx, my, hx, hy, single, r, x
    cdef int kind
    cdef double merged_ratio, max_merged, max_cut, match_min_px
    if (bl.shape[1] < 7 or pp.shape[1] < 13 or cfg.shape[0] < 12 or out.shape[1] < 2
            or out.shape[0] < n * pp.shape[0]):
        raise ValueError("dx_offsets: bl must be (N, 7+), pp (P, 13+), cfg (12,), out (>= N P, 2)")
    merged_ratio, max_merged, max_cut, match_min_px = cfg[5], cfg[6], cfg[7], cfg[1]
    for k in range(pp.shape[0]):
        mx = pp[k, 0]; my = pp[k, 1] + dy; hx = pp[k, 2]; hy = pp[k, 3]; single = pp[k, 4]
        for i in range(n):
            if not (fabs(bl[i, 1] - my) <= match_min_px + fabs(hy) and fabs(bl[i, 0] - mx) <= radius_px + fabs(hx)):
                continue
            kind = _width_class(bl[i, 4] - bl[i, 3], bl[i, 6] - bl[i, 5], pp[k, 9], pp[k, 10],
                                pp[k, 11], pp[k, 12], hx, cfg)
            if kind == 0:
                r = bl[i, 2] / single
                if merged_ratio < r and r <= max_merged:
                    kind = 2
                elif 1.0 / max_cut <= r and r <= merged_ratio:
                    kind = 1
            x = bl[i, 0]
            if kind == 2:
                out[j, 0] = x - mx
                j += 1
            elif kind == 1:
                out[j, 0] = x - mx + hx
                out[j, 1] = x - mx - hx
                j += 1
    return j


def head_fluxes(const unsigned char[:, :] gray, const long long[:, ::1] boxes, const double[::1] bgs,
                double[::1] out):
    """Pairer.head_flux of many boxes: out[k] = the float32 sum (numpy's order) of
    max(float32(gray) - float32(bgs[k]), 0) over the box x0 <= x < x1, y0 <= y < y1 (boxes rows:
    x0, x1, y0, y1, inside the frame; 0.0 when empty)."""
    cdef Py_ssize_t k, x, y, m, most = 0
    cdef long long x0, x1, y0, y1
    cdef float bg, v
    cdef float[::1] buf
    if boxes.shape[1] < 4 or bgs.shape[0] < boxes.shape[0] or out.shape[0] < boxes.shape[0]:
        raise ValueError("head_fluxes: boxes must be (F, 4), bgs and out (F,)")
    for k in range(boxes.shape[0]):
        if boxes[k, 1] <= boxes[k, 0] or boxes[k, 3] <= boxes[k, 2]:
            continue  # empty: 0.0
        if boxes[k, 0] < 0 or boxes[k, 2] < 0 or boxes[k, 1] > gray.shape[1] or boxes[k, 3] > gray.shape[0]:
            raise ValueError("head_fluxes: a box reaches past the frame")
        m = (boxes[k, 1] - boxes[k, 0]) * (boxes[k, 3] - boxes[k, 2])
        if m > most:
            most = m
    buf = np.empty(max(most, 1), np.float32)
    for k in range(boxes.shape[0]):
        x0 = boxes[k, 0]; x1 = boxes[k, 1]; y0 = boxes[k, 2]; y1 = boxes[k, 3]
        if x1 <= x0 or y1 <= y0:
            out[k] = 0.0
            continue
        bg = <float>bgs[k]
        m = 0
        for y in range(y0, y1):
            for x in range(x0, x1):
                v = (<float>gray[y, x]) - bg
                buf[m] = v if v > 0.0 else 0.0
                m += 1
        out[k] = <double>((<float>0.0) + pw_sum(&buf[0], m))
