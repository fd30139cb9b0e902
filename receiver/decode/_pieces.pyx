# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# Share: 34 % of an indoor-static frame's instructions (4.5 of 13.2 M a frame; docs/kernels.md).
"""The likelihood tables of receiver.decode.pieces.PieceAssembler, their one implementation (a
share of a frame is in docs/kernels.md): a piece's correlations with the candidates' packets
and their windowed best (`correlate`), the table of every (ID, phase) hypothesis kept up to the
pieces' placements (`update`, `take_back`), its best hypothesis (`choose`), where each piece
fits under one (`fits`), the frame jitter it measures (`measure`) and the best hypothesis against
every other candidate on the chips where their packets differ (`rivals`).

Every value is numpy's own for the same expressions: float32 products and sums where the tables
are float32 (a piece's correlation adds its chips in order, as a reduction over an outer axis
does), float64 likelihood sums adding the terms in order, numpy's pairwise summation for the
mean (receiver/core/_npsum.pxd), first maxima as argmax's, comparisons of float32 values with a
threshold in float32 (numpy's rule for a Python float beside a float32 array). Built with
-ffp-contract=off so no product-sum is fused. tests/decode/test_ook_pieces.py checks the
correlations against numpy's FFT, the tables against sums of the terms and the rivals' chips
against a numpy fit of each piece.
"""

from libc.math cimport fabs, floor, fmod, INFINITY
from libc.stdlib cimport free, malloc
from receiver.core._npsum cimport pw_sum

import numpy as np

cdef enum:
    PACKET = 54
    STEPS = 4
    PHASES = PACKET * STEPS

PACKET_LEN = PACKET
PHASE_STEPS = STEPS


cdef inline long long _mod(long long a, long long n) noexcept nogil:
    """a mod n in [0, n) (Python's % for a positive n)."""
    cdef long long r = a % n
    return r + n if r < 0 else r


cdef inline double _wrap(double x) noexcept nogil:
    """x chips wrapped into [-27, 27): (x + 27) % 54 - 27 with Python's (and numpy's) float %."""
    cdef double m = fmod(x + PACKET / 2.0, <double>PACKET)
    if m != 0.0:
        if m < 0.0:
            m += PACKET
    else:
        m = 0.0
    return m - PACKET / 2.0


cdef inline long long _position(double q, int ph) noexcept nogil:
    """Packet position of a chip at packet time q under phase index ph: floor(q + ph / 4 + 1/2) % 54."""
    return _mod(<long long>floor(q + ph / <double>STEPS + 0.5), PACKET)


def correlate(const float[:, ::1] wrapped, const float[::1] x, double den, float[:, :, ::1] corr,
              float[:, :, :, ::1] rep, Py_ssize_t slot, int half_wide, double pen_wide, int half_narrow,
              double pen_narrow):
    """One piece x (n,) against the packets twice round `wrapped` (K, 108), into its slot of
    the tables: corr[slot, k, s] = sum_j x[j] T[k, (s + j) % 54] / den (float32, chips in
    order), and rep[w, slot] (K, 432) its best within the wide (w = 0) and the narrow (1)
    window, each of 54 positions repeated for its 4 phases, twice round: best[s] = max over d
    in [-half, half] of corr[(s + d) % 54] - float32(penalty |d|)."""
    cdef Py_ssize_t K = wrapped.shape[0], n = x.shape[0], k, j, jj, s, i, w
    cdef int d, half
    cdef float xj, fden = <float>den
    cdef float acc[PACKET]
    cdef float ext[3 * PACKET]  # the row's correlations with up to 54 of the other end each side
    cdef float best[PACKET]
    cdef float v, pen_d
    cdef double pen
    if not (0 <= slot < corr.shape[0] and corr.shape[1] == K and rep.shape[2] == K and n > 0):
        raise IndexError(f"piece slot {slot} or a table's shape does not fit the tables")
    for k in range(K):
        # the chips in order for every position at once (each position's sum is its own)
        xj = x[0]
        for s in range(PACKET):
            acc[s] = wrapped[k, s] * xj
        for j in range(1, n):
            xj = x[j]
            jj = j % PACKET  # (a piece longer than the packet goes round it)
            for s in range(PACKET):
                acc[s] = acc[s] + wrapped[k, s + jj] * xj
        for s in range(PACKET):
            acc[s] = acc[s] / fden
            corr[slot, k, s] = acc[s]
            ext[s] = acc[s]
            ext[s + PACKET] = acc[s]
            ext[s + 2 * PACKET] = acc[s]
        for w in range(2):
            half = half_wide if w == 0 else half_narrow
            pen = pen_wide if w == 0 else pen_narrow
            if half <= 0:
                for s in range(PACKET):
                    best[s] = acc[s]
            else:
                # shifts d = -half .. half in order: best[s] = max of ext[54 + s + d] - pen |d|
                pen_d = <float>(pen * half)
                for s in range(PACKET):
                    best[s] = ext[PACKET + s - half] - pen_d
                for d in range(-half + 1, half + 1):
                    pen_d = <float>(pen * (d if d >= 0 else -d))
                    for s in range(PACKET):
                        v = ext[PACKET + s + d] - pen_d
                        best[s] = v if v > best[s] else best[s]
            for i in range(PHASES):
                rep[w, slot, k, i] = best[i // STEPS]
                rep[w, slot, k, i + PHASES] = best[i // STEPS]


cdef inline double _term(double[:, ::1] ll, const float[:, :, :, ::1] rep, Py_ssize_t slot,
                         long long m, long long narrow, double coef) noexcept nogil:
    """ll += float32(coef) * the slice from m of the piece's repeated table (float32 products
    added in float64); returns coef (the piece's share of the total)."""
    cdef Py_ssize_t K = ll.shape[0], k, i
    cdef float c = <float>coef
    for k in range(K):
        for i in range(PHASES):
            ll[k, i] = ll[k, i] + <double>(rep[narrow, slot, k, m + i] * c)
    return coef


def take_back(double[:, ::1] ll, const float[:, :, :, ::1] rep, const double[::1] den,
              long long[::1] term_m, long long[::1] term_n, Py_ssize_t slot, double total):
    """Take a dropped piece's term (if any) out of the table; returns the new total weight."""
    if not 0 <= slot < den.shape[0]:
        raise IndexError(f"piece slot {slot} outside the tables")
    if term_m[slot] >= 0:
        total += _term(ll, rep, slot, term_m[slot], term_n[slot], -den[slot])
        term_m[slot] = -1
    return total


def update(double[:, ::1] ll, const float[:, :, :, ::1] rep, const double[::1] den, const double[::1] q,
           long long[::1] term_m, long long[::1] term_n, list jitters, long long added, double total,
           double[::1] qq, unsigned char[::1] narrow):
    """Bring the table to the placements of the latest len(jitters) pieces (added in order; the
    a-th piece added sits in slot (a - 1) % slots): each at packet time q + j in the narrow
    window, j its frame's jitter, or at q in the wide one when j is None. A piece whose slice
    start floor(4 (qq + 1/2)) % 216 or window changed has its old term taken back and its new
    one added, in the pieces' order. Writes the placements to qq / narrow; returns (total
    weight, pieces placed by a jitter)."""
    cdef Py_ssize_t P = len(jitters), S = den.shape[0], i, slot
    cdef long long m, nw
    cdef int timed = 0
    cdef double x
    for i in range(P):
        slot = _mod(added - P + i, S)
        j = jitters[i]
        if j is None:
            x = q[slot]
            nw = 0
        else:
            x = q[slot] + <double>j
            nw = 1
            timed += 1
        qq[i] = x
        narrow[i] = nw
        m = _mod(<long long>floor(STEPS * (x + 0.5)), PHASES)
        if m != term_m[slot] or nw != term_n[slot]:
            if term_m[slot] >= 0:
                total += _term(ll, rep, slot, term_m[slot], term_n[slot], -den[slot])
            total += _term(ll, rep, slot, m, nw, den[slot])
            term_m[slot] = m
            term_n[slot] = nw
    return total, timed


def choose(const double[:, ::1] ll, double total, Py_ssize_t row):
    """The best hypothesis of the mean table ll / total: (candidate, phase index, its mean, the
    best mean of the other candidates (-1 with one candidate)); row >= 0 fixes the candidate.
    First maxima, as argmax."""
    cdef Py_ssize_t K = ll.shape[0], k, i, c = 0, ph = 0
    cdef double top, v, second = -1.0
    if row >= 0:
        c = row
        top = ll[c, 0] / total
        for i in range(1, PHASES):
            v = ll[c, i] / total
            if v > top:
                top, ph = v, i
    else:
        top = ll[0, 0] / total
        for k in range(K):
            for i in range(PHASES):
                v = ll[k, i] / total
                if v > top:
                    top, c, ph = v, k, i
    if K > 1:
        second = -INFINITY
        for k in range(K):
            if k == c:
                continue
            for i in range(PHASES):
                v = ll[k, i] / total
                if v > second:
                    second = v
    return c, ph, top, second


cdef void _fits(const float[:, :, :, ::1] rep, const double[::1] qq, const unsigned char[::1] narrow,
                Py_ssize_t P, long long added, Py_ssize_t S, Py_ssize_t c, int ph, int J,
                long long *at) noexcept nogil:
    cdef Py_ssize_t i, slot
    cdef long long start, s, best_s
    cdef int o, near = J if J < 1 else 1  # min(1, J)
    cdef float v, b
    for i in range(P):
        slot = _mod(added - P + i, S)
        start = _position(qq[i], ph)
        best_s = -1
        b = -INFINITY
        for o in range(-J, J + 1):
            s = _mod(start + o, PACKET)
            if narrow[i] and (o > near or o < -near):
                v = -INFINITY
            else:
                v = rep[narrow[i], slot, c, STEPS * s]
            if best_s < 0 or v > b:
                b, best_s = v, s
        at[i] = best_s


def fits(const float[:, :, :, ::1] rep, const double[::1] qq, const unsigned char[::1] narrow,
         Py_ssize_t P, long long added, Py_ssize_t c, int ph, int J, long long[::1] at):
    """Packet position where each of the latest P pieces fits best under hypothesis (candidate
    c, phase index ph), into at (P,): the first maximum of its penalised best correlation over
    the positions within +-J of its placement's (+-1 in the narrow window)."""
    _fits(rep, qq, narrow, P, added, rep.shape[1], c, ph, J, &at[0])


def measure(const float[:, :, ::1] corr, const float[:, :, :, ::1] rep, const double[::1] q,
            const double[::1] qq, const unsigned char[::1] narrow, Py_ssize_t P, long long added,
            Py_ssize_t c, int ph, int J, double ref_match, double ref_unique, long long[::1] at):
    """The frame jitter the latest P pieces measure under hypothesis (c, ph): the light's
    continuous phase phi = ph / 4 + the mean of wrap(fit - qq - ph / 4) over the pieces
    (`fits`); then each piece's best position within +-J of its timestamp's place (q, not
    its placement) by its unpenalised correlation. Returns [(piece index, wrap(position - q -
    phi)), ...] of the pieces whose best correlation is >= ref_match and beats the window's
    next best by >= ref_unique (float32 comparisons; with J = 0 the next best is -1 and the
    difference a float64)."""
    cdef Py_ssize_t S = corr.shape[0], i, slot
    cdef double base = ph / <double>STEPS, phi
    cdef long long start, s, best_s
    cdef int o
    cdef float v, top, other, f_match = <float>ref_match, f_unique = <float>ref_unique
    cdef double[::1] d = np.empty(P)
    cdef bint ok
    _fits(rep, qq, narrow, P, added, S, c, ph, J, &at[0])
    for i in range(P):
        d[i] = _wrap((at[i] - qq[i]) - base)
    phi = base + pw_sum(&d[0], P) / P
    out = []
    for i in range(P):
        slot = _mod(added - P + i, S)
        start = _position(q[slot], ph)
        best_s = -1
        top = -INFINITY
        for o in range(-J, J + 1):
            s = _mod(start + o, PACKET)
            v = corr[slot, c, s]
            if best_s < 0 or v > top:
                top, best_s = v, s
        if J > 0:
            other = -INFINITY
            for o in range(-J, J + 1):
                s = _mod(start + o, PACKET)
                if s != best_s and corr[slot, c, s] > other:
                    other = corr[slot, c, s]
            ok = top >= f_match and top - other >= f_unique
        else:
            ok = top >= f_match and <double>top + 1.0 >= ref_unique
        if ok:
            out.append((i, _wrap((best_s - q[slot]) - phi)))
    return out



cdef inline long long _fit(const float[:, :, ::1] corr, Py_ssize_t slot, Py_ssize_t k, long long start, int half,
                           double pen) noexcept nogil:
    """Packet position where a piece placed at `start` fits candidate k best: the first
    maximum over d in [-half, half] of corr[slot, k, (start + d) % 54] - float32(pen |d|) (the
    windowed best `correlate` keeps)."""
    cdef long long best_s, s
    cdef float b, v
    cdef int d
    if half <= 0:
        return _mod(start, PACKET)
    best_s = _mod(start - half, PACKET)
    b = corr[slot, k, best_s] - <float>(pen * half)
    for d in range(-half + 1, half + 1):
        s = _mod(start + d, PACKET)
        v = corr[slot, k, s] - <float>(pen * (d if d >= 0 else -d))
        if v > b:
            b, best_s = v, s
    return best_s


def rivals(const double[:, ::1] ll, const float[:, :, ::1] corr, const float[:, ::1] wrapped, list xs,
           const double[::1] qq, const unsigned char[::1] narrow, long long added, Py_ssize_t c, int ph,
           int J, double pen_wide, double pen_narrow, double[::1] evidence, double[::1] differ,
           double[::1] differ_sq):
    """The winner (candidate c, phase index ph) against every other candidate k at its own best
    phase (the first maximum of ll[k]), on the chips where their packets differ: each of the
    latest P = len(xs) pieces (weighted chips xs[i], placed at qq[i] in the wide (+-J,
    pen_wide) or narrow (+-min(1, J), pen_narrow) window) is fitted under each hypothesis
    (`_fit`); differ[k] = the sum of |x| over the chips whose two fitted packets' chips differ
    (differ_sq[k]: of x squared),
    evidence[k] = (ll[c, ph] - ll[k, best]) / 2: the sum over those chips of x times c's chip,
    less half the two fits' difference of window penalties. For c itself both are 0."""
    cdef Py_ssize_t K = ll.shape[0], P = len(xs), S = corr.shape[0], k, i, j, n, o
    cdef long long fc, fk
    cdef int phk, p, near = J if J < 1 else 1
    cdef double d, d2, top, v
    cdef const float[::1] x
    if not (0 <= c < K and corr.shape[1] == K and wrapped.shape[0] == K and evidence.shape[0] == K
            and differ.shape[0] == K and differ_sq.shape[0] == K and qq.shape[0] >= P and narrow.shape[0] >= P and ll.shape[1] == PHASES):
        raise IndexError("candidate or a table's shape does not fit the tables")
    top = ll[c, ph]
    # the pieces' |x| one after another (start of piece i: offs[i]), each piece's slot, window
    # and penalty, and c's fit of each
    offs_a = np.zeros(P + 1, np.int64)
    for i in range(P):
        offs_a[i + 1] = offs_a[i] + len(xs[i])
    ax_a = np.abs(np.concatenate(xs)) if P else np.zeros(0, np.float32)
    fc_a, slot_a, half_a, pen_a = np.empty(P, np.int64), np.empty(P, np.int64), np.empty(P, np.intc), np.empty(P)
    cdef long long[::1] offs = offs_a, fcv = fc_a, slots = slot_a
    cdef int[::1] halves = half_a
    cdef double[::1] pens = pen_a
    cdef const float[::1] ax = ax_a.astype(np.float32, copy=False)
    for i in range(P):
        slots[i] = _mod(added - P + i, S)
        halves[i] = near if narrow[i] else J
        pens[i] = pen_narrow if narrow[i] else pen_wide
        fcv[i] = _fit(corr, slots[i], c, _position(qq[i], ph), halves[i], pens[i])
    for k in range(K):
        if k == c:
            evidence[k] = 0.0
            differ[k] = 0.0
            differ_sq[k] = 0.0
            continue
        phk = 0
        v = ll[k, 0]
        for p in range(1, PHASES):
            if ll[k, p] > v:
                v, phk = ll[k, p], p
        d = 0.0
        d2 = 0.0
        for i in range(P):
            fc = fcv[i]
            fk = _fit(corr, slots[i], k, _position(qq[i], phk), halves[i], pens[i])
            o = offs[i]
            n = offs[i + 1] - o
            for j in range(n):
                if wrapped[c, fc + j % PACKET] != wrapped[k, fk + j % PACKET]:
                    d += ax[o + j]
                    d2 += ax[o + j] * <double>ax[o + j]
        evidence[k] = (top - v) / 2.0
        differ[k] = d
        differ_sq[k] = d2



cdef inline bint _near(double a, double b, double agree) noexcept nogil:
    """abs(wrap(a - b)) <= agree."""
    return fabs(_wrap(a - b)) <= agree


cdef bint _within(const double *vals, Py_ssize_t n, Py_ssize_t i, Py_ssize_t o, double agree) noexcept nogil:
    """Every value of group i (the values near vals[i]) is a value of group o."""
    cdef Py_ssize_t j, k
    cdef bint found
    for j in range(n):
        if not _near(vals[j], vals[i], agree):
            continue
        found = False
        for k in range(n):
            if vals[k] == vals[j] and _near(vals[k], vals[o], agree):
                found = True
                break
        if not found:
            return False
    return True


cdef object _consensus(dict d, object key, double agree):
    """The other lights' consensus of one frame's jitter measurements d {light: chips}: the
    median (statistics.median's: the middle one, or the mean of the middle two) of the largest
    group of measurements within `agree` chips of one of them (wrapped differences), the first
    such group in d's order; None when no other light measured it, or when another group of
    that size holds other values (a tie)."""
    cdef Py_ssize_t n = 0, m = len(d), i, j, l, best_i = 0, top = -1
    cdef double a, b, t
    cdef double *vals
    cdef Py_ssize_t *size
    if m == 0:
        return None
    vals = <double *>malloc(2 * m * sizeof(double))
    size = <Py_ssize_t *>malloc(m * sizeof(Py_ssize_t))
    try:
        for k, v in d.items():
            if k != key:
                vals[n] = v
                n += 1
        if n == 0:
            return None
        if n == 1:
            return vals[0]
        if n == 2:
            a, b = vals[0], vals[1]
            return (a + b) / 2 if _near(b, a, agree) or _near(a, b, agree) else None
        for i in range(n):
            size[i] = 0
            for j in range(n):
                size[i] += _near(vals[j], vals[i], agree)
            if size[i] > top:
                best_i, top = i, size[i]
        for i in range(n):
            if i != best_i and size[i] == top and not (_within(vals, n, i, best_i, agree)
                                                        and _within(vals, n, best_i, i, agree)):
                return None
        # the largest group's values, sorted (insertion), after the measurements in vals
        m = 0
        for j in range(n):
            if _near(vals[j], vals[best_i], agree):
                t = vals[j]
                l = m
                while l > 0 and vals[n + l - 1] > t:
                    vals[n + l] = vals[n + l - 1]
                    l -= 1
                vals[n + l] = t
                m += 1
        if m % 2 == 1:
            return vals[n + m // 2]
        return (vals[n + m // 2 - 1] + vals[n + m // 2]) / 2
    finally:
        free(vals)
        free(size)


def consensus(dict d, key, double agree):
    """`_consensus` (FrameJitter's consensus of frame d for light key)."""
    return _consensus(d, key, agree)


def estimates(dict by_frame, dict known_all, list ts, key, double agree):
    """Each frame stamp's consensus for light `key` (None where the frame has none), cached per
    frame and light in known_all {t: {key: estimate}} (the caller drops a frame's cache when
    it gets a measurement)."""
    out = []
    for t in ts:
        d = by_frame.get(t)
        if not d:
            out.append(None)
            continue
        known = known_all.get(t)
        if known is None:
            known = known_all[t] = {}
        v = known.get(key, known)
        if v is known:
            v = known[key] = _consensus(d, key, agree)
        out.append(v)
    return out
