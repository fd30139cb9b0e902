# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled `position` object of the lighting server's replies (`receiver.serve.devices`): the
dict `receiver.serve.devices.position_object` builds (and `PoseFilter.update` before it), with its
numbers rounded in C instead of ~40 Python-level `round` calls, each a decimal conversion there.

Equal to the Python builder by construction (tests compare both):
* Python's `round(v, n)` (the double nearest to v's correctly rounded n-decimal value) is
  rint(v * 10^n) / 10^n wherever v * 10^n, as computed, is below 1e9 in magnitude and at least
  1e-6 away from a half-integer: then the computed product is within 1.2e-7 of the exact one and
  rounds to the same integer, and the division (both operands exact) is correctly rounded. Any
  other value (near a tie, large, not finite) is handed to Python's `round`.
* numpy's `round` (`ndarray.round`) is rint(v * 10^n) / 10^n by definition.
* yaw / pitch / roll: `devices.ypr_deg` with the C library's asin / cos / atan2 (what Python's
  math module calls) and math.degrees' factor 180 / pi.
"""

from libc.math cimport asin, atan2, cos, fabs, floor, isfinite, rint, sqrt

from receiver.serve._buf cimport load

cdef double RAD_TO_DEG = 180.0 / 3.14159265358979323846   # CPython's math.degrees factor
cdef double POW10[9]
for _n in range(9):
    POW10[_n] = 10.0 ** _n                                  # exact


cdef object _py_round(double v, int n):
    """Python's round(v, n)."""
    cdef double y = v * POW10[n]
    cdef double f
    if isfinite(y) and fabs(y) < 1e9:
        f = y - floor(y)
        if fabs(f - 0.5) > 1e-6:
            return rint(y) / POW10[n]
    return round(v, n)


cdef inline double _np_round(double v, int n) noexcept:
    """numpy's round(v, n)."""
    return rint(v * POW10[n]) / POW10[n]


cdef inline double _clip_max0(double v) noexcept:
    """Python's max(0.0, v)."""
    return v if v > 0.0 else 0.0


cdef dict _xyz(double* v):
    return {"x": _py_round(v[0], 5), "y": _py_round(v[1], 5), "z": _py_round(v[2], 5)}


cdef list _std(double* cov, int stride):
    return [_py_round(sqrt(_clip_max0(cov[i * stride + i])), 5) for i in range(3)]


def position(x, P, C, cov, R, str method, int n_leds, handedness):
    """`devices.position_object`: x (6,) and P (6, 6) the filter state (both None without a
    track); C (3,), cov (3, 3) and R (3, 3) or None of the frame's fix (C None: no fix); method
    its `method` (or "kalman-coast"); handedness the map's, or None while undecided."""
    cdef double xb[6]
    cdef double Pb[36]
    cdef double Cb[3]
    cdef double covb[9]
    cdef double Rb[9]
    cdef double theta, yaw, roll, s
    cdef int i
    cdef dict pos
    if x is not None:
        load(x, xb, 6, 0)
        load(P, Pb, 6, 6)
        pos = _xyz(xb)
        pos["method"] = method
        pos["n_leds"] = n_leds
        pos["filtered"] = True
        pos["std_m"] = _std(Pb, 6)
        pos["cov"] = [[_np_round(Pb[6 * i + j], 8) for j in range(3)] for i in range(3)]
        pos["velocity_mps"] = [_py_round(xb[3 + i], 4) for i in range(3)]
    else:
        load(C, Cb, 3, 0)
        pos = _xyz(Cb)
        pos["method"] = method
        pos["n_leds"] = n_leds
        pos["filtered"] = False
    if C is not None:
        load(C, Cb, 3, 0)
        load(cov, covb, 3, 3)
        pos["raw"] = _xyz(Cb)
        pos["raw_std_m"] = _std(covb, 3)
        if R is not None:
            load(R, Rb, 3, 3)
            pos["R_wc"] = [[_np_round(Rb[3 * j + i], 6) for j in range(3)] for i in range(3)]
            s = -Rb[8]                                       # max(-1.0, min(1.0, -R[2][2]))
            s = s if s < 1.0 else 1.0
            s = s if s > -1.0 else -1.0
            theta = asin(s)
            if fabs(cos(theta)) < 1e-6:
                yaw, roll = atan2(Rb[0], -Rb[1]), 0.0
            else:
                yaw, roll = atan2(Rb[7], Rb[6]), atan2(-Rb[2], -Rb[5])
            pos["yaw_deg"] = _py_round(yaw * RAD_TO_DEG, 3)
            pos["pitch_deg"] = _py_round(-(theta * RAD_TO_DEG), 3)
            pos["roll_deg"] = _py_round(roll * RAD_TO_DEG, 3)
    else:
        pos["raw"] = None
    if handedness is not None:
        pos["handedness"] = handedness
    return pos
