# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Kept: a numpy path of this glue costs 8.3 % more instructions per whole frame on synthetic (docs/kernels.md).
"""Compiled per-frame glue of the indoor positioner: one call per frame instead of a
dozen numpy calls on 16 small arrays.

* `cut_by_edge`: `Ranger._touching_edge` -- does each envelope come within the margin of the
  image edge (a NaN coordinate compares False, as numpy's min / max propagate it)?
* `pack_outline`: the arrays of `Positioner._outline_targets` -- every target's edge points and
  the centroids in one (M + T, 2) array, each point's sigma (hypot with the model's, over the
  focal length: libm's hypot, as np.hypot), the point ranges, centres and half extents.
The small arrays are read through the buffer protocol directly (a typed memoryview per array
costs ~2.5 k instructions, a frame has 16-32 of them). The one implementation of these steps
(receiver/locate/ranging.py and indoor.py convert other inputs to float64 arrays first), tested
against their definitions, known truth and OpenCV (tests/engine/test_glue_kernels.py).
"""

from cpython.buffer cimport PyBUF_C_CONTIGUOUS, PyBUF_FORMAT, PyBuffer_Release, PyObject_GetBuffer
from libc.math cimport hypot, isnan
from receiver.core._buf cimport fresh_data
from receiver.core._pyround cimport py_round

import numpy as np


cdef const double* f64(object o, Py_buffer* b, int ndim, Py_ssize_t cols) except NULL:
    """The data of a C-contiguous native float64 array of `ndim` dims (`cols` columns when 2-D);
    ValueError (buffer released) otherwise. The caller releases `b`."""
    PyObject_GetBuffer(o, b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
    if (b.ndim != ndim or b.itemsize != 8 or b.format == NULL or b.format[0] != b'd' or b.format[1] != 0
            or (ndim == 2 and b.shape[1] != cols)):
        PyBuffer_Release(b)
        raise ValueError("expected a C-contiguous float64 array")
    return <const double*>b.buf


def cut_by_edge(list contours, double margin, double x_max, double y_max):
    """[bool] per contour ((K, 2) float64 C-contiguous, or None): its smallest x or y <= margin,
    or its largest x >= x_max or y >= y_max (x_max = width - 1 - margin). None or empty: False."""
    cdef Py_buffer b
    cdef const double* c
    cdef Py_ssize_t i, j, k, n = len(contours)
    cdef double lox, loy, hix, hiy, x, y
    cdef bint nanx, nany
    out = [False] * n
    for i in range(n):
        obj = contours[i]
        if obj is None:
            continue
        c = f64(obj, &b, 2, 2)
        k = b.shape[0]
        if k > 0:
            lox = hix = c[0]
            loy = hiy = c[1]
            nanx = isnan(lox)
            nany = isnan(loy)
            for j in range(1, k):
                x = c[2 * j]
                y = c[2 * j + 1]
                if x < lox:
                    lox = x
                elif x > hix:
                    hix = x
                if y < loy:
                    loy = y
                elif y > hiy:
                    hiy = y
                nanx = nanx or isnan(x)
                nany = nany or isnan(y)
            out[i] = (not nanx and (lox <= margin or hix >= x_max)) or (not nany and (loy <= margin or hiy >= y_max))
        PyBuffer_Release(&b)
    return out


# A frame's edge-point sigmas take a few values (most are clamped at the floor of
# receiver.vision.outline): the last distinct ones and their hypot are kept (libm's hypot, ~100
# instructions, is most of the packing; a pure function, so a kept value is the same bits).
cdef enum:
    SIGMA_MEMO = 8


cdef inline double _sigma_of(double s, double model_sigma, double focal, double* memo, int* n_memo) noexcept nogil:
    """hypot(s, model_sigma) / focal, looked up in `memo` ((s, result) pairs, n_memo[0] of them,
    the newest overwriting the oldest) before it is computed."""
    cdef int i
    cdef double out
    for i in range(n_memo[0] if n_memo[0] < SIGMA_MEMO else SIGMA_MEMO):
        if memo[2 * i] == s:
            return memo[2 * i + 1]
    out = hypot(s, model_sigma) / focal
    i = n_memo[0] % SIGMA_MEMO
    memo[2 * i] = s
    memo[2 * i + 1] = out
    n_memo[0] += 1
    return out


def pack_outline(list chosen, double model_sigma, double focal):
    """(pts (M + T, 2), sigma (M,), ends (T + 1,) int64, xyz (T, 3), half (T, 2)) of the frame's
    targets `chosen`: T (observation, (points (N_k, 2), sigma (N_k,)) float64 C-contiguous,
    (led, (hx, hy), (x, y, z))). `pts`: every target's points in turn, then the T centroids
    (cx, cy); `sigma`: hypot(sigma_px, model_sigma) / focal; `ends[k]`: where target k starts."""
    cdef Py_buffer bp, bs
    cdef const double* P
    cdef const double* S
    cdef double* pv
    cdef double* sv
    cdef double* xv
    cdef double* hv
    cdef Py_ssize_t t, j, k, a = 0, n = len(chosen), m = 0
    cdef double memo[2 * SIGMA_MEMO]
    cdef int n_memo = 0
    for t in range(n):
        m += len(chosen[t][1][0])
    pts = np.empty((m + n, 2))
    sigma = np.empty(m)
    xyz = np.empty((n, 3))
    half = np.empty((n, 2))
    pv, sv, xv, hv = fresh_data(pts), fresh_data(sigma), fresh_data(xyz), fresh_data(half)
    ends = [0] * (n + 1)
    for t in range(n):
        o, e, fx = chosen[t]
        P = f64(e[0], &bp, 2, 2)
        try:
            S = f64(e[1], &bs, 1, 0)
            try:
                k = bp.shape[0]
                if bs.shape[0] != k or a + k > m:
                    raise ValueError("pack_outline: edge points and sigmas do not match")
                for j in range(k):
                    pv[2 * (a + j)] = P[2 * j]
                    pv[2 * (a + j) + 1] = P[2 * j + 1]
                    sv[a + j] = _sigma_of(S[j], model_sigma, focal, memo, &n_memo)
            finally:
                PyBuffer_Release(&bs)
        finally:
            PyBuffer_Release(&bp)
        a += k
        ends[t + 1] = a
        pv[2 * (m + t)] = o.cx
        pv[2 * (m + t) + 1] = o.cy
        _, h, X = fx
        hv[2 * t], hv[2 * t + 1] = h
        xv[3 * t], xv[3 * t + 1], xv[3 * t + 2] = X
    if a != m:
        raise ValueError("pack_outline: edge points and sigmas do not match")
    return pts, sigma, np.array(ends, np.int64), xyz, half


def polygon_sums(poly, bint perimeter):
    """(sum of cross products x_i y_j - x_j y_i, perimeter or 0.0, sum (x_i + x_j) cross_i,
    sum (y_i + y_j) cross_i) of a closed (K >= 1, 2) float64 C-contiguous polygon (j = i + 1
    mod K): `ranging.polygon_area_perimeter` / `polygon_centroid`'s sums, in one pass."""
    cdef Py_buffer b
    cdef const double* p = f64(poly, &b, 2, 2)
    cdef Py_ssize_t i, j, k = b.shape[0]
    cdef double c, s_cross = 0.0, s_per = 0.0, s_x = 0.0, s_y = 0.0
    try:
        for i in range(k):
            j = i + 1 if i + 1 < k else 0
            c = p[2 * i] * p[2 * j + 1] - p[2 * j] * p[2 * i + 1]
            s_cross += c
            s_x += (p[2 * i] + p[2 * j]) * c
            s_y += (p[2 * i + 1] + p[2 * j + 1]) * c
            if perimeter:
                s_per += hypot(p[2 * j] - p[2 * i], p[2 * j + 1] - p[2 * i + 1])
    finally:
        PyBuffer_Release(&b)
    return s_cross, s_per, s_x, s_y


cdef extern from "Python.h":
    int PyObject_GenericSetAttr(object o, object name, object value) except -1
    dict PyDict_Copy(object d)


def annotate(list leds, list items, list d, list names, object record, object slow):
    """`Ranger.annotate`: `leds` with the finite ranges of `items` ((observation, ...) each; d:
    their ranges, m, as Python floats; names: their estimators; taken pairwise as zip does) rounded as round(v, 5) (receiver/core/_pyround.pxd) and set
    by `with_ranges`; a list copy of `leds` when none is finite."""
    cdef Py_ssize_t i, n = min(len(items), len(d), len(names))   # (as zip)
    cdef double v
    ranged = {}
    for i in range(n):
        v = d[i]
        if v - v == 0.0:  # finite
            ranged[id(items[i][0])] = (py_round(v, 5), names[i])
    if not ranged:
        return list(leds)
    return with_ranges(leds, ranged, record, slow)


def with_ranges(list leds, dict ranged, object record, object slow):
    """`Ranger.annotate`'s copies: each observation whose id(obs) is in `ranged` ({id: (distance_m,
    estimator)}) copied with the two fields set -- for a `record` instance its field dict copied
    and set as the new instance's dict (no generated __init__), anything else by `slow(obs, d,
    name)` -- the others as they are."""
    cdef Py_ssize_t i, n = len(leds)
    out = [None] * n
    for i in range(n):
        o = leds[i]
        r = ranged.get(id(o))
        if r is None:
            out[i] = o
        elif type(o) is record:
            d = PyDict_Copy(o.__dict__)
            d["distance_m"] = (<tuple>r)[0]
            d["distance_estimator"] = (<tuple>r)[1]
            new = record.__new__(record)
            PyObject_GenericSetAttr(new, "__dict__", d)
            out[i] = new
        else:
            out[i] = slow(o, (<tuple>r)[0], (<tuple>r)[1])
    return out
