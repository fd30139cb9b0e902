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
(`min_corr`), its pieces must show the packet's bits (either chip of a Manchester pair shows its
bit; all but `MAX_UNSEEN_BITS`: `bits_seen`), and it must beat every other ID on the chips where
their two packets differ, by the chips' agreement and by the evidence in noise sds
(`PieceAssembler._beats_rivals`): two packets at the code's least distance differ in 8 of 54
chips, so a test over all chips (a flat gap of mean correlations) could not tell them apart.
"""

from __future__ import annotations

import functools
import math
from collections import deque

import numpy as np

from firmware_tx.crc import crc8
from firmware_tx.framing import SYNC
from receiver.core.native import require

# the compiled tables (receiver/decode/_pieces.pyx): the one implementation of the likelihood
_k = require("receiver.decode._pieces")

PACKET_LEN = 54
SYNC_LEN = len(SYNC)  # the packet's sync chips; then 24 Manchester bits, two chips each (PROTOCOL.md)
# Any two packets' 24 bits (16 ID + CRC-8) differ in at least this many (a linear code: the
# least weight of a nonzero ID's bits; tests/decode/test_ook_pieces.py enumerates them).
CRC_MIN_DISTANCE_BITS = 4
# Bits of the winner's packet its pieces may leave unseen: with one, every other packet, of the
# map or not, still differs from the winner in at least 3 seen bits (6 chips).
MAX_UNSEEN_BITS = 1
# Sub-chip steps of the packet phase phi searched.
PHASE_STEPS = 4
assert (_k.PACKET_LEN, _k.PHASE_STEPS) == (PACKET_LEN, PHASE_STEPS)


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
        self.sure: set = set()  # the lights that posted with their ID accepted (`post_all`'s sure)
        self._known: dict = {}  # t -> {key: estimate}, dropped when frame t gets a measurement
        self._since_want: int | None = None  # frames measured since a light without ID asked

    def post(self, t: float, key: int, m: float) -> None:
        self.post_all(key, [(t, m)])

    def post_all(self, key: int, measured: list, sure: bool = False) -> None:
        """`post` each (t, m) of `measured` in order; `sure`: light `key` has its ID."""
        if sure:
            self.sure.add(key)
        by_frame, known = self.by_frame, self._known
        for t, m in measured:
            d = by_frame.get(t)
            if d is None:
                d = by_frame[t] = {}
                if self._since_want is not None:
                    self._since_want += 1
                if len(by_frame) > self.frames:
                    for old in sorted(by_frame)[:len(by_frame) - self.frames]:
                        del by_frame[old]
                        known.pop(old, None)
            d[key] = _wrap(float(m))
            known.pop(t, None)

    def wanted(self) -> bool:
        return self._since_want is not None and self._since_want <= self.want_frames

    def want(self) -> None:
        """A light without its ID shows a piece this frame: the others' measurements are needed."""
        self._since_want = 0

    def estimate(self, t: float, key: int) -> float | None:
        return self.estimates([t], key)[0]

    def by_sure(self, t: float, key: int, est: float | None) -> bool:
        """Whether a light other than `key` that has its ID measured frame t within
        `agree_chips` of the estimate `est`."""
        d = self.by_frame.get(t)
        if d is None or est is None:
            return False
        return any(k != key and k in self.sure and abs(_wrap(m - est)) <= self.agree for k, m in d.items())

    def estimates(self, ts: list, key: int) -> list:
        """`estimate` of each frame stamp in ts (one call for a light's pieces; the consensus
        is the compiled kernel's, receiver/decode/_pieces.pyx)."""
        return _k.estimates(self.by_frame, self._known, ts, key, self.agree)


class Candidates:
    """The candidate IDs of one map and chip rate with what every light's `PieceAssembler`
    reads of them, made once and shared: `ids` (K,) int64, `templates` (K, 54) float32 +-1
    packets, `wrapped` (K, 108) the packets twice (cyclic windows as slices) and `row` {ID:
    its first row}."""

    __slots__ = ("ids", "templates", "wrapped", "row")

    def __init__(self, ids: np.ndarray, templates: np.ndarray):
        self.ids = np.asarray(ids)
        self.templates = np.asarray(templates, dtype=np.float32).reshape(-1, PACKET_LEN)
        self.wrapped = np.ascontiguousarray(np.concatenate((self.templates, self.templates), axis=1))
        self.row = {int(v): i for i, v in reversed(list(enumerate(self.ids.tolist())))}

    def __len__(self) -> int:
        return int(self.ids.size)


class _Piece:
    """One frame's piece: weighted chips x, weight den, packet time q, frame stamp t, its slot
    in the light's tables (the a-th piece added sits in slot (a - 1) % history, the slot of the
    piece it drops)."""

    __slots__ = ("x", "den", "q", "t", "n", "slot")

    def __init__(self, x: np.ndarray, den: float, q: float, t: float, slot: int):
        self.x, self.den, self.q, self.t, self.n, self.slot = x, den, q, t, x.size, slot


class PieceAssembler:
    """One light's recent pieces and the ML choice of its ID among `candidates`.

    ids: the candidate IDs (K,), templates their (K, 54) +-1 packets; or ids a `Candidates`
    (the tables of many lights, made once) and templates None. shift_penalty: correlation
    taken off per chip a piece sits away from its timestamp's place when its frame's jitter is
    unknown; timed_penalty: the same, within +-1 chip, when the other lights measured it.
    jitter: the `FrameJitter` shared by the lights of this rate (None: every piece by its
    timestamp alone). ref_corr / ref_gap: a light whose best hypothesis has this mean
    correlation and gap measures the jitter for the others (an accepted one always does);
    ref_match: its piece must fit there this well, and ref_unique better than elsewhere in
    its window.

    The tables and their sums are the compiled kernel receiver/decode/_pieces.pyx (the one
    implementation): per piece slot its correlations with the candidates `_corr` (slots, K,
    54) and their best within the wide [0] and the narrow [1] window, each position repeated
    for its PHASE_STEPS phases twice round, `_rep` (2, slots, K, 2 * 54 * PHASE_STEPS): a
    piece placed at packet time qq adds weight times the slice from floor(PHASE_STEPS (qq +
    1/2)) % (54 PHASE_STEPS) of it to the likelihood table `ll` (K, 54 PHASE_STEPS), its
    score at every phase phi (position floor(qq + phi + 1/2) % 54), and a piece whose
    placement moves has its old slice taken back."""

    _next_key = 0

    def __init__(self, ids: np.ndarray | Candidates, templates: np.ndarray | None = None, *, jitter_chips: int,
                 history: int,
                 min_frames: int, min_corr: float, min_agree: float, min_z: float, shift_penalty: float = 0.2,
                 jitter: FrameJitter | None = None, timed_penalty: float = 1.0, ref_corr: float = 0.75,
                 ref_gap: float = 0.1, ref_match: float = 0.75, ref_unique: float = 0.3):
        cands = ids if isinstance(ids, Candidates) else Candidates(ids, templates)
        self.ids, self.templates = cands.ids, cands.templates
        self._row = cands.row  # ID -> first row
        self._wrapped = cands.wrapped  # the packets twice: cyclic windows as slices
        # a window of half the packet or more would meet itself round the cycle
        self.jitter_chips = min(int(jitter_chips), PACKET_LEN // 2 - 1)
        self.history = history
        self.pieces: deque = deque()
        self.min_frames = min_frames
        self.min_corr = min_corr
        self.min_agree, self.min_z = min_agree, min_z
        self.shift_penalty = shift_penalty
        self.timed_penalty = timed_penalty
        self.frame_jitter = jitter
        self.ref_corr, self.ref_gap, self.ref_match, self.ref_unique = ref_corr, ref_gap, ref_match, ref_unique
        PieceAssembler._next_key += 1
        self.key = PieceAssembler._next_key
        self.ll: np.ndarray | None = None  # sum over pieces of weight * best[:, s(phi)] (K, 54 * steps)
        self.total = 0.0
        self.score = 0.0  # the latest decision's mean correlation, gap and best ID (diagnostics)
        self.gap = 0.0
        self.best_id: int | None = None
        self.agree = self.z = float("nan")  # ... the least agreement and evidence (sds) over its rivals
        self.timed = 0  # pieces of the latest decision placed by the other lights' jitter
        self.added = 0  # pieces added so far
        self._fresh = 0  # the newest pieces whose correlations are not computed yet
        # per slot: the piece's weight and packet time, its term's slice start in ll (-1: none)
        # and window (1: narrow)
        self._den = np.zeros(history)
        self._q = np.zeros(history)
        self._term_m = np.full(history, -1, np.int64)
        self._term_n = np.zeros(history, np.int64)
        self._qq = np.zeros(history)  # the latest update's placements (packet time, narrow?)
        self._narrow = np.zeros(history, np.uint8)
        self._at = np.zeros(history, np.int64)
        self._corr: np.ndarray | None = None
        self._rep: np.ndarray | None = None

    def add(self, soft: np.ndarray, cw: np.ndarray, q: float, t: float | None = None) -> None:
        """Keep a piece (soft chips, weights, packet time q, frame stamp t); its correlations
        with the candidates are computed once `min_frames` pieces are there (a light that shows
        a short piece for a frame or two, entering the image, costs nothing)."""
        x = (np.clip(soft, -1.0, 1.0) * cw).astype(np.float32)
        den = float(np.abs(x).sum())
        if den <= 0 or self.ids.size == 0:
            return
        self.added += 1
        if len(self.pieces) >= self.history:  # the oldest piece goes, its term taken back
            old = self.pieces.popleft()
            if self.ll is not None:
                self.total = _k.take_back(self.ll, self._rep, self._den, self._term_m, self._term_n,
                                          old.slot, self.total)
        p = _Piece(x, den, float(q) % PACKET_LEN, q if t is None else float(t), (self.added - 1) % self.history)
        self.pieces.append(p)
        self._den[p.slot], self._q[p.slot] = p.den, p.q
        self._fresh = min(self._fresh + 1, len(self.pieces))

    def _correlate(self, p: _Piece) -> None:
        """The piece's correlations and their windowed best into its slot of the tables."""
        if self._corr is None:
            self._corr = np.empty((self.history, self.ids.size, PACKET_LEN), np.float32)
            self._rep = np.empty((2, self.history, self.ids.size, 2 * PACKET_LEN * PHASE_STEPS), np.float32)
        _k.correlate(self._wrapped, p.x, p.den, self._corr, self._rep, p.slot, self.jitter_chips,
                     self.shift_penalty, min(1, self.jitter_chips), self.timed_penalty)

    def _update(self) -> None:
        """Bring the likelihood table up to the pieces' current placements: each at its frame's
        jitter as the other lights measured it (narrow window), else at its timestamp's place."""
        if self.ll is None:  # made once needed: most lights never show enough short pieces
            self.ll = np.zeros((self.ids.size, PACKET_LEN * PHASE_STEPS))
        for i in range(len(self.pieces) - self._fresh, len(self.pieces)):
            self._correlate(self.pieces[i])
        self._fresh = 0
        fj = self.frame_jitter
        ts = [p.t for p in self.pieces]
        js = [None] * len(ts) if fj is None else fj.estimates(ts, self.key)
        self.total, self.timed = _k.update(self.ll, self._rep, self._den, self._q, self._term_m, self._term_n,
                                           js, self.added, self.total, self._qq, self._narrow)

    def decide(self, fixed: int | None = None, near: tuple = ()) -> int | None:
        """The ID of the best (ID, phase) hypothesis when it passes the checks, else None.
        fixed: the light's ID when already known (then only its phase is followed, and the
        light measures the jitter of its latest frame for the others). near: the map IDs the
        tracked pose puts where this light is (receiver.locate.map_prior), tested by
        `_decide_near` when the choice among all candidates does not pass."""
        if len(self.pieces) < self.min_frames:
            return None
        self._update()
        if self.total <= 0:
            return None
        row = -1
        if fixed is not None:
            row = self._row.get(fixed, -1)
            if row < 0:
                return None
        c, ph, top, second = _k.choose(self.ll, self.total, row)
        self.score, self.gap, self.best_id = top, top - second, int(self.ids[c])
        if fixed is not None or (top >= self.ref_corr and top - second >= self.ref_gap):
            self._post(c, ph, fixed is not None)
        self.agree = self.z = float("nan")
        if fixed is not None:
            return None
        # the winner's pieces, each where it fits best in its window, must show every bit
        if top >= self.min_corr and bits_seen(self._seen(c, ph)) and self._beats_rivals(c, ph):
            return int(self.ids[c])
        return self._decide_near(near, c, ph, top, second) if near else None

    def _seen(self, c: int, ph: int) -> np.ndarray:
        """The packet positions (54,) the pieces cover under hypothesis (c, ph), each piece
        where it fits best in its window (its fitted start in `_at`)."""
        P = len(self.pieces)
        _k.fits(self._rep, self._qq, self._narrow, P, self.added, c, ph, self.jitter_chips, self._at)
        # packet position s is covered by a piece fitted at `at` with n chips when (s - at) % 54 < n
        n = np.array([p.n for p in self.pieces])
        return ((np.arange(PACKET_LEN)[None, :] - self._at[:P, None]) % PACKET_LEN < n[:, None]).any(axis=0)

    def _decide_near(self, near: tuple, c: int, ph: int, top: float, second: float) -> int | None:
        """Candidate c (at phase index ph, mean correlation top; the other candidates' best
        second), the choice among all K candidates, when it is one of `near` (the k map IDs the
        pose allows here) and its pieces confirm it, else None.

        The choice among all candidates guards against K x phases hypotheses with every bit but
        `MAX_UNSEEN_BITS` seen: a packet unrelated to the winner matches its seen bits at one
        phase with probability 2^-seen, so its bound is K x phases x 2^-(24 - MAX_UNSEEN_BITS).
        Among k IDs the same bound holds with log2(K / k) fewer bits seen
        (`unseen_bits_allowed`), and the pieces must confirm c against such a packet by the
        rivals' agreement and evidence. That bound is for packets unrelated to c; the packets
        nearest c (its twins, of the map or not) are tested one by one: the chips seen must
        tell c from every other packet, at c's phase and at every other, and agree with c where
        the two differ (`_beats_every_packet`), so a light whose packet is c's twin but for bits
        unseen, or c's but for a few chips once moved by a pair (0xfff3 a pair later is 0x7ff9
        but for 4 chips), is never given c. The pieces must still choose c: it must be the
        strict best of all K candidates (a map ID outside `near` that fits them as well or
        better refuses it: the pose never picks between IDs the chips cannot tell apart),
        correlate by `min_corr`, and beat each other ID of `near` by the rivals' test."""
        rows = sorted({self._row[v] for v in near if v in self._row})
        if c not in rows or top < self.min_corr or not top > second:
            return None
        if not bits_seen(self._seen(c, ph), unseen_bits_allowed(self.ids.size, len(rows))):
            return None
        if not self._beats_every_packet(c):
            return None
        if len(rows) > 1 and not self._beats_rivals(c, ph, rows):
            return None
        return int(self.ids[c])

    def _beats_every_packet(self, c: int) -> bool:
        """Whether the pieces, where `_seen` fitted them (`_at`), confirm candidate c's packet
        against a packet unrelated to it, and tell it from every other packet there is (65,535:
        the map's IDs and all others) at those placements.

        Per bit b of the packet, its chips' sums e_b of x times c's chip, v_b of x squared and
        d_b of |x|. An unrelated packet's bits are c's or their complements at random, each
        Manchester bit's two chips together: with y_b = e_b, E = sum y_b has mean 0 and sd
        sqrt(sum y_b^2) under it; c needs E / sum d_b >= `min_agree` and E / sqrt(sum y_b^2) >=
        `min_z` (the rivals' test, against that null). Another packet differs from c in the
        bits of a nonzero code word w: c needs a chip of those bits seen (w . d > 0: the chips
        can tell the two apart, `shows_every_difference`) and the rivals' agreement there,
        w . e >= `min_agree` w . d, met by every w when every bit's is (else tried on all; a
        light sending c's twin, which differs from c in a bit or two, shows those chips against
        c: agreement about -1). That test reads only the pieces placed by the frame jitter
        that other lights with their IDs measured (the narrow window, `FrameJitter.by_sure`), or
        with no window at all: a piece free to move a chip within its wide window, or placed by
        a jitter that lights without their IDs measured under a wrong hypothesis, can read a
        Manchester pair's bit as its neighbour's, and so fit a twin's chips to c's. The same
        pinned chips must tell c from every other packet sent at any other phase, agreeing with c
        where they differ (`beats_every_shifted_packet`): the light's phase is only c's best,
        and all pieces moved together by a pair fit a packet whose copy a pair later is c's but
        for chips they left unseen or read against c."""
        P = len(self.pieces)
        tpl = self.templates[c]
        fj = self.frame_jitter
        if self.jitter_chips and fj is not None:  # the pieces placed by the jitter lights with an ID measured
            ts = [p.t for p in self.pieces]
            pinned = [bool(nar) and fj.by_sure(t, self.key, j)
                      for t, j, nar in zip(ts, fj.estimates(ts, self.key), self._narrow[:P].tolist())]
        else:
            pinned = [not self.jitter_chips] * P
        e, d = np.zeros((2, PACKET_LEN)), np.zeros((2, PACKET_LEN))  # [0] every piece, [1] the pinned ones
        for p, at, pin in zip(self.pieces, self._at[:P].tolist(), pinned):
            pos = (at + np.arange(p.n)) % PACKET_LEN
            x = p.x.astype(np.float64)
            for k in range(1 + pin):
                np.add.at(e[k], pos, x * tpl[pos])
                np.add.at(d[k], pos, np.abs(x))
        yb, db = e[:, SYNC_LEN::2] + e[:, SYNC_LEN + 1::2], d[:, SYNC_LEN::2] + d[:, SYNC_LEN + 1::2]  # (2, 24)
        E, V, D = float(yb[0].sum()), float((yb[0] * yb[0]).sum()), float(db[0].sum())
        if V <= 0 or E < self.min_agree * D or E * E < self.min_z ** 2 * V or E <= 0:
            return False
        if not shows_every_difference(db[1] > 0):
            return False
        a = yb[1] - self.min_agree * db[1]  # a packet differing in bits w: agreement met when w . a >= 0
        if not ((a >= 0).all() or (_code_bits() @ a.astype(np.float32)).min() >= 0):
            return False
        return beats_every_shifted_packet(tpl > 0, e[1] - self.min_agree * d[1], d[1] > 0, int(self.ids[c]))

    def _beats_rivals(self, c: int, ph: int, rows: list | None = None) -> bool:
        """Whether hypothesis (c, ph) beats every other candidate k, at k's own best phase and
        fits, on the chips where their two packets differ (`_pieces.rivals`): half the table's
        gap is the evidence E_k = sum of x times c's chip over those chips (less half the window
        penalties' difference), D_k = sum of |x| over them. A soft chip is the chip plus noise,
        so E_k is the log-likelihood ratio of c over k up to the noise variance; with chips
        that tell c from k no better than chance (each term +-|x| at random) it is about 0
        with sd sqrt(V_k), V_k the sum of x squared over those chips. The
        winner needs, against every rival, agreement E_k / D_k >= `min_agree` and evidence
        E_k / sqrt(V_k) >= `min_z`. Sets `agree` and `z`: their least over the rivals (over
        the candidates of `rows` only when given: those the pose allows, `_decide_near`)."""
        K = self.ids.size
        if K < 2:
            return True
        ev, df, df2 = np.empty(K), np.empty(K), np.empty(K)
        _k.rivals(self.ll, self._corr, self._wrapped, [p.x for p in self.pieces], self._qq, self._narrow,
                  self.added, c, ph, self.jitter_chips, self.shift_penalty, self.timed_penalty, ev, df, df2)
        ok = df2 > 0
        agree = np.where(ok, ev / np.where(ok, df, 1.0), -np.inf)
        z = np.where(ok, ev / np.sqrt(np.where(ok, df2, 1.0)), -np.inf)
        agree[c] = z[c] = np.inf
        if rows is not None:
            agree, z = agree[rows], z[rows]
        self.agree, self.z = float(agree.min()), float(z.min())
        return self.agree >= self.min_agree and self.z >= self.min_z

    def _post(self, c: int, ph: int, sure: bool = False) -> None:
        """Measure the frame jitter of each kept piece's frame under hypothesis (c, ph) for the
        other lights (the latest hypothesis restates the earlier frames too: pieces that came
        before any light was sure get placed once one is): where the piece fits the packet
        near its timestamp's place, against this light's continuous phase (the mean of its
        pieces' fitted positions about their placements; `_pieces.measure`)."""
        if self.frame_jitter is None:
            return
        pieces = self.pieces
        measured = _k.measure(self._corr, self._rep, self._q, self._qq, self._narrow, len(pieces), self.added,
                              c, ph, self.jitter_chips, self.ref_match, self.ref_unique, self._at)
        self.frame_jitter.post_all(self.key, [(pieces[k].t, m) for k, m in measured], sure)


def bits_seen(seen: np.ndarray, unseen: int = MAX_UNSEEN_BITS) -> bool:
    """Whether the packet positions `seen` (54,) show all of the packet's bits but at most
    `unseen`: a Manchester bit's two chips are complements, so either one shows it;
    the sync is the same in every packet and tells no ID from another."""
    data = np.asarray(seen, bool)[SYNC_LEN:]
    return int((~(data[0::2] | data[1::2])).sum()) <= unseen


@functools.cache
def code_words() -> np.ndarray:
    """(65536,) int64: the 24 bits of every ID's packet (ID << 8 | CRC-8); a linear code, so the
    XOR combinations of the 16 single-bit IDs' words."""
    words = np.zeros(1, np.int64)
    for b in range(16):
        words = np.concatenate((words, words ^ (((1 << b) << 8) | crc8(1 << b, 16))))
    return words


@functools.cache
def word_bits() -> np.ndarray:
    """(65536, 24) float32 0/1: the bits (packet order, MSB first) of every ID's packet, row =
    ID (about 15 ms to make: receiver.decode.policy makes it before a video's first frame)."""
    return ((code_words()[:, None] >> np.arange(23, -1, -1)[None, :]) & 1).astype(np.float32)


def _code_bits() -> np.ndarray:
    """(65535, 24): the bits of every nonzero code word, i.e. of every difference between two
    packets (the code is linear: `word_bits` but ID 0's)."""
    return word_bits()[1:]


@functools.cache
def _shifted_chips() -> tuple:
    """What packet w moved by s = 1..53 chips shows at chip i (53, 54) of another packet's
    placements: its chip (i - s) % 54, a sync chip of value `sync` (0/1; -1: a data chip) or
    the packet bit `bit` (Manchester: bit b is chips SYNC_LEN + 2b, the bit, and SYNC_LEN + 2b +
    1, its complement: `comp`). Made once."""
    sync = np.full(PACKET_LEN, -1, np.int64)
    sync[:SYNC_LEN] = list(SYNC)
    k = np.arange(PACKET_LEN) - SYNC_LEN
    bit, comp = np.where(k >= 0, k // 2, -1), ((k >= 0) & (k % 2 == 1)).astype(np.int64)
    j = (np.arange(PACKET_LEN)[None, :] - np.arange(1, PACKET_LEN)[:, None]) % PACKET_LEN
    is_sync = sync[j] >= 0
    rows = np.broadcast_to(np.arange(PACKET_LEN - 1)[:, None], j.shape)
    return is_sync, sync[j], comp[j], rows[~is_sync], bit[j][~is_sync]


def beats_every_shifted_packet(c_chips: np.ndarray, a: np.ndarray, seen: np.ndarray, c_id: int) -> bool:
    """Whether the chips `seen` (54,), which agree with packet `c_chips` (54,) 0/1 by a_i = e_i -
    min_agree d_i at c's placements (e_i the sum of x times c's chip, d_i of |x|), tell c from
    every packet of another ID sent at any other phase (the same pieces, each moved by the same
    1 to 53 chips: the light's phase is only the winner's best, and a packet whose copy a chip
    pair or more later matches c's but for a few chips fits them almost as well), and agree with
    c where the two differ: a seen chip differs, and the sum over the differing chips of a_i
    (unseen: 0) is >= 0.

    Packet w moved by s chips shows at c's chip i its own chip (i - s) % 54: a sync chip (a
    constant) or its bit b or that bit's complement; so with u_i = c_i XOR (complemented?) the
    chip differs from c by u_i + w_b (1 - 2 u_i), and a sum over the differing chips is affine
    in w's 24 bits, const_s + w . g_s (the count of seen ones in integers, exact). A shift whose
    least over all 2^24 words, const_s + sum min(0, g_s), passes both passes; the others are
    tried on every packet but c's own."""
    c = np.asarray(c_chips, np.int64)
    v = np.stack((np.asarray(a, np.float64), np.asarray(seen, bool).astype(np.float64)))  # (2, 54)
    is_sync, sync, comp, rows, bits = _shifted_chips()
    u = c[None, :] ^ comp  # (53, 54)
    const = np.where(is_sync[None], (sync ^ c[None, :])[None] * v[:, None, :], u[None] * v[:, None, :]).sum(axis=2)
    g = np.zeros((2, PACKET_LEN - 1, 24))
    for k in range(2):
        np.add.at(g[k], (rows, bits), ((1 - 2 * u) * v[k][None, :])[~is_sync])
    low = const + np.minimum(g, 0.0).sum(axis=2)  # (2, 53)
    hard = np.flatnonzero((low[0] < 0) | (low[1] < 1))
    if hard.size == 0:
        return True
    words = word_bits()
    sums = words @ g[0, hard].T.astype(np.float32) + const[0, hard].astype(np.float32)[None, :]
    count = words @ g[1, hard].T.astype(np.float32) + const[1, hard].astype(np.float32)[None, :]  # integers
    ok = (sums >= 0) & (count > 0.5)
    ok[c_id] = True  # c's own packet at another phase is still c's ID
    return bool(ok.all())


def shows_every_difference(bits: np.ndarray) -> bool:
    """Whether the packet bits `bits` (24,) seen tell every packet from every other: no nonzero
    code word is zero on them, i.e. the 16 single-bit IDs' words restricted to them are
    independent over GF(2) (rank 16; at least 16 bits seen)."""
    mask = int((np.asarray(bits, bool).astype(np.int64) << np.arange(23, -1, -1)).sum())
    rows = [int(w) & mask for w in code_words()[1 << np.arange(16)]]
    rank = 0
    for bit in range(23, -1, -1):
        pivot = next((i for i in range(rank, len(rows)) if rows[i] >> bit & 1), None)
        if pivot is None:
            continue
        rows[rank], rows[pivot] = rows[pivot], rows[rank]
        for i in range(len(rows)):
            if i != rank and rows[i] >> bit & 1:
                rows[i] ^= rows[rank]
        rank += 1
    return rank == 16


def unseen_bits_allowed(n_candidates: int, n_near: int) -> int:
    """Bits a choice among `n_near` of the `n_candidates` IDs may leave unseen at the false-accept
    bound of the choice among all of them (`PieceAssembler._decide_near`): `MAX_UNSEEN_BITS`
    plus floor(log2(n_candidates / n_near)) (never fewer than `MAX_UNSEEN_BITS`)."""
    if n_near <= 0 or n_candidates <= n_near:
        return MAX_UNSEEN_BITS
    return MAX_UNSEEN_BITS + int(math.floor(math.log2(n_candidates / n_near) + 1e-12))


def jitter_chips(jitter_us: float, rate_hz: float) -> int:
    """Chips either side a piece may sit off its timestamp's place."""
    return int(math.ceil(jitter_us * rate_hz * 1e-6))


def frames_needed(chips_a_frame: float, min_frames: int) -> int:
    """Fewest frames of one light from which its packet can be pieced together: its pieces must
    show the packet's bits, which take the 48 chips after the sync (`bits_seen`), and the ML
    choice waits for `min_frames` of them."""
    return max(int(math.ceil((PACKET_LEN - SYNC_LEN) / max(chips_a_frame, 1e-9))), int(min_frames))


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
