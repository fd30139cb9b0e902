# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Tracker step (receiver.vision.track.Tracker.step), its one implementation: the gated
assignment of all tracks x blobs and the assigned tracks' updates in one call per frame
(predicted centroid cx + vx dt plus the accumulated shift since the track's blob, distance by
hypot, gate gate_px + gate_size sqrt(area), area ratio bounds; the velocity blend). The
assignment: the gated pairs themselves when no track and no blob has two, else the solver the
caller passes (scipy's, `receiver.vision.track._solver_assignment`) on the same costs.
tests/engine/test_track_kernels.py checks it on streams where each light is known.
"""

from libc.math cimport sqrt, hypot, fabs, isfinite
from libc.stdlib cimport malloc, free

import numpy as np

from receiver.core.records import Blob


cdef inline double _max1(double a) noexcept nogil:
    """np.maximum(a, 1.0) (NaN stays NaN)."""
    return a if (a >= 1.0 or a != a) else 1.0


def step(list tracks, list blobs, long long frame_index, double sx, double sy, object shift_sum,
         bint shifted, double gate_px, double gate_size, double max_area_ratio, double velocity_gain,
         long long max_missed, object solver):
    """Assign the blobs to the tracks and update the tracks (in place): returns (alive tracks,
    ended tracks, used: bytearray, 1 per blob that went to a track). The caller adds a new track
    per unused blob.

    Each track's and blob's fields are read once (the update reuses them); a pair whose x or y
    offset alone exceeds the gate is out without its hypot (hypot(dx, dy) >= |dx|, |dy|: the
    same decision), and the solver's distances are all computed when it is needed."""
    cdef Py_ssize_t T = len(tracks), B = len(blobs), i, j
    cdef double *bx = NULL
    cdef double *tx = NULL
    cdef unsigned char *ok = NULL
    cdef long long *lastf = NULL
    cdef int *row_of = NULL
    cdef int *rcount = NULL
    cdef int *ccount = NULL
    cdef double px, py, tarea, gate, ratio, inv = 1.0 / max_area_ratio, g, dt, ox, oy, dx, dy, dd
    cdef double *tr
    cdef bint unique = True
    cdef double[:, ::1] dv
    cdef unsigned char[:, ::1] ov
    cdef long long dti
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
            # per track: predicted x, y, max(area, 1), gate, blob cx, cy, vx, vy, shift0 x, y
            tx = <double *> malloc(10 * T * sizeof(double))
            lastf = <long long *> malloc(T * sizeof(long long))
            ok = <unsigned char *> malloc(T * B)
            rcount = <int *> malloc(T * sizeof(int))
            ccount = <int *> malloc(B * sizeof(int))
            if bx == NULL or tx == NULL or lastf == NULL or ok == NULL or rcount == NULL or ccount == NULL:
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
                tr = tx + 10 * i
                lastf[i] = t.last_frame
                dt = <double>(frame_index - lastf[i])
                tr[4] = tb.cx
                tr[5] = tb.cy
                tr[6] = t.vx
                tr[7] = t.vy
                s0 = t.shift0
                tr[8] = s0[0]
                tr[9] = s0[1]
                px = tr[4] + tr[6] * dt
                py = tr[5] + tr[7] * dt
                if shifted:
                    px = px + (sx - tr[8])
                    py = py + (sy - tr[9])
                tr[0] = px
                tr[1] = py
                tarea = _max1(tb.area_px)
                tr[2] = tarea
                tr[3] = gate_px + gate_size * sqrt(tarea)
            for i in range(T):
                rcount[i] = 0
                tr = tx + 10 * i
                px = tr[0]
                py = tr[1]
                tarea = tr[2]
                gate = tr[3]
                for j in range(B):
                    ok[i * B + j] = 0
                    dx = bx[3 * j] - px
                    dy = bx[3 * j + 1] - py
                    if fabs(dx) > gate or fabs(dy) > gate:
                        continue
                    ratio = bx[3 * j + 2] / tarea
                    if hypot(dx, dy) <= gate and ratio <= max_area_ratio and ratio >= inv:
                        ok[i * B + j] = 1
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
                        dv[i, j] = hypot(bx[3 * j] - tx[10 * i], bx[3 * j + 1] - tx[10 * i + 1])
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
                tr = tx + 10 * i
                dti = frame_index - lastf[i]
                if dti < 1:
                    dti = 1
                g = velocity_gain if t.hits > 1 else 1.0
                ox = sx - tr[8]
                oy = sy - tr[9]
                t.vx = (1 - g) * tr[6] + g * (bx[3 * j] - tr[4] - ox) / <double>dti
                t.vy = (1 - g) * tr[7] + g * (bx[3 * j + 1] - tr[5] - oy) / <double>dti
                t.blob = blobs[j]
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
        free(bx); free(tx); free(lastf); free(ok); free(row_of); free(rcount); free(ccount)
    return alive, ended, used


def led_records(list seen, list lights, dict env, object pair_of, object covered, set decoded, bint locate,
                bint tones, type cls):
    """The seen tracks' LED observations of one frame (receiver.pipeline.Receiver._report), in
    one call: (records in track order, `want`: the track ids whose outline points the positioner
    gets, `want_fields`: the `__dict__` of each one's record, None when it is not reported).
    Tracks of an S2-PSK pair (`pair_of`), near a reported pair (`covered`) or not striped give no
    record; each record's ID goes into `decoded`. `tones`: the map has tone lights (else freq_hz
    is None; a finite frequency is rounded to 0.1 Hz). Records are `cls` instances whose
    `__dict__` is filled in place (edge_px, None here, is set once measured)."""
    cdef Py_ssize_t i, n = len(seen)
    cdef list leds = [], want = [], want_fields = []
    cdef dict fields, bd
    cdef double f
    if len(lights) != n:
        raise ValueError("one light per seen track")
    for i in range(n):
        t = seen[i]
        light = lights[i]
        tid = t.track_id
        if tid in pair_of or not light.striped:
            continue
        led_id = light.led_id
        fields = None
        if tid not in covered:
            b = env[tid]
            if type(b) is Blob:  # a record's fields are its __dict__: read there, not by getattr
                bd = b.__dict__
                cx, cy, area, hull, border, peak = bd["cx"], bd["cy"], bd["area_px"], bd["hull"], bd["border"], bd["peak"]
            else:
                cx, cy, area, hull, border, peak = b.cx, b.cy, b.area_px, b.hull, b.border, b.peak
            freq = None
            if tones and light.states:
                fo = light.freq_hz
                f = fo
                if isfinite(f):
                    freq = round(fo, 1)
            o = cls.__new__(cls)
            fields = o.__dict__
            fields["track"] = tid
            fields["cx"] = cx
            fields["cy"] = cy
            fields["area_px"] = area
            fields["contour"] = hull
            fields["border"] = border
            fields["id"] = led_id
            fields["mode"] = light.mode
            fields["peak"] = peak
            fields["distance_m"] = None
            fields["distance_estimator"] = None
            fields["freq_hz"] = freq
            fields["kind"] = None
            fields["edge_px"] = None
            leds.append(o)
            if led_id is not None:
                decoded.add(led_id)
        if locate and led_id is not None and light.mode != "s2psk":
            want.append(tid)
            want_fields.append(fields)
    return leds, want, want_fields
