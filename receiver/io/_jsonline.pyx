# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled `receiver.io.output.frame_line`: a frame's JSON line written into one C buffer, every
number formatted by CPython's own float formatter (`PyOS_double_to_string`, what `"%.2f" % v` and
`repr(v)` call), so the characters are those of `output._fast_line` / json.dumps (tests:
tests/io/test_output_line.py, tests/engine/test_glue_kernels.py). Anything it does not format exactly the
same way (NaN, a numpy int as an LED field, a string needing escapes, an int subclass...) gives
None, and the Python writer decides.
"""

from cpython.mem cimport PyMem_Free, PyMem_Malloc, PyMem_Realloc
from libc.math cimport fabs, isfinite, nearbyint, signbit
from libc.string cimport memcpy, strlen

from receiver.core.records import LedObservation

cdef extern from "Python.h":
    char* PyOS_double_to_string(double val, char format_code, int precision, int flags, int* ptype) except NULL
    bint PyFloat_Check(object o)
    double PyFloat_AS_DOUBLE(object o)
    bint PyLong_CheckExact(object o)
    bint PyLong_Check(object o)
    double PyLong_AsDouble(object o) except? -1.0
    long long PyLong_AsLongLongAndOverflow(object o, int* overflow) except? -1
    bint PyUnicode_CheckExact(object o)
    bint PyUnicode_Check(object o)
    bint PyList_Check(object o)
    bint PyTuple_Check(object o)
    bint PyDict_Check(object o)
    const char* PyUnicode_AsUTF8AndSize(object o, Py_ssize_t* size) except NULL
    bint PyUnicode_IS_ASCII(object o)
    object PyUnicode_DecodeASCII(const char* s, Py_ssize_t size, const char* errors)

cdef int Py_DTSF_ADD_DOT_0 = 0x02
# output.PX_DECIMALS, AREA_DECIMALS, M_DECIMALS, MS_DECIMALS, T_DECIMALS and the range where
# `_num_tok` formats "%.{nd}f" (output._FAST_MIN, _FAST_MAX): passed by the wrapper at import.
cdef int PX = 2, AREA = 1, M = 4, MS = 3, T = 6
cdef double FAST_MIN = 1e-4, FAST_MAX = 1e9
cdef int MAX_DEPTH = 32
cdef object _LED = LedObservation


def configure(int px, int area, int m, int ms, int t, double fast_min, double fast_max):
    """The decimals and the fixed-notation range of receiver.io.output (set once at its import)."""
    global PX, AREA, M, MS, T, FAST_MIN, FAST_MAX
    PX, AREA, M, MS, T, FAST_MIN, FAST_MAX = px, area, m, ms, t, fast_min, fast_max


cdef struct Buf:
    char* p
    Py_ssize_t n
    Py_ssize_t cap


cdef int open_buf(Buf* b, Py_ssize_t cap) except -1:
    """An empty buffer of `cap` bytes (the caller frees b.p with PyMem_Free)."""
    b.n = 0
    b.cap = cap
    b.p = <char*>PyMem_Malloc(cap)
    if b.p == NULL:
        raise MemoryError()
    return 0


cdef int grow(Buf* b, Py_ssize_t k) except -1:
    """Room for k more bytes (the buffer doubled until they fit)."""
    cdef Py_ssize_t cap = 2 * b.cap
    cdef char* q
    while cap < b.n + k:
        cap *= 2
    q = <char*>PyMem_Realloc(b.p, cap)
    if q == NULL:
        raise MemoryError()
    b.p, b.cap = q, cap
    return 0


cdef inline int put(Buf* b, const char* s, Py_ssize_t k) except -1:
    if b.n + k > b.cap:
        grow(b, k)
    memcpy(b.p + b.n, s, k)
    b.n += k
    return 0


cdef inline int puts(Buf* b, const char* s) except -1:
    return put(b, s, strlen(s))


cdef double POW10[23]
POW10[0] = 1.0
for _i in range(1, 23):
    POW10[_i] = POW10[_i - 1] * 10.0   # exact: 10^k for k <= 22 is a double (5^22 < 2^53)
cdef double SCALED_MAX = 1125899906842624.0   # 2^50: below it an ulp of a*10^k is <= 1/4
cdef double FIXED_SCALED_MAX = 68719476736.0  # 2^36: below it a*10^nd is within 2^-17 of its double


cdef int put_fixed_int(Buf* b, bint neg, long long n, int k, bint strip) except -1:
    """'-'? n / 10^k written with k decimals (`strip`: trailing zeros dropped, one kept)."""
    cdef char tmp[48]
    cdef int i = 47, d = 0
    while strip and k > 1 and n % 10 == 0:
        n //= 10
        k -= 1
    tmp[i] = 0
    while d < k:
        i -= 1
        tmp[i] = <char>(48 + n % 10)
        n //= 10
        d += 1
    if k == 0:
        i -= 1
        tmp[i] = b'0'
    i -= 1
    tmp[i] = b'.'
    while True:
        i -= 1
        tmp[i] = <char>(48 + n % 10)
        n //= 10
        if n == 0:
            break
    if neg:
        i -= 1
        tmp[i] = b'-'
    return put(b, tmp + i, 47 - i)


cdef bint fast_fixed(Buf* b, double x, int nd) except -1:
    """`"%.{nd}f" % x` with trailing zeros dropped (one kept), for 1e-4 <= |x| < 1e9 or 0 and
    nd <= 6 and |x| 10^nd < 2^36: the nearest integer to |x| 10^nd (exactly the nearest: not
    within 1e-4 of a half, where False asks CPython's formatter)."""
    cdef double a = fabs(x), p, n
    if nd < 0 or nd > 6 or not (a < 1e9 and (a >= 1e-4 or a == 0.0)):
        return False
    p = a * POW10[nd]
    if p >= FIXED_SCALED_MAX:
        return False
    n = nearbyint(p)
    if fabs(p - n) > 0.4999:   # |x| 10^nd is p within 2^-17 (half an ulp of p < 2^36)
        return False
    put_fixed_int(b, signbit(x), <long long>n, nd, True)
    return True


cdef int put_ll(Buf* b, long long v) except -1:
    """The decimal digits of v ('%lld')."""
    cdef char tmp[24]
    cdef int i = 24
    cdef unsigned long long u = <unsigned long long>v
    if v < 0:
        u = 0 - u
    while True:
        i -= 1
        tmp[i] = <char>(48 + u % 10)
        u //= 10
        if u == 0:
            break
    if v < 0:
        i -= 1
        tmp[i] = b'-'
    return put(b, tmp + i, 24 - i)


cdef int put_exp(Buf* b, bint neg, long long n, int k) except -1:
    """repr's exponent notation of n / 10^k (n > 0 without trailing zeros, value below 1e-4):
    'd.ddde-XX' (one digit: 'de-XX'), the exponent at least two digits."""
    cdef char tmp[48]
    cdef int nd = 0, i, e
    cdef char dig[24]
    while n > 0:
        dig[nd] = <char>(48 + n % 10)
        n //= 10
        nd += 1
    i = 0
    if neg:
        tmp[i] = b'-'
        i += 1
    tmp[i] = dig[nd - 1]
    i += 1
    if nd > 1:
        tmp[i] = b'.'
        i += 1
        for e in range(nd - 2, -1, -1):
            tmp[i] = dig[e]
            i += 1
    e = k - nd + 1  # the value is d.ddd 10^-e
    tmp[i] = b'e'
    tmp[i + 1] = b'-'
    i += 2
    if e >= 100:
        tmp[i] = <char>(48 + e // 100)
        i += 1
        e = e % 100
    tmp[i] = <char>(48 + e // 10)
    tmp[i + 1] = <char>(48 + e % 10)
    return put(b, tmp, i + 2)


cdef bint fast_repr_small(Buf* b, double x) except -1:
    """repr(x) for 0 < |x| < 1e-4 (exponent notation), by `fast_repr`'s argument: the fewest
    decimals k <= 22 (10^k exact) whose nearest integer n to |x| 10^k < 2^50 reads back as x.
    False (CPython's formatter decides) when none does."""
    cdef double a = fabs(x), p, n
    cdef int k
    for k in range(5, 23):
        p = a * POW10[k]
        if p >= SCALED_MAX:
            return False
        n = nearbyint(p)
        if n != 0.0 and n / POW10[k] == a:
            put_exp(b, signbit(x), <long long>n, k)
            return True
    return False


cdef bint fast_repr(Buf* b, double x) except -1:
    """repr(x) for 1e-4 <= |x| < 2^50 (fixed notation): the fewest decimals k whose nearest
    integer n to |x| 10^k reads back as x (n / 10^k == |x|, a correctly rounded division, as
    strtod reads the digits); below 2^50 only that integer can, so these are repr's digits. False
    (CPython's formatter decides) outside that range or beyond 17 decimals. Below 1e-4:
    `fast_repr_small`."""
    cdef double a = fabs(x), p, n
    cdef int k
    if x == 0.0:
        if signbit(x):
            put(b, b"-0.0", 4)
        else:
            put(b, b"0.0", 3)
        return True
    if a < 1e-4:
        return fast_repr_small(b, x)
    if not (a < SCALED_MAX):
        return False
    for k in range(18):
        p = a * POW10[k]
        if p >= SCALED_MAX:
            return False
        n = nearbyint(p)
        if n / POW10[k] == a:
            put_fixed_int(b, signbit(x), <long long>n, k, False)
            return True
    return False


cdef int put_dtoa(Buf* b, double x, char code, int prec, int flags, bint strip) except -1:
    """CPython's formatting of x ('f' with prec decimals, or 'r': repr); `strip`: trailing zeros
    dropped, one kept after the point (`output._num_tok`)."""
    cdef char* s = PyOS_double_to_string(x, code, prec, flags, NULL)
    cdef Py_ssize_t k = strlen(s)
    if strip:
        while k > 1 and s[k - 1] == b'0':
            k -= 1
    try:
        put(b, s, k)
        if strip and s[k - 1] == b'.':
            put(b, b"0", 1)
    finally:
        PyMem_Free(s)
    return 0


cdef int put_pystr(Buf* b, object s) except -1:
    cdef Py_ssize_t k
    cdef const char* c = PyUnicode_AsUTF8AndSize(s, &k)
    return put(b, c, k)


cdef int put_num(Buf* b, object v, int nd) except -1:
    """`output._num_tok(v, nd)`; 1 where the Python writer must decide (not a float or int)."""
    cdef double x, a
    if v is None:
        put(b, b"null", 4)
        return 0
    if PyFloat_Check(v):
        x = PyFloat_AS_DOUBLE(v)
    elif PyLong_CheckExact(v):
        try:
            x = PyLong_AsDouble(v)
        except OverflowError:
            return 1
    else:
        return 1
    a = fabs(x)
    if nd > 0 and (FAST_MIN <= a < FAST_MAX or a == 0.0):
        if fast_fixed(b, x, nd):
            return 0
        return put_dtoa(b, x, b'f', nd, 0, True)
    if not isfinite(x):
        put(b, b"null", 4)
        return 0
    put_pystr(b, repr(round(x, nd)))
    return 0


cdef int put_int(Buf* b, object v) except -1:
    """`output._int_tok(v)`; 1 for anything but None or an int."""
    cdef int overflow = 0
    cdef long long n
    if v is None:
        put(b, b"null", 4)
        return 0
    if not PyLong_CheckExact(v):
        return 1
    n = PyLong_AsLongLongAndOverflow(v, &overflow)
    if overflow:
        put_pystr(b, repr(v))
        return 0
    put_ll(b, n)
    return 0


cdef bint plain(object s):
    """A str json.dumps writes as is between quotes (printable ASCII, no quote or backslash)."""
    cdef Py_ssize_t k, i
    cdef const char* c
    cdef char ch
    if not PyUnicode_CheckExact(s) or not PyUnicode_IS_ASCII(s):
        return False
    c = PyUnicode_AsUTF8AndSize(s, &k)
    for i in range(k):
        ch = c[i]
        if ch < 32 or ch > 126 or ch == b'"' or ch == b'\\':
            return False
    return True


cdef int put_word(Buf* b, object v) except -1:
    """`output._str_tok(v)`, for every str json.dumps writes unescaped (not only its words: e.g.
    the vehicle's "fv-track"); 1 for anything else."""
    if v is None:
        put(b, b"null", 4)
        return 0
    if not plain(v):
        return 1
    put(b, b'"', 1)
    put_pystr(b, v)
    put(b, b'"', 1)
    return 0


cdef int put_json(Buf* b, object v, int depth) except -1:
    """json.dumps(v, separators=(",", ":"), allow_nan=False, default=output._jsonable) for the
    types a position / vehicle object holds, in json's own order of type tests; 1 otherwise
    (a NaN, an escaped string, an int or str subclass, a non-str key, too deep)."""
    cdef bint first = True
    if depth > MAX_DEPTH:
        return 1
    if v is None:
        put(b, b"null", 4)
    elif v is True:
        put(b, b"true", 4)
    elif v is False:
        put(b, b"false", 5)
    elif PyUnicode_Check(v):
        if not plain(v):
            return 1
        put(b, b'"', 1)
        put_pystr(b, v)
        put(b, b'"', 1)
    elif PyLong_Check(v):
        return put_int(b, v)
    elif PyFloat_Check(v):
        if not isfinite(PyFloat_AS_DOUBLE(v)):
            return 1
        if not fast_repr(b, PyFloat_AS_DOUBLE(v)):
            put_dtoa(b, PyFloat_AS_DOUBLE(v), b'r', 0, Py_DTSF_ADD_DOT_0, False)
    elif PyList_Check(v) or PyTuple_Check(v):
        put(b, b"[", 1)
        for item in v:
            if not first:
                put(b, b",", 1)
            first = False
            if put_json(b, item, depth + 1):
                return 1
        put(b, b"]", 1)
    elif PyDict_Check(v):
        put(b, b"{", 1)
        for key, item in (<dict>v).items():
            if not plain(key):
                return 1
            if not first:
                put(b, b",", 1)
            first = False
            put(b, b'"', 1)
            put_pystr(b, key)
            put(b, b'":', 2)
            if put_json(b, item, depth + 1):
                return 1
        put(b, b"}", 1)
    else:
        tolist = getattr(v, "tolist", None)  # output._jsonable: numpy arrays and scalars
        if tolist is None:
            return 1
        try:
            v = tolist()
        except Exception:
            return 1
        return put_json(b, v, depth + 1)
    return 0


cdef int put_led(Buf* b, object o) except -1:
    """`output._led_tok(o)`; 1 where the Python writer must decide."""
    cdef dict d
    if type(o) is not _LED:
        return 1
    d = o.__dict__
    dist, kind, freq = d["distance_m"], d["kind"], d["freq_hz"]
    put(b, b'{"track":', 9)
    if put_int(b, d["track"]):
        return 1
    put(b, b',"id":', 6)
    if put_int(b, d["id"]):
        return 1
    put(b, b',"mode":', 8)
    if put_word(b, d["mode"]):
        return 1
    put(b, b',"cx":', 6)
    if put_num(b, d["cx"], PX):
        return 1
    put(b, b',"cy":', 6)
    if put_num(b, d["cy"], PX):
        return 1
    put(b, b',"area_px":', 11)
    if put_num(b, d["area_px"], AREA):
        return 1
    put(b, b',"distance_m":', 14)
    if dist is None:
        put(b, b"null", 4)
    elif put_num(b, dist, M):
        return 1
    if d["border"]:
        put(b, b',"border":true', 14)
    else:
        put(b, b',"border":false', 15)
    if kind is not None:
        put(b, b',"kind":', 8)
        if put_word(b, kind):
            return 1
    if freq is not None:
        if type(freq) is not float or not isfinite(<double>freq):
            return 1
        put(b, b',"freq_hz":', 11)
        if not fast_repr(b, <double>freq):
            put_dtoa(b, <double>freq, b'r', 0, Py_DTSF_ADD_DOT_0, False)
    if dist is not None:
        put(b, b',"distance_estimator":', 22)
        if put_word(b, d["distance_estimator"]):
            return 1
    put(b, b"}", 1)
    return 0


cdef int put_frame(Buf* b, object res, bint profile) except -1:
    cdef bint first = True
    put(b, b'{"frame":', 9)
    if put_int(b, res.frame):
        return 1
    put(b, b',"t":', 5)
    if put_num(b, res.t_s, T):
        return 1
    put(b, b',"latency_ms":', 14)
    if put_num(b, res.latency_ms, MS):
        return 1
    put(b, b',"leds":[', 9)
    for o in res.leds:
        if not first:
            put(b, b",", 1)
        first = False
        if put_led(b, o):
            return 1
    put(b, b'],"position":', 13)
    if put_json(b, res.position, 0):
        return 1
    put(b, b',"vehicle":', 11)
    if put_json(b, res.vehicle, 0):
        return 1
    if profile:
        put(b, b',"stage_ms":{', 13)
        first = True
        for k, v in res.stage_ms.items():
            if not first:
                put(b, b",", 1)
            first = False
            if put_word(b, k):
                return 1
            put(b, b":", 1)
            if put_num(b, v, MS):
                return 1
        put(b, b"}", 1)
    put(b, b"}", 1)
    return 0


def frame_line(res, bint profile):
    """`output.frame_line(res, profile=profile)`'s text, or None where the Python writer must
    decide (module doc)."""
    cdef Buf b
    open_buf(&b, 4096)
    try:
        if put_frame(&b, res, profile):
            return None
        return PyUnicode_DecodeASCII(b.p, b.n, NULL)
    finally:
        PyMem_Free(b.p)


def number_tokens(double x, int nd):
    """(the fast fixed token or None, the fast repr or None, CPython's fixed token, CPython's
    repr) of x: the tests compare the fast formatters with CPython's on many values."""
    cdef Buf b
    open_buf(&b, 256)
    try:
        fixed = fast_fixed(&b, x, nd)
        t1 = PyUnicode_DecodeASCII(b.p, b.n, NULL) if fixed else None
        b.n = 0
        rep = fast_repr(&b, x)
        t2 = PyUnicode_DecodeASCII(b.p, b.n, NULL) if rep else None
        b.n = 0
        put_dtoa(&b, x, b'f', nd, 0, True)
        t3 = PyUnicode_DecodeASCII(b.p, b.n, NULL)
        b.n = 0
        put_dtoa(&b, x, b'r', 0, Py_DTSF_ADD_DOT_0, False)
        t4 = PyUnicode_DecodeASCII(b.p, b.n, NULL)
        return t1, t2, t3, t4
    finally:
        PyMem_Free(b.p)
