"""Packets from short pieces placed by the frame times (PROTOCOL.md section 1: the stream is
periodic, so pieces of it seen in different frames belong to one packet).

A light whose image shows only a few chips per frame (5-10 kHz chips on a small or far panel:
6-13 chips) rarely shows the sync, and two frames' pieces rarely overlap enough to be aligned
by their chips. Their times place them instead: frame f's chip 0 sits at packet position

    s_f = phi + q_f + j_f (mod 54),   q_f = rate * t_f + Y_f / p,

with t_f the frame's timestamp, Y_f the image row where its chip 0 starts, p rows per chip,
phi the light's unknown packet phase and j_f the frame's start jitter in chips (the camera's
true frame start differs from its timestamp by about 100-200 us: one or two chips at 10 kHz).

The jitter is common to every light of a frame (one rolling shutter reads them all), so the
lights measure it for one another (`FrameJitter`): a light whose best (ID, phase) hypothesis is
strong finds where its piece fits best near phi + q_f, and posts the difference m_f = s_f -
q_f - phi. A piece is then placed at q_f + j_f, j_f the consensus of the *other* lights' m_f
(its own hypothesis never moves its own pieces), within +-1 chip and a steep penalty; a piece
of a frame no other light measured may sit up to `jitter_chips` either side of q_f with a mild
penalty per chip (a jitter of one or two chips is likelier than the window's edge; it also
denies wrong IDs the window's freedom).

The light's ID and phase are chosen by maximum likelihood over the map's IDs at this chip rate
(`candidates`) and phi: every piece contributes its best normalised correlation with the
candidate's packet within its window; the winner must correlate strongly on average
(`min_corr`), beat every other ID by `min_gap`, and its pieces must cover the whole packet.
"""

from __future__ import annotations

import math
import statistics
from collections import deque

import numpy as np
from numpy.lib.stride_tricks import as_strided, sliding_window_view

PACKET_LEN = 54
# Sub-chip steps of the packet phase phi searched.
PHASE_STEPS = 4


def _wrap(x: float) -> float:
    """x chips wrapped into [-27, 27)."""
    return (x + PACKET_LEN / 2) % PACKET_LEN - PACKET_LEN / 2


class FrameJitter:
    """Per-frame start jitter (chips) of one chip rate, measured by the lights of the frame.

    `post(t, key, m)`: light `key` measured m chips (wrapped to +-27) in the frame stamped t;
    `estimate(t, key)`: the consensus of the other lights' measurements of that frame, or
    None. The consensus is the median of the largest group of measurements within
    `agree_chips` of one another; a tie between groups (two lights that disagree) gives none.
    Only the last `frames` frames (the newest stamps) are kept.
    `wanted()`: a light still without its ID asked for an estimate within the last
    `want_frames` frames measured: only then do lights whose ID is known need measuring."""

    def __init__(self, *, frames: int = 64, agree_chips: float = 0.75, want_frames: int = 8):
        self.frames = frames
        self.agree = agree_chips
        self.want_frames = want_frames
        self.by_frame: dict = {}
        self._known: dict = {}  # t -> {key: estimate}, dropped when frame t gets a measurement
        self._since_want: int | None = None  # frames measured since a light without ID asked

    def post(self, t: float, key: int, m: float) -> None:
        d = self.by_frame.get(t)
        if d is None:
            d = self.by_frame[t] = {}
            if self._since_want is not None:
                self._since_want += 1
            if len(self.by_frame) > self.frames:
                for old in sorted(self.by_frame)[:len(self.by_frame) - self.frames]:
                    del self.by_frame[old]
                    self._known.pop(old, None)
        d[key] = _wrap(float(m))
        self._known.pop(t, None)

    def wanted(self) -> bool:
        return self._since_want is not None and self._since_want <= self.want_frames

    def want(self) -> None:
        """A light without its ID shows a piece this frame: the others' measurements are needed."""
        self._since_want = 0

    def estimate(self, t: float, key: int) -> float | None:
        d = self.by_frame.get(t)
        if not d:
            return None
        known = self._known.setdefault(t, {})
        if key not in known:
            known[key] = self._consensus(d, key)
        return known[key]

    def _consensus(self, d: dict, key: int) -> float | None:
        vals = [m for k, m in d.items() if k != key]
        if not vals:
            return None
        if len(vals) == 1:
            return vals[0]
        if len(vals) == 2:  # (the groups below for two: both or a tie; the median is the mean)
            a, b = vals
            ok = abs(_wrap(b - a)) <= self.agree or abs(_wrap(a - b)) <= self.agree
            return (a + b) / 2 if ok else None
        groups = [[v for v in vals if abs(_wrap(v - u)) <= self.agree] for u in vals]
        sizes = sorted((len(g) for g in groups), reverse=True)
        best = max(groups, key=len)
        if sizes[0] == sizes[1] and any(len(g) == sizes[0] and set(g) != set(best) for g in groups):
            return None
        return float(statistics.median(best))


class _Piece:
    """One frame's piece: weighted chips x, weight den, packet time q, frame stamp t, its slot
    in the light's correlation tables; its (K, 54) correlations `corr` (views of those tables
    once computed), its latest placement, and the slice its term in the likelihood table was
    made with."""

    __slots__ = ("x", "den", "q", "t", "n", "slot", "corr", "used", "term")

    def __init__(self, x: np.ndarray, q: float, t: float, slot: int):
        self.x, self.den, self.q, self.t, self.n, self.slot = x, float(np.abs(x).sum()), q, t, x.size, slot
        self.corr = None
        self.used: tuple | None = None  # (placed q, narrow?) of the latest decision
        self.term: tuple | None = None  # (slice start, narrow?) of the piece's term in ll


def _windowed(corr: np.ndarray, half: int, penalty: float) -> np.ndarray:
    """The best of `corr` within +-half positions of each (cyclically), `penalty` off per
    position away: the maximum over a sliding window (a strided view) of corr with `half`
    columns of the other end on each side, each shift less its penalty."""
    if half <= 0:
        return corr.copy()
    k, n = corr.shape
    ext = np.concatenate((corr[:, n - half:], corr, corr[:, :half]), axis=1)
    shifts = as_strided(ext, (k, 2 * half + 1, n), (ext.strides[0], ext.strides[1], ext.strides[1]),
                        writeable=False)  # [:, i] = ext[:, i:i + n]
    pens = (penalty * np.abs(np.arange(-half, half + 1))).astype(corr.dtype)
    return (shifts - pens[None, :, None]).max(axis=1)


class PieceAssembler:
    """One light's recent pieces and the ML choice of its ID among `candidates`.

    templates: (K, 54) +-1 packets of the candidate IDs `ids` (K,). shift_penalty: correlation
    taken off per chip a piece sits away from its timestamp's place when its frame's jitter is
    unknown; timed_penalty: the same, within +-1 chip, when the other lights measured it.
    jitter: the `FrameJitter` shared by the lights of this rate (None: every piece by its
    timestamp alone). ref_corr / ref_gap: a light whose best hypothesis has this mean
    correlation and gap measures the jitter for the others (an accepted one always does);
    ref_match: its piece must fit there this well, and ref_unique better than elsewhere in
    its window."""

    _next_key = 0

    def __init__(self, ids: np.ndarray, templates: np.ndarray, *, jitter_chips: int, history: int,
                 min_frames: int, min_corr: float, min_gap: float, shift_penalty: float = 0.2,
                 jitter: FrameJitter | None = None, timed_penalty: float = 1.0, ref_corr: float = 0.75,
                 ref_gap: float = 0.1, ref_match: float = 0.75, ref_unique: float = 0.3):
        self.ids = np.asarray(ids)
        self.templates = np.asarray(templates, dtype=np.float32)
        self._wrapped = None if self.templates.size == 0 else np.concatenate(
            (self.templates, self.templates), axis=1)  # the packets twice: cyclic windows as slices
        # (K, 55, 54): [:, k] is the packets' window from chip k on
        self._windows = None if self._wrapped is None else sliding_window_view(self._wrapped, PACKET_LEN, axis=1)
        # a window of half the packet or more would meet itself round the cycle
        self.jitter_chips = min(int(jitter_chips), PACKET_LEN // 2 - 1)
        self.history = history
        self.pieces: deque = deque()
        self.min_frames = min_frames
        self.min_corr = min_corr
        self.min_gap = min_gap
        self.shift_penalty = shift_penalty
        self.timed_penalty = timed_penalty
        self.frame_jitter = jitter
        self.ref_corr, self.ref_gap, self.ref_match, self.ref_unique = ref_corr, ref_gap, ref_match, ref_unique
        PieceAssembler._next_key += 1
        self.key = PieceAssembler._next_key
        self.phis = np.arange(PACKET_LEN * PHASE_STEPS) / PHASE_STEPS
        self.ll: np.ndarray | None = None  # sum over pieces of weight * best[:, s(phi)] (K, 54 * steps)
        self.total = 0.0
        self.score = 0.0  # the latest decision's mean correlation, gap and best ID (diagnostics)
        self.gap = 0.0
        self.best_id: int | None = None
        self.timed = 0  # pieces of the latest decision placed by the other lights' jitter
        self.added = 0  # pieces added so far
        # per piece slot (history + 1 of them, `_Piece.slot`): its correlations (slots, K, 54);
        # their best within the wide [0] and the narrow [1] window repeated for the phases
        # (`_rep`, (2, slots, K, 2 * 54 * steps)), and `_best` (2, slots, K, 54) a view of it
        self._corr: np.ndarray | None = None
        self._rep: np.ndarray | None = None
        self._best: np.ndarray | None = None
        self._evicted: list = []  # terms of dropped pieces not yet taken back
        self._placed: tuple = ()  # (placed q, narrow?, slot) of the pieces at the latest update

    def _slots(self, q, ph=None) -> np.ndarray:
        """Packet position of a piece's chip 0 (q: packet time, or an array of them) under every
        phase hypothesis, or under phase index `ph` alone."""
        phi = self.phis if ph is None else self.phis[ph]
        return np.floor(q + phi + 0.5).astype(np.int64) % PACKET_LEN

    def add(self, soft: np.ndarray, cw: np.ndarray, q: float, t: float | None = None) -> None:
        """Keep a piece (soft chips, weights, packet time q, frame stamp t); its correlations
        with the candidates are computed once `min_frames` pieces are there (a light that shows
        a short piece for a frame or two, entering the image, costs nothing)."""
        x = (np.clip(soft, -1.0, 1.0) * cw).astype(np.float32)
        if float(np.abs(x).sum()) <= 0 or self.ids.size == 0:
            return
        self.added += 1
        if len(self.pieces) >= self.history:
            if self._evicted:  # its table slot comes round again below: take its term back now
                self._terms(self._evicted)
                self._evicted = []
            old = self.pieces.popleft()
            if old.term is not None:
                self._evicted.append((old, *old.term, -1.0))
        # history + 1 slots: the piece just dropped keeps its slot until its term is taken back
        self.pieces.append(_Piece(x, float(q) % PACKET_LEN, q if t is None else float(t),
                                  (self.added - 1) % (self.history + 1)))

    def _correlate(self, p: _Piece) -> None:
        if self._corr is None:
            slots = self.history + 1
            self._corr = np.empty((slots, self.ids.size, PACKET_LEN), np.float32)
            self._rep = np.empty((2, slots, self.ids.size, 2 * PACKET_LEN * PHASE_STEPS), np.float32)
            self._best = self._rep[..., 0:PACKET_LEN * PHASE_STEPS:PHASE_STEPS]
        # (K, 54): the piece at each packet position, sum_k x_k T[:, (s + k) % 54], all the products
        # at once (K, n, 54) summed over k (a reduction over an outer axis adds its slices in order)
        corr = np.add.reduce(self._windows[:, :p.n] * p.x[None, :, None], axis=1)
        corr /= p.den
        self._corr[p.slot] = corr
        best = np.stack((_windowed(corr, self.jitter_chips, self.shift_penalty),
                         _windowed(corr, min(1, self.jitter_chips), self.timed_penalty)))
        # each packet position's best repeated for its PHASE_STEPS phases, twice round: any
        # placement's (K, 54 * PHASE_STEPS) term is a slice (`_start`)
        rep = self._rep[:, p.slot]
        half = PACKET_LEN * PHASE_STEPS
        rep[..., :half] = np.repeat(best, PHASE_STEPS, axis=2)
        rep[..., half:] = rep[..., :half]
        p.corr = self._corr[p.slot]

    def _start(self, qq: float) -> int:
        """The phase table's slice start of a piece placed at qq: weight * best[:, s(phi)] for
        every phase phi, where s(phi) = floor(qq + phi + 1/2) % 54 (`_slots`), is the slice
        from floor(PHASE_STEPS (qq + 1/2)) on of its repeated table (`_rep`; placements with
        one start give one term)."""
        return int(math.floor(PHASE_STEPS * (qq + 0.5))) % self.phis.size

    def _terms(self, terms: list) -> None:
        """Add (sign +1) or take back (-1) pieces' terms, in order: each (piece, slice start m
        (`_start`), narrow?, sign) adds sign * weight times the slice from m of its narrow or
        wide repeated table. (A reduction over the outer axis adds its slices in order: the
        same sums as one term at a time.)"""
        if not terms:
            return
        n = self.phis.size
        parts, coef = [], []
        for p, m, narrow, sign in terms:
            parts.append(self._rep[int(narrow), p.slot, :, m:m + n])
            coef.append(sign * p.den)
            self.total += sign * p.den
        scaled = np.concatenate(parts).reshape(len(terms), self.ids.size, n)  # (T, K, 54 * steps)
        scaled *= np.array(coef, np.float32)[:, None, None]
        self.ll = np.add.reduce(np.concatenate((self.ll[None], scaled)), axis=0)

    def _place(self, p: _Piece) -> tuple[float, bool]:
        """(packet time, narrow window?) of a piece: its frame's jitter as the others measured it."""
        j = None if self.frame_jitter is None else self.frame_jitter.estimate(p.t, self.key)
        return (p.q, False) if j is None else (p.q + j, True)

    def _update(self) -> None:
        """Bring the likelihood table up to the pieces' current placements."""
        if self.ll is None:  # made once needed: most lights never show enough short pieces
            self.ll = np.zeros((self.ids.size, self.phis.size))
        timed = 0
        changes, self._evicted = self._evicted, []
        qqs, narrows = [], []
        for p in self.pieces:
            if p.corr is None:
                self._correlate(p)
            p.used = qq, narrow = self._place(p)
            qqs.append(qq)
            narrows.append(narrow)
            timed += narrow
            term = (self._start(qq), narrow)
            if term != p.term:
                if p.term is not None:
                    changes.append((p, *p.term, -1.0))
                changes.append((p, *term, 1.0))
                p.term = term
        self._terms(changes)
        self.timed = timed
        self._placed = (np.array(qqs), np.array(narrows, np.intp), np.array([p.slot for p in self.pieces]))

    def _fits(self, c: int, ph: int) -> tuple[np.ndarray, np.ndarray]:
        """(placed q, packet position where the piece fits best in its window) per piece, (P,)
        each, under hypothesis (candidate c, phase index ph); the window's correlations are the
        penalised ones (the place the score used)."""
        J = self.jitter_chips
        qq, narrow, slots = self._placed
        offs = np.arange(-J, J + 1)
        window = (self._slots(qq, ph)[:, None] + offs[None, :]) % PACKET_LEN  # (P, 2 J + 1)
        rows = np.arange(qq.size)[:, None]
        vals = self._best[narrow, slots, c][rows, window]
        vals[(narrow[:, None] != 0) & (np.abs(offs) > min(1, J))[None, :]] = -np.inf  # narrow: +-1 chip
        return qq, window[rows[:, 0], np.argmax(vals, axis=1)]

    def decide(self, fixed: int | None = None) -> int | None:
        """The ID of the best (ID, phase) hypothesis when it passes the checks, else None.
        fixed: the light's ID when already known (then only its phase is followed, and the
        light measures the jitter of its latest frame for the others)."""
        if len(self.pieces) < self.min_frames:
            return None
        self._update()
        if self.total <= 0:
            return None
        mean = self.ll / self.total
        row = None
        if fixed is not None:
            hit = np.flatnonzero(self.ids == fixed)
            if hit.size == 0:
                return None
            row = int(hit[0])
            c, ph = row, int(np.argmax(mean[row]))
        else:
            c, ph = np.unravel_index(int(np.argmax(mean)), mean.shape)
        top = float(mean[c, ph])
        second = -1.0
        if self.ids.size > 1:
            row_best = mean.max(axis=1)
            row_best[c] = -np.inf
            second = float(row_best.max())
        self.score, self.gap, self.best_id = top, top - second, int(self.ids[c])
        if fixed is not None or (top >= self.ref_corr and top - second >= self.ref_gap):
            self._post(int(c), int(ph))
        if fixed is not None or top < self.min_corr or top - second < self.min_gap:
            return None
        # the winner's pieces, each where it fits best in its window, must cover the packet
        seen = np.zeros(PACKET_LEN, bool)
        for p, at in zip(self.pieces, self._fits(int(c), int(ph))[1].tolist()):
            seen[(at + np.arange(p.n)) % PACKET_LEN] = True
        return int(self.ids[c]) if seen.all() else None

    def _post(self, c: int, ph: int) -> None:
        """Measure the frame jitter of each kept piece's frame under hypothesis (c, ph) for the
        other lights (the latest hypothesis restates the earlier frames too: pieces that came
        before any light was sure get placed once one is): where the piece fits the packet
        near its timestamp's place, against this light's continuous phase (the mean of its
        pieces' fitted positions about their placements)."""
        if self.frame_jitter is None:
            return
        base = self.phis[ph]
        qq, at = self._fits(c, ph)
        phi = base + float(np.mean(_wrap(at - qq - base)))
        J = self.jitter_chips
        pieces = list(self.pieces)
        # every piece's window about its timestamp's place under phase ph: (pieces, 2 J + 1)
        qs = np.array([p.q for p in pieces])
        starts = self._slots(qs, ph)
        window = (starts[:, None] + np.arange(-J, J + 1)[None, :]) % PACKET_LEN
        rows = np.arange(len(pieces))
        vals = self._corr[self._placed[2], c][rows[:, None], window]
        i = np.argmax(vals, axis=1)
        top = vals[rows, i]
        if J > 0:
            vals[rows, i] = -np.inf
            other = vals.max(axis=1)
        else:
            other = np.full(len(pieces), -1.0)
        at = window[rows, i].tolist()
        for k in np.flatnonzero((top >= self.ref_match) & (top - other >= self.ref_unique)).tolist():
            p = pieces[k]
            self.frame_jitter.post(p.t, self.key, _wrap(float(at[k]) - p.q - phi))


def jitter_chips(jitter_us: float, rate_hz: float) -> int:
    """Chips either side a piece may sit off its timestamp's place."""
    return int(math.ceil(jitter_us * rate_hz * 1e-6))


def frames_needed(chips_a_frame: float, min_frames: int) -> int:
    """Fewest frames of one light from which its packet can be pieced together: its pieces must
    cover the 54 chips, and the ML choice waits for `min_frames` of them."""
    return max(int(math.ceil(PACKET_LEN / max(chips_a_frame, 1e-9))), int(min_frames))


def chips_verdict(chips_a_frame: float, rate_hz: float, *, max_chips: float, min_frames: int,
                  mapped: bool) -> tuple[bool, str]:
    """(readable, text) for lights whose images show `chips_a_frame` chips of `rate_hz` OOK chips
    a frame: whether one frame can hold a whole packet, how many frames an ID needs, and the chip
    rate or image height that would read the packets from their own chips (more than
    `max_chips` chips a frame; fewer are pieced together by the frame times, which needs the
    map's IDs: `mapped`)."""
    c = float(chips_a_frame)
    khz = rate_hz / 1000.0
    head = (f"the lights' images show {c:.0f} chips a frame (median) of the {khz:g} kHz OOK chips, "
            f"a packet is {PACKET_LEN}")
    if c >= PACKET_LEN:
        return True, f"{head}: one frame holds a whole packet"
    if c > max_chips:
        return True, (f"{head}: no single frame holds a packet; it is assembled from the overlaps of at least "
                      f"{int(math.ceil(PACKET_LEN / c))} frames of each light")
    more = max_chips / max(c, 1e-9)
    fix = (f"more than {max_chips:g} chips a frame (chips at > {rate_hz * more / 1000:.0f} kHz, or lights "
           f"{more:.1f}x taller in the image) are read from their own chips")
    if not mapped:
        return False, (f"{head}: no single frame holds a packet, and pieces this short are placed only among the "
                       f"map's IDs (addressing \"map\"): no ID can be read; {fix}")
    return True, (f"{head}: no single frame holds a packet; its IDs are pieced together by the frame times over "
                  f"at least {frames_needed(c, min_frames)} frames of each light; {fix}")
