# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""S2-PSK decoder kernel (receiver.decode.s2psk.S2pskDecoder.folded_sums): the symbol-grid
phase search and the fold modulo the packet in one call instead of ~15 numpy calls per
decoder step. Every sum is taken in numpy's order (np.bincount: sequential in input order
from 0.0; the phase score np.abs(sums).sum(axis=1): 0.0 plus numpy's pairwise sum of a row),
so the results equal the numpy path to the bit (tests/decode/test_s2psk_fold.py)."""

from libc.math cimport floor, fabs
from libc.stdlib cimport malloc, free
from receiver.core._npsum cimport pw_sum


def folded_sums(const double[::1] t, const double[::1] x, const double[::1] phases, double symbol_s,
                double guard, Py_ssize_t packet_len, double[::1] out_s, double[::1] out_c,
                double[::1] out_q):
    """Fold the samples (times `t` s, soft values `x`) at the best of `phases` (in symbols):
    writes the per-position sums, counts and sums of squares into out_s / out_c / out_q
    (packet_len each) and returns the index of the best phase."""
    cdef Py_ssize_t n = t.shape[0], npz = phases.shape[0], i, k, j, nsym, best
    cdef long long s, smin, smax
    cdef double u, sym, frac, hi_guard = 1.0 - guard, w, score, best_score
    cdef double *sums
    cdef double *cnt
    cdef double *sq
    cdef double *ab
    if x.shape[0] != n or n == 0 or npz == 0 or packet_len <= 0:
        raise ValueError("folded_sums: t and x must have the same non-zero length, phases non-empty")
    if out_s.shape[0] != packet_len or out_c.shape[0] != packet_len or out_q.shape[0] != packet_len:
        raise ValueError("folded_sums: outputs must hold packet_len values")
    smin = <long long>floor(t[0] / symbol_s - phases[0])
    smax = smin
    for k in range(npz):
        for i in range(n):
            s = <long long>floor(t[i] / symbol_s - phases[k])
            if s < smin:
                smin = s
            if s > smax:
                smax = s
    nsym = <Py_ssize_t>(smax - smin + 1)
    sums = <double *>malloc(npz * nsym * sizeof(double))
    cnt = <double *>malloc(npz * nsym * sizeof(double))
    sq = <double *>malloc(nsym * sizeof(double))
    ab = <double *>malloc(nsym * sizeof(double))
    if sums == NULL or cnt == NULL or sq == NULL or ab == NULL:
        free(sums); free(cnt); free(sq); free(ab)
        raise MemoryError()
    try:
        for j in range(npz * nsym):
            sums[j] = 0.0
            cnt[j] = 0.0
        for k in range(npz):
            for i in range(n):
                u = t[i] / symbol_s - phases[k]
                sym = floor(u)
                frac = u - sym
                j = k * nsym + <Py_ssize_t>(<long long>sym - smin)
                if frac >= guard and frac <= hi_guard:
                    sums[j] += x[i]
                    cnt[j] += 1.0
                else:
                    sums[j] += 0.0 * x[i]
                    cnt[j] += 0.0
        best = 0
        best_score = 0.0
        for k in range(npz):
            for j in range(nsym):
                ab[j] = fabs(sums[k * nsym + j])
            score = 0.0 + pw_sum(ab, nsym)
            # np.argmax: the first maximum, a NaN counting as the maximum
            if k == 0 or score > best_score or (score != score and best_score == best_score):
                best, best_score = k, score
        for j in range(nsym):
            sq[j] = 0.0
        for i in range(n):
            u = t[i] / symbol_s - phases[best]
            sym = floor(u)
            frac = u - sym
            if frac >= guard and frac <= hi_guard:
                sq[<Py_ssize_t>(<long long>sym - smin)] += x[i] * x[i]
        for j in range(packet_len):
            out_s[j] = 0.0
            out_c[j] = 0.0
            out_q[j] = 0.0
        for j in range(nsym):
            i = <Py_ssize_t>((j + smin) % packet_len)
            if i < 0:
                i += packet_len
            out_s[i] += sums[best * nsym + j]
            out_c[i] += cnt[best * nsym + j]
            out_q[i] += sq[j]
    finally:
        free(sums); free(cnt); free(sq); free(ab)
    return best
