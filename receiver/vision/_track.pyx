# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled tracker step (receiver.vision.track.Tracker.step): the gated assignment of all
tracks x blobs and the assigned tracks' updates in one call per frame.

The pure reference is `Tracker._step_pure`; this does the same arithmetic in the same order
(predicted centroid cx + vx dt plus the accumulated shift since the track's blob, distance by
hypot, gate gate_px + gate_size sqrt(area), area ratio bounds; the velocity blend), and the same
assignment: the gated pairs themselves when no track and no blob has two, else the solver the
caller passes (scipy's, `receiver.vision.track._solver_assignment`) on the same costs.
tests/test_track_kernels.py runs both on the same streams and asserts equal tracks.
"""

from libc.math cimport sqrt, hypot
from libc.stdlib cimport malloc, free

import numpy as np


cdef inline double _max1(double a) noexcept nogil:
    """np.maximum(a, 1.0) (NaN stays NaN)."""
    return a if (a >= 1.0 or a != a) else 1.0


def step(list tracks, list blobs, long long frame_index, double sx, double sy, object shift_sum,
         bint shifted, double gate_px, double gate_size, double max_area_ratio, double velocity_gain,
         long long max_missed, object solver):
    """Assign the blobs to the tracks and update the tracks (in place): returns (alive tracks,
    ended tracks, used: bytearray, 1 per blob that went to a track). The caller adds a new track
    per unused blob."""
    cdef Py_ssize_t T = len(tracks), B = len(blobs), i, j, n_ok
    cdef double *bx = NULL
    cdef double *tx = NULL
    cdef double *d = NULL
    cdef unsigned char *ok = NULL
    cdef int *row_of = NULL
    cdef int *rcount = NULL
    cdef int *ccount = NULL
    cdef double px, py, tarea, gate, ratio, inv = 1.0 / max_area_ratio, g, dt, ox, oy
    cdef bint unique = True
    cdef double[:, ::1] dv
    cdef unsigned char[:, ::1] ov
    cdef long long last, dti
    used = bytearray(B)
    alive = []
    ended = []
    try:
        row_of = <int *> malloc((T + 1) * sizeof(int))
        if row_of == NULL:
            raise MemoryError()
        for i in range(T):
            row_of[i] = -1
        if T and B:
            bx = <double *> malloc(3 * B * sizeof(double))
            tx = <double *> malloc(4 * T * sizeof(double))
            d = <double *> malloc(T * B * sizeof(double))
            ok = <unsigned char *> malloc(T * B)
            rcount = <int *> malloc(T * sizeof(int))
            ccount = <int *> malloc(B * sizeof(int))
            if bx == NULL or tx == NULL or d == NULL or ok == NULL or rcount == NULL or ccount == NULL:
                raise MemoryError()
            for j in range(B):
                b = blobs[j]
                bx[3 * j] = b.cx
                bx[3 * j + 1] = b.cy
                bx[3 * j + 2] = _max1(b.area_px)
                ccount[j] = 0
            for i in range(T):
                t = tracks[i]
                tb = t.blob
                dt = <double>(frame_index - <long long>t.last_frame)
                px = <double>tb.cx + <double>t.vx * dt
                py = <double>tb.cy + <double>t.vy * dt
                if shifted:
                    s0 = t.shift0
                    px = px + (sx - <double>s0[0])
                    py = py + (sy - <double>s0[1])
                tx[4 * i] = px
                tx[4 * i + 1] = py
                tarea = _max1(tb.area_px)
                tx[4 * i + 2] = tarea
                tx[4 * i + 3] = gate_px + gate_size * sqrt(tarea)
            for i in range(T):
                rcount[i] = 0
                px = tx[4 * i]
                py = tx[4 * i + 1]
                tarea = tx[4 * i + 2]
                gate = tx[4 * i + 3]
                for j in range(B):
                    d[i * B + j] = hypot(bx[3 * j] - px, bx[3 * j + 1] - py)
                    ratio = bx[3 * j + 2] / tarea
                    ok[i * B + j] = d[i * B + j] <= gate and ratio <= max_area_ratio and ratio >= inv
                    if ok[i * B + j]:
                        rcount[i] += 1
                        ccount[j] += 1
                        row_of[i] = <int>j
                if rcount[i] > 1:
                    unique = False
            for j in range(B):
                if ccount[j] > 1:
                    unique = False
            if not unique:
                dn = np.empty((T, B))
                okn = np.empty((T, B), np.uint8)
                dv = dn
                ov = okn
                for i in range(T):
                    for j in range(B):
                        dv[i, j] = d[i * B + j]
                        ov[i, j] = ok[i * B + j] != 0
                for i in range(T):
                    row_of[i] = -1
                for r, c in solver(dn, okn.view(bool)).items():
                    row_of[<Py_ssize_t>r] = <int>c
        for i in range(T):
            t = tracks[i]
            if row_of[i] >= 0:
                j = row_of[i]
                used[j] = 1
                b = blobs[j]
                tb = t.blob
                last = t.last_frame
                dti = frame_index - last
                if dti < 1:
                    dti = 1
                g = velocity_gain if t.hits > 1 else 1.0
                s0 = t.shift0
                ox = sx - <double>s0[0]
                oy = sy - <double>s0[1]
                t.vx = (1 - g) * <double>t.vx + g * (<double>b.cx - <double>tb.cx - ox) / <double>dti
                t.vy = (1 - g) * <double>t.vy + g * (<double>b.cy - <double>tb.cy - oy) / <double>dti
                t.blob = b
                t.last_frame = frame_index
                t.seen = True
                t.shift0 = shift_sum
                t.hits += 1
                t.misses = 0
                alive.append(t)
            else:
                t.seen = False
                t.misses += 1
                (alive if t.misses <= max_missed else ended).append(t)
    finally:
        free(bx); free(tx); free(d); free(ok); free(row_of); free(rcount); free(ccount)
    return alive, ended, used
