# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Kept: without it the lighting server spends 17 % more CPU per reply (docs/kernels.md).
"""The INTERFACES.md `position` object of the receiver's frames and the lighting server's
replies (`receiver.locate.posefilter.PoseFilter`, `receiver.serve.devices`), with its numbers
rounded in C instead of ~40 Python-level `round` calls, each a decimal conversion there:
* Python's and numpy's rounding: receiver/core/_pyround.pxd (rint(v * 10^n) / 10^n is Python's
  round(v, n) where it is used);
* yaw / pitch / roll: `receiver.locate.pose.rotation_to_ypr_deg`'s formulas with the C library's
  asin / cos / atan2 (what Python's math module calls) and math.degrees' factor 180 / pi.
"""

from libc.math cimport asin, atan2, cos, fabs, isfinite, rint, sqrt

from receiver.core._buf cimport load
from receiver.core._pyround cimport np_round, pow10, py_round, rint_is_round

cdef double RAD_TO_DEG = 180.0 / 3.14159265358979323846   # CPython's math.degrees factor


cdef inline double _clip_max0(double v) noexcept:
    """Python's max(0.0, v)."""
    return v if v > 0.0 else 0.0


cdef dict _xyz(double* v):
    return {"x": py_round(v[0], 5), "y": py_round(v[1], 5), "z": py_round(v[2], 5)}


cdef list _std(double* cov, int stride):
    return [py_round(sqrt(_clip_max0(cov[i * stride + i])), 5) for i in range(3)]


cdef void _ypr(const double* Rb, double* yaw, double* theta, double* roll) noexcept:
    """Yaw, theta (= -pitch) and roll, rad, of a row-major R_wc as the numpy server computes
    them: theta = asin(clip(-R[2][2], -1, 1)); at |cos theta| < 1e-6 (gimbal lock) roll is 0."""
    cdef double s = -Rb[8]                               # max(-1.0, min(1.0, -R[2][2]))
    s = s if s < 1.0 else 1.0
    s = s if s > -1.0 else -1.0
    theta[0] = asin(s)
    if fabs(cos(theta[0])) < 1e-6:
        yaw[0], roll[0] = atan2(Rb[0], -Rb[1]), 0.0
    else:
        yaw[0], roll[0] = atan2(Rb[7], Rb[6]), atan2(-Rb[2], -Rb[5])


def position(x, P, C, cov, R, str method, int n_leds, handedness):
    """The position object of x (6,) and P (6, 6) the filter state (both None without a
    track); C (3,), cov (3, 3) and R (3, 3) or None of the frame's fix (C None: no fix); method
    its `method` (or "kalman-coast"); handedness the map's, or None while undecided."""
    cdef double xb[6]
    cdef double Pb[36]
    cdef double Cb[3]
    cdef double covb[9]
    cdef double Rb[9]
    cdef double theta, yaw, roll
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
        pos["cov"] = [[np_round(Pb[6 * i + j], 8) for j in range(3)] for i in range(3)]
        pos["velocity_mps"] = [py_round(xb[3 + i], 4) for i in range(3)]
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
            pos["R_wc"] = [[np_round(Rb[3 * j + i], 6) for j in range(3)] for i in range(3)]
            _ypr(Rb, &yaw, &theta, &roll)
            pos["yaw_deg"] = py_round(yaw * RAD_TO_DEG, 3)
            pos["pitch_deg"] = py_round(-(theta * RAD_TO_DEG), 3)
            pos["roll_deg"] = py_round(roll * RAD_TO_DEG, 3)
    else:
        pos["raw"] = None
    if handedness is not None:
        pos["handedness"] = handedness
    return pos


# ---------------------------------------------------------------- the position object as JSON

from libc.string cimport memcpy, strlen
from cpython.mem cimport PyMem_Free
from json.encoder import encode_basestring_ascii as _json_str

cdef extern from "Python.h":
    char* PyOS_double_to_string(double val, char format_code, int precision, int flags, int* ptype) except NULL
    int Py_DTSF_ADD_DOT_0

cdef enum:
    BUF = 4096


cdef struct Out:
    char buf[BUF]
    int n


cdef int _put(Out* o, const char* s, int n) except -1:
    if o.n + n > BUF:
        raise OverflowError("position JSON too long")
    memcpy(o.buf + o.n, s, n)
    o.n += n
    return 0


cdef int _putb(Out* o, bytes b) except -1:
    return _put(o, b, len(b))


cdef int _put_str(Out* o, str s) except -1:
    b = s.encode("ascii")
    return _put(o, b, len(b))


cdef int _put_repr(Out* o, double v) except -1:
    """json's float: CPython's repr (PyOS_double_to_string, shortest round-trip digits), NaN
    and infinities refused (allow_nan=False)."""
    cdef char* s
    if not isfinite(v):
        raise ValueError("Out of range float values are not JSON compliant")
    s = PyOS_double_to_string(v, b'r', 0, Py_DTSF_ADD_DOT_0, NULL)
    try:
        _put(o, s, <int>strlen(s))
    finally:
        PyMem_Free(s)
    return 0


cdef int _put_py_round(Out* o, double v, int n) except -1:
    """json of Python's round(v, n) (`py_round`)."""
    cdef double y = v * pow10(n)
    if rint_is_round(y):
        return _put_repr(o, rint(y) / pow10(n))
    return _put_repr(o, round(v, n))


cdef int _put_np_round(Out* o, double v, int n) except -1:
    """json of numpy's round(v, n) (`np_round`)."""
    return _put_repr(o, np_round(v, n))


cdef int _put_xyz(Out* o, double* v) except -1:
    _putb(o, b'{"x":')
    _put_py_round(o, v[0], 5)
    _putb(o, b',"y":')
    _put_py_round(o, v[1], 5)
    _putb(o, b',"z":')
    _put_py_round(o, v[2], 5)
    return _putb(o, b"}")


cdef int _put_std(Out* o, double* cov, int stride) except -1:
    cdef int i
    for i in range(3):
        _putb(o, b"[" if i == 0 else b",")
        _put_py_round(o, sqrt(_clip_max0(cov[i * stride + i])), 5)
    return _putb(o, b"]")


cdef int _put_matrix(Out* o, double* M, bint transpose, int n) except -1:
    cdef int i, j
    for i in range(3):
        _putb(o, b"[[" if i == 0 else b",[")
        for j in range(3):
            if j:
                _putb(o, b",")
            _put_np_round(o, M[3 * j + i] if transpose else M[3 * i + j], n)
        _putb(o, b"]")
    return _putb(o, b"]")


def position_json(x, P, C, cov, R, str method, int n_leds, handedness):
    """`position`'s dict as compact strict JSON (what `receiver.serve.wire.encode` writes for
    it), without building the dict; NaN / infinities: ValueError."""
    cdef Out o
    cdef double xb[6]
    cdef double Pb[36]
    cdef double Cb[3]
    cdef double covb[9]
    cdef double Rb[9]
    cdef double P3[9]
    cdef double theta, yaw, roll
    cdef int i, j
    o.n = 0
    if x is not None:
        load(x, xb, 6, 0)
        load(P, Pb, 6, 6)
        for i in range(3):
            for j in range(3):
                P3[3 * i + j] = Pb[6 * i + j]
        _put_xyz(&o, xb)
        o.n -= 1                                             # reopen the object
    else:
        load(C, Cb, 3, 0)
        _put_xyz(&o, Cb)
        o.n -= 1
    _putb(&o, b',"method":')
    _put_str(&o, _json_str(method))
    _putb(&o, b',"n_leds":')
    _put_str(&o, str(n_leds))
    if x is not None:
        _putb(&o, b',"filtered":true,"std_m":')
        _put_std(&o, Pb, 6)
        _putb(&o, b',"cov":')
        _put_matrix(&o, P3, False, 8)
        _putb(&o, b',"velocity_mps":')
        for i in range(3):
            _putb(&o, b"[" if i == 0 else b",")
            _put_py_round(&o, xb[3 + i], 4)
        _putb(&o, b"]")
    else:
        _putb(&o, b',"filtered":false')
    if C is not None:
        load(C, Cb, 3, 0)
        load(cov, covb, 3, 3)
        _putb(&o, b',"raw":')
        _put_xyz(&o, Cb)
        _putb(&o, b',"raw_std_m":')
        _put_std(&o, covb, 3)
        if R is not None:
            load(R, Rb, 3, 3)
            _putb(&o, b',"R_wc":')
            _put_matrix(&o, Rb, True, 6)
            _ypr(Rb, &yaw, &theta, &roll)
            _putb(&o, b',"yaw_deg":')
            _put_py_round(&o, yaw * RAD_TO_DEG, 3)
            _putb(&o, b',"pitch_deg":')
            _put_py_round(&o, -(theta * RAD_TO_DEG), 3)
            _putb(&o, b',"roll_deg":')
            _put_py_round(&o, roll * RAD_TO_DEG, 3)
    else:
        _putb(&o, b',"raw":null')
    if handedness is not None:
        _putb(&o, b',"handedness":')
        _put_str(&o, _json_str(handedness))
    _putb(&o, b"}")
    return o.buf[:o.n]


def rotation_json(R):
    """A (3, 3) float64 array as the JSON of its nested list at full precision (repr of each
    number: what `wire.encode` writes for `R.tolist()`); NaN / infinities: ValueError."""
    cdef Out o
    cdef double Rb[9]
    cdef int i, j
    o.n = 0
    load(R, Rb, 3, 3)
    for i in range(3):
        _putb(&o, b"[[" if i == 0 else b",[")
        for j in range(3):
            if j:
                _putb(&o, b",")
            _put_repr(&o, Rb[3 * i + j])
        _putb(&o, b"]")
    _putb(&o, b"]")
    return o.buf[:o.n]
