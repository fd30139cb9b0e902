# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Arrays in and out of kernels through the buffer protocol, where typed memoryviews would cost
more to set up per argument than the kernel's arithmetic on them: `load` / `store` copy a small
float64 array (any strides) to or from a C array (the compiled pose filter's
receiver/locate/_kalman.pyx and _position.pyx, the server's _warm.pyx and _wire.pyx);
`fresh_data` is the data pointer of an output array a kernel has just allocated
(receiver/vision/_envelope.pyx, _pixels.pyx)."""

from cpython.buffer cimport (PyBUF_C_CONTIGUOUS, PyBUF_RECORDS, PyBUF_RECORDS_RO, PyBUF_WRITABLE, PyBuffer_Release,
                             PyObject_GetBuffer)


cdef inline bint _is_double(Py_buffer* v) noexcept:
    cdef const char* f = v.format
    if v.itemsize != 8 or f == NULL:
        return False
    if f[0] == c'<' or f[0] == c'=' or f[0] == c'@':
        f += 1
    return f[0] == c'd' and f[1] == 0


cdef inline Py_ssize_t _copy(object obj, double* data, Py_ssize_t max_rows, Py_ssize_t cols, bint write) except -1:
    cdef Py_buffer v
    cdef Py_ssize_t i, j, k = 0, n0, n1, s0, s1
    cdef int ndim = 2 if cols else 1
    cdef char* p
    PyObject_GetBuffer(obj, &v, PyBUF_RECORDS if write else PyBUF_RECORDS_RO)
    try:
        if v.ndim != ndim or not _is_double(&v):
            raise TypeError(f"a {ndim}-d float64 array is needed")
        n0 = v.shape[0]
        n1 = v.shape[1] if cols else 1
        if n0 > max_rows or (cols and n1 != cols):
            raise ValueError(f"shape ({n0}, {n1}): at most {max_rows} rows of {max(cols, 1)}")
        s0 = v.strides[0]
        s1 = v.strides[1] if cols else 0
        for i in range(n0):
            p = <char*>v.buf + i * s0
            for j in range(n1):
                if write:
                    (<double*>(p + j * s1))[0] = data[k]
                else:
                    data[k] = (<double*>(p + j * s1))[0]
                k += 1
        return n0
    finally:
        PyBuffer_Release(&v)


cdef inline Py_ssize_t load(object obj, double* out, Py_ssize_t max_rows, Py_ssize_t cols) except -1:
    """Copy the float64 array obj -- (n, cols), or (n,) for cols 0, n <= max_rows, any strides,
    else TypeError / ValueError -- into out, row-major. Returns n."""
    return _copy(obj, out, max_rows, cols, False)


cdef inline Py_ssize_t store(object obj, double* src, Py_ssize_t max_rows, Py_ssize_t cols) except -1:
    """Write src (row-major) into the writable float64 array obj (shape as `load`). Returns n."""
    return _copy(obj, src, max_rows, cols, True)


cdef inline double* fresh_data(object arr) except NULL:
    """The data pointer of a C-contiguous writable array the caller just made (np.empty) and
    holds while it writes there: the buffer is released at once, the array does not move."""
    cdef Py_buffer b
    PyObject_GetBuffer(arr, &b, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE)
    PyBuffer_Release(&b)
    return <double*> b.buf
