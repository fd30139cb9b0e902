# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Kept: without it the lighting server spends about 6 % more CPU per reply (docs/kernels.md).
"""Compiled check of a decoded request in its common form, for the lighting server
(`receiver.serve.wire.parse_request(..., fast=)`): every field present with its plain JSON type
(float numbers, int IDs, no centroid keys) and in its range -- the checks of `wire._parse_body` /
`wire._parse_led_fast`, as comparisons in C. Anything else gives None and the Python parser
decides, with its reason and detail (tests: both accept the same requests with the same values).
"""

import numpy as np

from receiver.core._buf cimport store
from receiver.serve.wire import (DISTANCE_RANGE_M, MAX_ABS_T_S, MAX_ABS_UV, MAX_DEVICE_CHARS, MAX_LED_ID, MAX_LEDS,
                                 MAX_SEQ, SIGMA_M_RANGE, SIGMA_UV_RANGE)

cdef double D_LO = DISTANCE_RANGE_M[0], D_HI = DISTANCE_RANGE_M[1]
cdef double S_LO = SIGMA_M_RANGE[0], S_HI = SIGMA_M_RANGE[1]
cdef double UV_LO = SIGMA_UV_RANGE[0], UV_HI = SIGMA_UV_RANGE[1]
cdef double T_MAX = MAX_ABS_T_S, UV_MAX = MAX_ABS_UV
cdef Py_ssize_t N_MAX = MAX_LEDS, DEVICE_MAX = MAX_DEVICE_CHARS
cdef object SEQ_MAX = MAX_SEQ, ID_MAX = MAX_LED_ID


cdef inline bint _in(object v, double lo, double hi):
    """v a float (not an int, not a bool) with lo <= v <= hi (False for NaN)."""
    if type(v) is not float:
        return False
    cdef double f = v
    return lo <= f <= hi


def parse(dict obj):
    """(device, seq, t, sigma_uv, ids, rows) of a request object in the common form -- rows an
    (n, 4) float64 array of u, v, distance_m, sigma_m -- or None (then `wire` checks it)."""
    cdef double buf[4 * 64]
    cdef Py_ssize_t n, k
    cdef dict item
    device = obj.get("device")
    if type(device) is not str or not 1 <= len(<str>device) <= DEVICE_MAX:
        return None
    seq = obj.get("seq")
    if type(seq) is not int or not 0 <= seq <= SEQ_MAX:
        return None
    t, sigma_uv, leds = obj.get("t"), obj.get("sigma_uv"), obj.get("leds")
    if not _in(t, -T_MAX, T_MAX) or not _in(sigma_uv, UV_LO, UV_HI) or type(leds) is not list:
        return None
    n = len(<list>leds)
    if n > N_MAX or n > 64:
        return None
    camera = obj.get("camera", None)
    if camera is not None and type(camera) is not dict or "camera" in obj and camera is None:
        return None
    ids = []
    for k in range(n):
        it = (<list>leds)[k]
        if type(it) is not dict:
            return None
        item = <dict>it
        if "cx" in item or "cy" in item:
            return None
        led_id, u, v = item.get("id"), item.get("u"), item.get("v")
        d, sd = item.get("distance_m"), item.get("sigma_m")
        if (type(led_id) is not int or not 0 <= led_id <= ID_MAX or not _in(u, -UV_MAX, UV_MAX)
                or not _in(v, -UV_MAX, UV_MAX) or not _in(d, D_LO, D_HI) or not _in(sd, S_LO, S_HI)):
            return None
        ids.append(led_id)
        buf[4 * k] = u
        buf[4 * k + 1] = v
        buf[4 * k + 2] = d
        buf[4 * k + 3] = sd
    ids = tuple(ids)
    if len(set(ids)) != n:
        return None
    rows = np.empty((n, 4))
    store(rows, buf, 64, 4)
    return device, seq, t, sigma_uv, ids, rows
