# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled envelope merge (receiver.vision.envelope), its one implementation (it saves over
5 % of a frame: docs/kernels.md): every tracked light's merged envelope of one frame in one call.

Per light: its own hull and its hulls of the previous frames (each moved by the light's velocity
times the frame gap, in float64, then rounded to float32), the convex hull of all those points
(`convex_hull_f32`: a monotone chain giving cv2.convexHull's vertices in its orientation and,
where its input order does not shift it, from its start vertex), the hull's centroid and area
(as receiver.vision.detect._hull_stats_many: Green's theorem plus the half-pixel rim) and its
box (floor of the float32 extremes, cv2.boundingRect of float points). `merge` returns None for
hulls it does not take (not (K, 2) float64). tests/engine/test_track_kernels.py checks the hull
against cv2.convexHull and the merged envelopes against OpenCV's hull of the moved points.
"""

from receiver.core._buf cimport fresh_data
from libc.math cimport floor, sqrt, hypot, fabs
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy
from cpython.buffer cimport (PyBUF_C_CONTIGUOUS, PyBUF_FORMAT, PyBUF_STRIDES, PyBUF_WRITABLE, PyBuffer_Release,
                             PyObject_CheckBuffer, PyObject_GetBuffer)
from receiver.core._npsum cimport pw_sum

import numpy as np

cdef double QUARTER_PI = 0.7853981633974483  # math.pi / 4.0


cdef inline unsigned int _bits(float f) noexcept nogil:
    cdef unsigned int u
    memcpy(&u, &f, 4)
    return u


cdef inline unsigned long long _key(float x, float y) noexcept nogil:
    """An integer whose order is the (x, y) order of finite floats (-0.0 as 0.0)."""
    cdef unsigned int ux = _bits(x + <float>0.0), uy = _bits(y + <float>0.0)
    # negative: all bits flipped, else the sign bit set (branch-free)
    ux ^= <unsigned int>(<int>ux >> 31) | 0x80000000u
    uy ^= <unsigned int>(<int>uy >> 31) | 0x80000000u
    return (<unsigned long long>ux << 32) | uy


cdef inline bint _less(const unsigned long long *key, int i, int j) noexcept nogil:
    """OpenCV's CHullCmpPoints but its last key: by x, then y (the input position, its last
    key, is kept by `_sort`'s stability)."""
    return key[i] < key[j]


cdef void _sort(const unsigned long long *key, int *a, int *tmp, int *bounds, int n) noexcept nogil:
    """Sort the positions a[0..n), given ascending, stably by `_less`: OpenCV's CHullCmpPoints
    order (x, y, then the input position: a total order, so any correct sort gives the order
    of OpenCV's std::sort). Insertion sort for short inputs, else a natural merge sort (the
    input is a few convex polygons: a few monotone runs each; only strictly descending runs
    are reversed and a merge takes the left run's point on a tie, so equal points stay in input
    order). bounds: n + 1 ints of work."""
    cdef int i, j, k, v, nr, r, lo, mid, hi, t
    if n < 24:
        for i in range(1, n):
            v = a[i]
            j = i - 1
            while j >= 0 and _less(key, v, a[j]):
                a[j + 1] = a[j]
                j -= 1
            a[j + 1] = v
        return
    nr = 0
    i = 0
    while i < n:
        j = i + 1
        if j < n and _less(key, a[j], a[j - 1]):
            while j < n and _less(key, a[j], a[j - 1]):
                j += 1
            lo = i
            hi = j - 1
            while lo < hi:
                t = a[lo]
                a[lo] = a[hi]
                a[hi] = t
                lo += 1
                hi -= 1
        else:
            while j < n and not _less(key, a[j], a[j - 1]):
                j += 1
        bounds[nr] = i
        nr += 1
        i = j
    bounds[nr] = n
    while nr > 1:
        r = 0
        while r + 1 < nr:
            lo = bounds[r]
            mid = bounds[r + 1]
            hi = bounds[r + 2]
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                if _less(key, a[j], a[i]):
                    tmp[k] = a[j]
                    j += 1
                else:
                    tmp[k] = a[i]
                    i += 1
                k += 1
            while i < mid:
                tmp[k] = a[i]
                i += 1
                k += 1
            while j < hi:
                tmp[k] = a[j]
                j += 1
                k += 1
            memcpy(a + lo, tmp + lo, (hi - lo) * sizeof(int))
            r += 2
        # runs 2q, 2q + 1 are now one
        k = 0
        r = 0
        while r < nr:
            bounds[k] = bounds[r]
            k += 1
            r += 2
        bounds[k] = n
        nr = k


cdef inline bint _turns_left(const float *X, const float *Y, int o, int a, int b) noexcept nogil:
    """The turn o -> a -> b of sorted points bends to positive x dy - y dx: the cross product of
    the float differences in double, a turn within 1e-7 of |oa| |ab| (relative) counted as
    straight, so nearly collinear points drop out as OpenCV's test on normalised float vectors
    drops them."""
    cdef double ax = <double>X[a] - X[o], ay = <double>Y[a] - Y[o]
    cdef double bx = <double>X[b] - X[a], by = <double>Y[b] - Y[a]
    cdef double cross = ax * by - ay * bx
    return cross > 0 and cross * cross > 1e-14 * ((ax * ax + ay * ay) * (bx * bx + by * by))


cdef int _hull(const float *P, int n, int *srt, int *tmp, int *stack, int *hullbuf,
               unsigned long long *key, float *X) noexcept nogil:
    """cv::convexHull(points, clockwise=false, returnPoints=true) of the n float points P
    (x, y interleaved): the hull's vertices as input positions into hullbuf; returns their
    number. Andrew's monotone chain over the points sorted as OpenCV sorts them (x, y, input
    position), repeated points once; the vertices in OpenCV's orientation from its start (the
    largest x, then y), then OpenCV's cyclic shift towards ascending or descending input
    positions where one exists. Work buffers: srt, tmp, key (n), stack (2 n + 4), X (2 n).
    Finite points only."""
    cdef float *Y = X + n
    cdef int i, j, k = 0, t, top, nout
    cdef int min_idx, max_idx, lt, idx, mmdist, ascending, i0, curr_idx, next_j, next_idx
    if n <= 0:
        return 0
    for i in range(n):
        srt[i] = i
        key[i] = _key(P[2 * i], P[2 * i + 1])
    _sort(key, srt, tmp, stack, n)
    for i in range(n):
        X[i] = P[2 * srt[i]]
        Y[i] = P[2 * srt[i] + 1]
    # the lower chain (sorted positions), then the upper one back
    for i in range(n):
        if i > 0 and key[srt[i]] == key[srt[i - 1]]:
            continue
        while k >= 2 and not _turns_left(X, Y, stack[k - 2], stack[k - 1], i):
            k -= 1
        stack[k] = i
        k += 1
    if k == 1:
        hullbuf[0] = srt[stack[0]]
        return 1
    top = k - 1  # the last sorted point: OpenCV's first vertex
    t = k + 1
    i = n - 2
    while i >= 0:
        if key[srt[i]] != key[srt[i + 1]]:
            while k >= t and not _turns_left(X, Y, stack[k - 2], stack[k - 1], i):
                k -= 1
            stack[k] = i
            k += 1
        i -= 1
    nout = k - 1  # the first point closes the chain
    for j in range(nout):
        hullbuf[j] = srt[stack[(top + j) % nout]]
    # the cyclic shift that makes the input positions ascending or descending, if one does
    if nout >= 3:
        min_idx = 0
        max_idx = 0
        lt = 0
        for i in range(1, nout):
            idx = hullbuf[i]
            lt += hullbuf[i - 1] < idx
            if lt > 1 and lt <= i - 2:
                break
            if idx < hullbuf[min_idx]:
                min_idx = i
            if idx > hullbuf[max_idx]:
                max_idx = i
        mmdist = max_idx - min_idx
        if mmdist < 0:
            mmdist = -mmdist
        if (mmdist == 1 or mmdist == nout - 1) and (lt <= 1 or lt >= nout - 2):
            ascending = (max_idx + 1) % nout == min_idx
            i0 = min_idx if ascending else max_idx
            j = i0
            if i0 > 0:
                i = 0
                while i < nout:
                    curr_idx = hullbuf[j]
                    stack[i] = curr_idx
                    next_j = j + 1 if j + 1 < nout else 0
                    next_idx = hullbuf[next_j]
                    if i < nout - 1 and (ascending != (curr_idx < next_idx)):
                        break
                    j = next_j
                    i += 1
                if i == nout:
                    memcpy(hullbuf, stack, nout * sizeof(int))
    return nout


def convex_hull_f32(const float[:, ::1] pts):
    """cv2.convexHull(pts) of (N, 2) float32 points as (M, 2) float32 (the equality tests'
    entry point)."""
    cdef int n = pts.shape[0], m, i
    cdef int *buf = <int *> malloc((5 * n + 8) * sizeof(int))
    cdef unsigned long long *key = <unsigned long long *> malloc((n + 1) * sizeof(unsigned long long))
    cdef float *xy = <float *> malloc((2 * n + 2) * sizeof(float))
    if buf == NULL or key == NULL or xy == NULL:
        free(buf)
        free(key)
        free(xy)
        raise MemoryError()
    try:
        m = _hull(&pts[0, 0] if n else NULL, n, buf, buf + n, buf + 2 * n, buf + 4 * n + 4, key, xy)
        out = [(pts[buf[4 * n + 4 + i], 0], pts[buf[4 * n + 4 + i], 1]) for i in range(m)]
    finally:
        free(buf)
        free(key)
        free(xy)
    return out


cdef void _stats(const double *x, const double *y, int m, double *tmp, double *out) noexcept nogil:
    """(cx, cy, area) of the closed polygon x, y (m vertices) as detect._hull_stats_many gives
    them: each per-vertex term summed as np.add.reduceat does (first + pairwise sum of the rest)."""
    cdef int i, j
    cdef double a2, sx, sy, perim, m00, xn, yn, c
    cdef double *cr = tmp
    cdef double *tx = tmp + m
    cdef double *ty = tmp + 2 * m
    cdef double *hp = tmp + 3 * m
    for i in range(m):
        j = i + 1 if i + 1 < m else 0
        xn = x[j]
        yn = y[j]
        c = x[i] * yn - xn * y[i]
        cr[i] = c
        tx[i] = (x[i] + xn) * c
        ty[i] = (y[i] + yn) * c
        hp[i] = hypot(xn - x[i], yn - y[i])
    a2 = cr[0] + pw_sum(cr + 1, m - 1)
    sx = tx[0] + pw_sum(tx + 1, m - 1)
    sy = ty[0] + pw_sum(ty + 1, m - 1)
    perim = hp[0] + pw_sum(hp + 1, m - 1)
    m00 = 0.5 * fabs(a2)
    if m00 <= 1e-6:
        out[0] = (x[0] + pw_sum(x + 1, m - 1)) / m
        out[1] = (y[0] + pw_sum(y + 1, m - 1)) / m
    else:
        out[0] = sx / (3.0 * a2)
        out[1] = sy / (3.0 * a2)
    out[2] = m00 + 0.5 * perim + QUARTER_PI


cdef extern from "Python.h":
    int PyObject_GenericSetDict(object o, object value, void *context) except -1

cdef extern from *:
    """
    /* object.__new__(type(src)) for a plain class (no __new__ of its own, not abstract): its
       tp_alloc, what object_new calls */
    static PyObject *occ_alloc_like(PyObject *src) {
        PyTypeObject *t = Py_TYPE(src);
        return t->tp_alloc(t, 0);
    }
    """
    object occ_alloc_like(object src)

cdef object _blob_like(object src, double cx, double cy, double area, object hull, long long x0, long long y0,
                       long long x1, long long y1, bint edge):
    """A copy of the Blob `src` with its geometry replaced, built from `src`'s attribute dict
    (what Blob(...) would hold, at a fraction of a frozen dataclass __init__'s cost):
    border = src.border or `edge`."""
    cdef dict d = (<dict> src.__dict__).copy()
    d["cx"] = cx
    d["cy"] = cy
    d["area_px"] = area
    d["hull"] = hull
    d["x0"] = x0
    d["y0"] = y0
    d["x1"] = x1
    d["y1"] = y1
    d["border"] = d["border"] or edge
    o = occ_alloc_like(src)
    PyObject_GenericSetDict(o, d, NULL)
    return o



cdef bint _f64_pairs(Py_buffer *b) noexcept:
    """`b` holds a (K, 2) float64 array (any strides)."""
    return (b.ndim == 2 and b.itemsize == 8 and b.format != NULL and b.format[0] == b'd' and b.format[1] == 0
            and b.shape[1] == 2)


cdef const void *_c_data(object o, int ndim, char kind, Py_ssize_t *n) except? NULL:
    """The data of a record's C-contiguous array (the record keeps it alive): int64 (kind 'q')
    of 1 dim or float64 ('d') pairs (n, 2); its length to n. ValueError for anything else."""
    cdef Py_buffer b
    cdef const char *fmt
    cdef bint ok
    PyObject_GetBuffer(o, &b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
    fmt = b.format
    if fmt == NULL:
        fmt = b"B"
    if fmt[0] == b'@' or fmt[0] == b'=' or fmt[0] == b'<':
        fmt += 1
    ok = (b.ndim == ndim and b.itemsize == 8 and fmt[0] != 0 and fmt[1] == 0 and
          (fmt[0] == b'd' if kind == b'd' else (fmt[0] == b'q' or fmt[0] == b'l')) and
          (ndim == 1 or b.shape[1] == 2))
    n[0] = b.shape[0] if b.ndim >= 1 else 0
    PyBuffer_Release(&b)
    if not ok:
        raise ValueError("merge: a record's ids / starts must be int64, its points (n, 2) float64")
    return b.buf


def merge(list tracks, long long k, list hist, long long width, long long height):
    """The merged envelopes of the n seen tracks (receiver.vision.envelope.EnvelopeHistory.step)
    and this frame's record for the next frames: (env {track id: Blob}, ids (n,) int64,
    starts (n + 1,) int64, points (sum K_i, 2) float64: the tracks' blob hulls in order, hulls
    [the blobs' hull arrays]); None when a blob's hull is not a (K, 2) float64 array (the
    caller raises). A track's Blob is its own blob when it has no earlier hull.

    k: this frame's index; hist: the earlier frames' records, oldest first, each (frame index,
    ids (m,) int64, starts (m + 1,) int64, points (., 2) float64, ...) as returned here (the
    caller passes only frames that count). A track's earlier hulls are moved by its velocity
    (vx, vy) px/frame times (k - frame). A merged track's Blob: its blob with cx, cy, area_px,
    hull (rows of one (rows, 2) float64 array), box and border replaced."""
    cdef int n = len(tracks), nh = len(hist), f, i, j, q, m, npts, maxpts = 0, a, b, total, nbuf = 0
    cdef long long o = 0, nout = 0
    cdef double dk, mx, my, x0f, y0f, x1f, y1f
    cdef long long x0, y0, x1, y1
    cdef float xv, yv
    cdef double st[3]
    cdef bint merged, edge
    cdef const char *hb
    cdef double *curp
    cdef double *outp = NULL
    cdef long long *ids
    cdef long long *cur_start
    cdef const long long *hid
    cdef Py_ssize_t nid, nst, npt
    cdef Py_buffer *bufs = <Py_buffer *> malloc((n + 1) * sizeof(Py_buffer))
    cdef long long *hk = <long long *> malloc((nh + 1) * sizeof(long long))
    cdef int *where = <int *> malloc((n * (nh + 1) + 1) * sizeof(int))
    cdef const double **hp = <const double **> malloc((nh + 1) * sizeof(double *))
    cdef const long long **hs = <const long long **> malloc((nh + 1) * sizeof(long long *))
    cdef double *vel = <double *> malloc((2 * n + 2) * sizeof(double))
    cdef float *P = NULL
    cdef int *ibuf = NULL
    cdef double *dbuf = NULL
    cdef unsigned long long *key = NULL
    if bufs == NULL or hk == NULL or where == NULL or hp == NULL or hs == NULL or vel == NULL:
        free(bufs); free(hk); free(where); free(hp); free(hs); free(vel)
        raise MemoryError()
    blobs = [None] * n
    hulls = [None] * n
    env = {}
    try:
        ids_arr = np.empty(n, np.int64)
        starts_arr = np.empty(n + 1, np.int64)
        ids = <long long *> fresh_data(ids_arr)
        cur_start = <long long *> fresh_data(starts_arr)
        cur_start[0] = 0
        for i in range(n):
            t = tracks[i]
            ids[i] = t.track_id
            vel[2 * i] = t.vx
            vel[2 * i + 1] = t.vy
            blob = t.blob
            blobs[i] = blob
            hull = blob.hull
            hulls[i] = hull
            if not PyObject_CheckBuffer(hull):
                return None
            PyObject_GetBuffer(hull, &bufs[i], PyBUF_STRIDES | PyBUF_FORMAT)
            nbuf += 1
            if not _f64_pairs(&bufs[i]):
                return None
            cur_start[i + 1] = cur_start[i] + bufs[i].shape[0]
        # this frame's points, in order (the record's)
        cur_arr = np.empty((cur_start[n], 2))
        curp = fresh_data(cur_arr)
        for i in range(n):
            hb = <const char *> bufs[i].buf
            a = <int>cur_start[i]
            for j in range(<int>bufs[i].shape[0]):
                curp[2 * (a + j)] = (<const double *>(hb + j * bufs[i].strides[0]))[0]
                curp[2 * (a + j) + 1] = (<const double *>(hb + j * bufs[i].strides[0] + bufs[i].strides[1]))[0]
        nout = cur_start[n]
        # each light's row in each earlier frame (or -1), and its number of points
        for f in range(nh):
            rec = hist[f]
            kh = rec[0]
            hk[f] = kh
            hid = <const long long *> _c_data(rec[1], 1, b'q', &nid)
            hs[f] = <const long long *> _c_data(rec[2], 1, b'q', &nst)
            hp[f] = <const double *> _c_data(rec[3], 2, b'd', &npt)
            m = <int>nid
            if nst != nid + 1:
                raise ValueError("merge: a record's starts must have len(ids) + 1 entries")
            nout += npt
            q = 0
            for i in range(n):
                where[i * nh + f] = -1
                # ids of both frames come in the tracker's order: scan on from the last match
                for j in range(m):
                    a = (q + j) % m
                    if hid[a] == ids[i]:
                        where[i * nh + f] = a
                        q = a + 1
                        break
        out = np.empty((nout, 2))
        outp = fresh_data(out)
        npts = 0
        for i in range(n):
            npts = <int>(cur_start[i + 1] - cur_start[i])
            for f in range(nh):
                if where[i * nh + f] >= 0:
                    a = where[i * nh + f]
                    npts += <int>(hs[f][a + 1] - hs[f][a])
            if npts > maxpts:
                maxpts = npts
        P = <float *> malloc((4 * maxpts + 4) * sizeof(float))
        ibuf = <int *> malloc((5 * maxpts + 8) * sizeof(int))
        dbuf = <double *> malloc((6 * maxpts + 8) * sizeof(double))
        key = <unsigned long long *> malloc((maxpts + 1) * sizeof(unsigned long long))
        if P == NULL or ibuf == NULL or dbuf == NULL or key == NULL:
            raise MemoryError()
        for i in range(n):
            merged = False
            total = 0
            a = <int>cur_start[i]
            b = <int>cur_start[i + 1]
            for j in range(a, b):
                P[2 * total] = <float>curp[2 * j]
                P[2 * total + 1] = <float>curp[2 * j + 1]
                total += 1
            for f in range(nh):
                q = where[i * nh + f]
                if q < 0:
                    continue
                merged = True
                dk = <double>(k - hk[f])
                mx = vel[2 * i] * dk
                my = vel[2 * i + 1] * dk
                for j in range(<int>hs[f][q], <int>hs[f][q + 1]):
                    P[2 * total] = <float>(hp[f][2 * j] + mx)
                    P[2 * total + 1] = <float>(hp[f][2 * j + 1] + my)
                    total += 1
            if not merged or total == 0:
                continue
            if o + total > nout:
                raise ValueError("merge: `out` has too few rows")
            m = _hull(P, total, ibuf, ibuf + total, ibuf + 2 * total, ibuf + 4 * total + 4, key, P + 2 * maxpts + 2)
            x0f = x1f = P[2 * ibuf[4 * total + 4]]
            y0f = y1f = P[2 * ibuf[4 * total + 4] + 1]
            for j in range(m):
                q = ibuf[4 * total + 4 + j]
                xv = P[2 * q]
                yv = P[2 * q + 1]
                outp[2 * (o + j)] = xv
                outp[2 * (o + j) + 1] = yv
                dbuf[j] = xv
                dbuf[maxpts + j] = yv
                if xv < x0f:
                    x0f = xv
                if xv > x1f:
                    x1f = xv
                if yv < y0f:
                    y0f = yv
                if yv > y1f:
                    y1f = yv
            _stats(dbuf, dbuf + maxpts, m, dbuf + 2 * maxpts, st)
            x0 = <long long>floor(x0f)
            y0 = <long long>floor(y0f)
            x1 = <long long>floor(x1f) + 1
            y1 = <long long>floor(y1f) + 1
            edge = x0 <= 0 or y0 <= 0 or x1 >= width or y1 >= height
            blobs[i] = _blob_like(blobs[i], st[0], st[1], st[2], out[o:o + m], x0 if x0 > 0 else 0,
                                  y0 if y0 > 0 else 0, x1 if x1 < width else width, y1 if y1 < height else height, edge)
            o += m
        for i in range(n):
            env[ids[i]] = blobs[i]
    finally:
        for i in range(nbuf):
            PyBuffer_Release(&bufs[i])
        free(bufs); free(hk); free(where); free(hp); free(hs); free(P); free(ibuf); free(dbuf); free(key); free(vel)
    return env, ids_arr, starts_arr, cur_arr, hulls
