# cython: language_level=3
"""numpy's pairwise summation (DOUBLE_pairwise_sum / CDOUBLE_pairwise_sum of numpy's loops:
8 accumulators, blocks of 128 scalars, halves above that), for kernels whose sums must equal
numpy's bit for bit (receiver.decode._ook, _pieces, receiver.locate._pnp, receiver.vision._envelope,
_pairing)."""

cdef enum:
    PW_BLOCKSIZE = 128


ctypedef fused pw_real:
    float
    double


cdef inline pw_real pw_sum(const pw_real *a, Py_ssize_t n) noexcept nogil:
    """numpy's DOUBLE_pairwise_sum / FLOAT_pairwise_sum (contiguous; the accumulators in the
    array's own type, as numpy's)."""
    cdef pw_real res, r0, r1, r2, r3, r4, r5, r6, r7
    cdef Py_ssize_t i, n2
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[i]
        return res
    elif n <= PW_BLOCKSIZE:
        r0 = a[0]; r1 = a[1]; r2 = a[2]; r3 = a[3]
        r4 = a[4]; r5 = a[5]; r6 = a[6]; r7 = a[7]
        i = 8
        while i < n - (n % 8):
            r0 += a[i]; r1 += a[i + 1]; r2 += a[i + 2]; r3 += a[i + 3]
            r4 += a[i + 4]; r5 += a[i + 5]; r6 += a[i + 6]; r7 += a[i + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return pw_sum(a, n2) + pw_sum(a + n2, n - n2)


cdef inline void pw_csum(const double *a, Py_ssize_t n, double *rr, double *ri) noexcept nogil:
    """numpy's CDOUBLE_pairwise_sum over n scalars (n / 2 complex numbers, interleaved)."""
    cdef double r0, r1, r2, r3, r4, r5, r6, r7, rr1, ri1, rr2, ri2
    cdef Py_ssize_t i, n2
    if n < 8:
        rr[0] = -0.0
        ri[0] = -0.0
        i = 0
        while i < n:
            rr[0] += a[i]
            ri[0] += a[i + 1]
            i += 2
        return
    elif n <= PW_BLOCKSIZE:
        r0 = a[0]; r1 = a[1]; r2 = a[2]; r3 = a[3]
        r4 = a[4]; r5 = a[5]; r6 = a[6]; r7 = a[7]
        i = 8
        while i < n - (n % 8):
            r0 += a[i]; r1 += a[i + 1]; r2 += a[i + 2]; r3 += a[i + 3]
            r4 += a[i + 4]; r5 += a[i + 5]; r6 += a[i + 6]; r7 += a[i + 7]
            i += 8
        rr[0] = (r0 + r2) + (r4 + r6)
        ri[0] = (r1 + r3) + (r5 + r7)
        while i < n:
            rr[0] += a[i]
            ri[0] += a[i + 1]
            i += 2
        return
    n2 = n // 2
    n2 -= n2 % 8
    pw_csum(a, n2, &rr1, &ri1)
    pw_csum(a + n2, n - n2, &rr2, &ri2)
    rr[0] = rr1 + rr2
    ri[0] = ri1 + ri2
