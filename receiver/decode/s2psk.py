"""S2-PSK decoding from frame-rate samples of an emitter pair (PROTOCOL.md sections 1, 3).

Each frame gives one soft XOR of the two emitters A and B (`pair_xor`, thesis eq. 42:
bit = s1 XOR s2, in phase = 0). A symbol lasts `symbol_clocks / clk_hz` seconds (80 ms at
the defaults, about 2.4 frames at 30 fps) and the camera is not synchronised, so symbol timing
comes from the frame timestamps:

1. keep the last `history_s` seconds of (t, soft XOR) samples;
2. for each candidate phase of the symbol grid (`N_PHASES` over one symbol) give every sample
   a symbol number floor((t - phase) / T); samples within `GUARD` of a boundary are left out
   (their exposure may straddle a symbol change). The right phase is the one under which the
   samples of each symbol agree best: maximum of sum |sum of the symbol's samples|;
3. fold the symbols modulo the 30-symbol packet (the stream repeats with no gap), find the
   sync `111000` by cyclic search (every sync symbol right by `SYNC_MARGIN`), Manchester-decode
   the 12 data bits by soft decision on each symbol pair, and check CRC-4;
4. accept only when every packet position has been seen, every pair and sync symbol is right
   by `MIN_MARGIN`, and the CRC holds. CRC-4 alone passes 1 in 16 random packets, so the
   margins carry most of the protection against wrong IDs;
5. (`S2pskSettings.soft_min_z` over 0, the default) a packet the margins reject is scored by maximum likelihood
   against every valid packet at every shift (`soft_stats`: one matrix product over the
   7,680 hypotheses, weighted by each position's sample count, noise fitted per packet) and
   accepted when its margin over every other ID is large in units of that noise
   (`decode_soft`; the thresholds are `S2pskSettings.soft_min_z` and this module's SOFT_*
   constants, their false-accept rates are in docs/s2psk-pairs.md).

IDs 0x00-0x7F are street lights (SL), 0x80-0xFF vehicles (FV).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from firmware_tx.crc import crc4
from firmware_tx.framing import S2PSK_CRC_BITS, S2PSK_ID_BITS, S2PSK_PACKET_LEN, SYNC, s2psk_packet
from receiver.decode.settings import S2pskSettings
from receiver.core.settings import resolve_settings
from receiver.core import protocol

# Symbol-grid phases tried over one symbol: 1/16 symbol = 5 ms steps at the defaults, well under
# the frames' timestamp jitter. Cost: the phase search is N_PHASES decodes' worth of binning.
N_PHASES = 16
# The full phase search runs every PHASE_EVERY decodes; the decodes between reuse the phase found
# (it drifts only with the emitter's clock error). Cost: a full search bins the samples at
# N_PHASES phases instead of one.
PHASE_EVERY = 8
# Fraction of a symbol at each end whose samples are not used (timestamp jitter and exposures
# straddling a symbol change).
GUARD = 0.12
# The hard rule: every sync symbol must be right by SYNC_MARGIN and every Manchester pair by
# MIN_MARGIN (soft units of a folded symbol mean, -1..1); random folded packets (N(0, sd) clipped
# to [-1, 1]) pass them and CRC-4 in 0, 0 and 2 of 10^5 at sd 0.3, 0.6 and 1.0.
SYNC_MARGIN = 0.25
MIN_MARGIN = 0.3
# Samples each packet position needs before a decode is attempted.
MIN_SAMPLES = 1
# The soft rule's evidence floors besides `S2pskSettings.soft_min_z`: the fitted amplitude at
# least SOFT_MIN_SNR noise sds (noise alone fits some codeword with a small amplitude), no
# position contradicting the packet by more than SOFT_MAX_CONTRADICTION noise sds (the code
# corrects nothing), and the noise sd at least SOFT_SIGMA_FLOOR soft units.
SOFT_MIN_SNR = 1.0
SOFT_MAX_CONTRADICTION = 2.0
SOFT_SIGMA_FLOOR = 0.05
# `decode_soft` scores no hypothesis when `snr_bound` is below SOFT_MIN_SNR x this: the bound is
# exact in real numbers, the slack covers the rounding of the two computations (~1e-15).
SNR_BOUND_SLACK = 1.0 - 1e-9

PACKET_LEN = S2PSK_PACKET_LEN  # 30 symbols
SYNC_LEN = len(SYNC)
N_BITS = S2PSK_ID_BITS + S2PSK_CRC_BITS  # 12
_SYNC_T = np.array([1.0 if c else -1.0 for c in SYNC])
_BIT_WEIGHTS = (1 << np.arange(N_BITS - 1, -1, -1)).astype(np.int64)
_SYNC_IDX = (np.arange(PACKET_LEN)[:, None] + np.arange(SYNC_LEN)[None, :]) % PACKET_LEN
_RING0 = 256  # initial sample ring size (2.5 packets at 30 fps: ~180 samples)
_CRC4 = np.array([crc4(i) for i in range(1 << S2PSK_ID_BITS)], dtype=np.int64)
_ID_STARTS = np.arange(0, PACKET_LEN << S2PSK_ID_BITS, PACKET_LEN)  # each ID's first codebook row


def pair_xor(a: float, b: float, a_on: float, b_on: float, a_off: float = 0.0,
             b_off: float = 0.0) -> float:
    """Soft XOR of two emitters in one frame, in [-1, 1] (> 0: anti-phase = symbol 1).

    a, b: the two blobs' mean intensities; *_on / *_off: their learned fully-on / fully-off
    levels. After normalising to na, nb in [0, 1], in-phase emitters read na = nb and anti-phase
    ones na + nb = 1, also when the exposure straddles a clock edge (both then read the same
    fraction f, or f and 1 - f). The result |na - nb| - |na + nb - 1| is +1 / -1 for clean
    anti-phase / in-phase samples and shrinks towards 0 as the sample approaches na = nb = 0.5,
    where both hypotheses fit equally (a half-and-half straddle).
    """
    da, db = a_on - a_off, b_on - b_off
    if da <= 0 or db <= 0:
        return 0.0
    na = min(max((a - a_off) / da, 0.0), 1.0)
    nb = min(max((b - b_off) / db, 0.0), 1.0)
    return abs(na - nb) - abs(na + nb - 1.0)


def flux_xor(flux: float, on: float, off: float = 0.0) -> float:
    """Soft XOR of one frame from a head's total flux (receiver.vision.pairing.Pairer.head_flux),
    in [-1, 1] (> 0: anti-phase = symbol 1). A head whose two halves cannot be told apart
    (a far street light) shows ~0 (both dark), F (one half lit) or 2F (both lit); `on` is its
    learned 2F level and `off` its dark level. With n = (flux - off) / (on - off), one half lit
    (n = 1/2) gives +1, none or both (n = 0 or 1) -1, linear in between. (A frame exposed
    across a clock edge of in-phase emitters reads as one half: the pair_xor ambiguity at
    na = nb = 1/2 moves to n = 1/2.)"""
    d = on - off
    if d <= 0:
        return 0.0
    n = min(max((flux - off) / d, 0.0), 1.0)
    return 1.0 - 4.0 * abs(n - 0.5)


def decode_symbols(m: np.ndarray, *, sync_margin: float = SYNC_MARGIN, min_margin: float = MIN_MARGIN
                   ) -> tuple[int | None, float]:
    """CRC-4-checked ID from 30 folded soft symbols in arbitrary cyclic order, or None.

    m: float (30,) mean soft symbol per packet position (stream position mod 30). The sync is
    searched over all 30 rotations; exactly one must have every sync symbol right by
    `sync_margin`. Returns (id or None, weakest Manchester pair reliability |a - b| / 2).
    """
    score = (m[_SYNC_IDX] * _SYNC_T).min(axis=1)
    hits = np.flatnonzero(score >= sync_margin)
    if hits.size != 1:
        return None, 0.0
    p = np.roll(m, -int(hits[0]))
    r = 0.5 * (p[SYNC_LEN::2] - p[SYNC_LEN + 1::2])
    conf = float(np.abs(r).min())
    if conf < min_margin:
        return None, conf
    value = int(_BIT_WEIGHTS @ (r > 0))
    led_id, crc = value >> S2PSK_CRC_BITS, value & ((1 << S2PSK_CRC_BITS) - 1)
    if _CRC4[led_id] != crc:
        return None, conf
    return led_id, conf


@functools.cache
def codebook() -> tuple[np.ndarray, np.ndarray]:
    """Every valid packet at every cyclic shift as +-1 rows: (7680, 30) float and the row's ID.
    Row 30 * id + r is the packet of `id` read from folded position r on (np.roll by -r).
    Built on first use (~1 ms: receiver.decode.policy.DecodePolicy builds it when the map has
    S2-PSK lights), not at import: indoor runs and photos never need it."""
    n_ids = 1 << S2PSK_ID_BITS
    packets = np.array([list(s2psk_packet(i)) for i in range(n_ids)], dtype=np.float64) * 2.0 - 1.0
    book = np.empty((n_ids, PACKET_LEN, PACKET_LEN))  # [id, r, p] = packets[id, (p - r) % 30]
    for r in range(PACKET_LEN):  # one slice copy per shift (a fancy index of all is ~10x slower)
        book[:, r, :r] = packets[:, PACKET_LEN - r:]
        book[:, r, r:] = packets[:, :PACKET_LEN - r]
    return book.reshape(-1, PACKET_LEN), np.repeat(np.arange(n_ids), PACKET_LEN)


# Minimum symbol distance between packets of two different IDs at any pair of cyclic shifts: 4
# (6 when both are aligned on the sync: CRC-4 x^4+x+1 on 8 bits is a shortened Hamming code,
# distance 3 bits = 6 Manchester symbols; shifted by 1-2 symbols, Manchester pairs straddle and
# the sync 111000 overlaps data, e.g. 0x00 at shift 0 and 0x6F at shift 1 differ in 4). 6990 of
# the 7680 hypotheses have a different-ID neighbour at distance 4, the other 690 at 6. Two
# shifts of the same ID are at least 4 apart too (tests/decode/test_s2psk_soft.py checks all three).


@dataclass(frozen=True)
class SoftStats:
    """Per-packet statistics of the soft decoder, arrays of shape (B,) (`soft_stats`).

    led_id: ID of the best hypothesis (the highest weighted correlation); z: its margin over
    every hypothesis of a different ID in units of that margin's noise (the smallest, eq. in
    `soft_stats`); snr: fitted amplitude over the noise estimate (per sample); amplitude: the
    fitted symbol amplitude a (soft units, clean samples read 1); sigma: the noise estimate
    (soft units, per sample, floored); contradiction: how far the position that most disagrees
    with the best hypothesis is on the wrong side of 0, -min_p s1_p S_p / (sigma sqrt(c_p)), in
    noise sds of its sum (negative when every position agrees)."""

    led_id: np.ndarray
    z: np.ndarray
    snr: np.ndarray
    amplitude: np.ndarray
    sigma: np.ndarray
    contradiction: np.ndarray


def best_per_id(scores: np.ndarray) -> np.ndarray:
    """(B, 256) the best score of each ID's 30 hypotheses of `scores` (B, 7680):
    scores.reshape(B, -1, 30).max(axis=2) (a maximum is exact, NaN propagates in both), by one
    np.maximum.reduceat over the rows (~2x faster on the short axis)."""
    return np.maximum.reduceat(scores, _ID_STARTS, axis=1)


def soft_stats(sums: np.ndarray, counts: np.ndarray, squares: np.ndarray, *,
               sigma_floor: float = SOFT_SIGMA_FLOOR, exact_from: float = -np.inf, min_snr: float = -np.inf,
               max_contradiction: float = np.inf) -> SoftStats:
    """Maximum-likelihood scoring of every valid packet (256 IDs x 30 shifts) against folded
    packets; sums, counts, squares: (B, 30) or (30,) sum of the soft samples, their number and
    the sum of their squares per folded position (`S2pskDecoder.folded_sums`).

    Model: a sample at position p is x = a s_p + n, s_p = +-1 the hypothesis' symbol (the XOR of
    thesis eq. 42 read as +-1), a > 0 one amplitude for the packet, n white noise of variance
    v_p = sigma^2 (one noise for the packet). The log-likelihood of a hypothesis is then const +
    a sum_p s_p S_p / v_p with S_p the sum of position p's samples: the ML hypothesis has the
    largest weighted correlation sum_p s_p S_p / v_p (a mean of c_p samples has variance
    v_p / c_p), all 7,680 of them one matrix product. The packet's noise sigma^2 is fitted
    under the best hypothesis (a = score / N, sigma^2 = residual sum of squares / (N - 1),
    N = sum c_p, floored by `sigma_floor`), so samples that disagree with each other or with the
    codeword raise it. Between the best hypothesis h1 and another h, the score difference is 2 sum_{p: s1 != s} s1_p S_p / v_p, of
    sd 2 sqrt(W) under h1, W = sum of c_p / v_p over the positions where they differ (unseen
    positions count 0, so an alternative that differs only where nothing was seen has z = 0);
    its z = (score1 - score_h) / (2 sqrt(W)), and `z` is the smallest over every h of a
    different ID (the hardest alternative, not only the second-best score). `snr` = a / sigma.

    `exact_from`: z is first taken against the best-scoring hypothesis of another ID only; the
    search over all 7,680 (one more matrix product) runs only for packets where that z is
    >= exact_from (below, the returned z is an upper bound of the smallest: enough to reject).
    `min_snr`, `max_contradiction`: when no packet has snr >= min_snr and contradiction <=
    max_contradiction (none can be accepted whatever its margin), no margin is computed: z is 0.
    """
    s = np.atleast_2d(np.asarray(sums, dtype=np.float64))
    c = np.atleast_2d(np.asarray(counts, dtype=np.float64))
    q = np.atleast_2d(np.asarray(squares, dtype=np.float64))
    rows = np.arange(s.shape[0])
    book, book_id = codebook()
    scores = s @ book.T  # (B, 7680)
    h1 = np.argmax(scores, axis=1)
    score1 = scores[rows, h1]
    n = np.maximum(c.sum(axis=1), 1.0)
    amp = score1 / n
    rss = np.maximum(q.sum(axis=1) - score1 * amp, 0.0)
    var = np.maximum(rss / np.maximum(n - 1.0, 1.0), sigma_floor ** 2)
    v = np.repeat(var[:, None], s.shape[1], axis=1)
    led_id = book_id[h1]
    s1 = book[h1]  # (B, 30)
    sigma = np.sqrt(var)
    contra = -(s * s1 / np.sqrt(np.maximum(c, 1.0) * v)).min(axis=1)
    snr = amp / sigma
    if not ((snr >= min_snr) & (contra <= max_contradiction)).any():
        return SoftStats(led_id, np.zeros(len(rows)), snr, amp, sigma, contra)
    scores = scores / var[:, None]
    score1 = score1 / var
    cu = c / v
    # the best hypothesis of another ID: W = sum_p c_p / v_p [s_h,p != s1_p]
    per_id = scores.reshape(s.shape[0], -1, PACKET_LEN)
    best_of_id = best_per_id(scores)
    best_of_id[rows, led_id] = -np.inf
    id2 = np.argmax(best_of_id, axis=1)
    h2 = id2 * PACKET_LEN + np.argmax(per_id[rows, id2], axis=1)
    w2 = (cu * (book[h2] != s1)).sum(axis=1)
    z = (score1 - scores[rows, h2]) / (2.0 * np.sqrt(np.maximum(w2, 1e-12)))
    full = np.flatnonzero(z >= exact_from)
    if full.size:
        # every hypothesis: W_h = (sum_p c_p / v_p - sum_p c_p / v_p s1_p s_h,p) / 2
        w = 0.5 * (cu[full].sum(axis=1)[:, None] - (cu[full] * s1[full]) @ book.T)
        zf = (score1[full, None] - scores[full]) / (2.0 * np.sqrt(np.maximum(w, 1e-12)))
        zf[book_id[None, :] == led_id[full, None]] = np.inf
        z[full] = zf.min(axis=1)
    return SoftStats(led_id, z, snr, amp, sigma, contra)


def snr_bound(sums: np.ndarray, counts: np.ndarray, squares: np.ndarray,
              sigma_floor: float = SOFT_SIGMA_FLOOR) -> float:
    """The largest `soft_stats` snr any hypothesis of one folded packet ((30,) sums, counts,
    squares) can have, without scoring them: a hypothesis' score sum_p s_p S_p is at most
    sum_p |S_p| (every sign right), and the fitted snr grows with the score (the amplitude
    score / N rises, the residual sum of squares falls)."""
    top = sum(map(abs, np.asarray(sums, float).tolist()))
    n = max(sum(np.asarray(counts, float).tolist()), 1.0)
    amp = top / n
    var = max(max(sum(np.asarray(squares, float).tolist()) - top * amp, 0.0) / max(n - 1.0, 1.0), sigma_floor ** 2)
    return amp / math.sqrt(var)


def decode_soft(sums: np.ndarray, counts: np.ndarray, squares: np.ndarray, *, min_z: float,
                min_snr: float, max_contradiction: float,
                sigma_floor: float = SOFT_SIGMA_FLOOR) -> tuple[int | None, float]:
    """ID of one folded packet by `soft_stats`, or None: accepted only when (a) its margin over
    every other ID is at least `min_z` noise sds, (b) its amplitude is at least `min_snr` noise
    sds (the absolute evidence floor: noise alone fits some codeword with a small amplitude) and
    (c) no position contradicts it by more than `max_contradiction` noise sds (the code corrects
    nothing: a few strongly wrong symbols, a mixed or slipped history, are rejected as the hard
    decoder rejects them). Returns (id or None, z); z is 0.0 when (b) or (c) fails (no
    hypothesis can reach `min_snr` by `snr_bound`: none is scored; or the best one fails them:
    no margin is computed)."""
    if snr_bound(sums, counts, squares, sigma_floor) < min_snr * SNR_BOUND_SLACK:
        return None, 0.0
    st = soft_stats(sums, counts, squares, sigma_floor=sigma_floor, exact_from=min_z, min_snr=min_snr,
                    max_contradiction=max_contradiction)
    z = float(st.z[0])
    if z >= min_z and float(st.snr[0]) >= min_snr and float(st.contradiction[0]) <= max_contradiction:
        return int(st.led_id[0]), z
    return None, z


def kind_of(led_id: int | None) -> str | None:
    """'SL' (street light, 0x00-0x7F) or 'FV' (vehicle, 0x80-0xFF)."""
    if led_id is None:
        return None
    return "FV" if led_id >= protocol.FV_ID_MIN else "SL"


@dataclass(frozen=True)
class S2pskState:
    """`led_id`: CRC-4-valid ID or None (stays until another valid ID persists for
    `switch_steps` steps); `kind`: 'SL' | 'FV' | None; `samples`: frames fed;
    `confidence`: margin of the latest packet estimate under the rule that decided it: the
    weakest Manchester pair reliability (`decode_symbols`) when the hard rule accepts or
    soft_min_z is 0, else the soft margin z in noise sds (`decode_soft`)."""

    led_id: int | None
    kind: str | None
    samples: int
    confidence: float


def _state(led_id: int | None, samples: int, confidence: float) -> S2pskState:
    """S2pskState(led_id, kind_of(led_id), samples, confidence), without the frozen record's
    per-field object.__setattr__ (a state per decoder per frame: ~35 a frame on vehicle)."""
    st = object.__new__(S2pskState)
    st.__dict__.update(led_id=led_id, kind=kind_of(led_id), samples=samples, confidence=confidence)
    return st


class S2pskDecoder:
    """Per-pair S2-PSK decoder driven by frame timestamps.

    Tunables: `S2pskSettings` (receiver.decode.settings), given as `settings=` or as keyword
    overrides of its fields.
    """

    def __init__(self, clk_hz: float = protocol.S2PSK_CLOCK_HZ, symbol_clocks: int = protocol.S2PSK_SYMBOL_CLOCKS, *,
                 settings: S2pskSettings | None = None, **overrides):
        s = self.settings = resolve_settings(settings, S2pskSettings, overrides)
        if clk_hz <= 0 or symbol_clocks <= 0:
            raise ValueError("clk_hz and symbol_clocks must be positive")
        self.symbol_s = symbol_clocks / clk_hz
        self.sign = -1.0 if s.inverted else 1.0
        self.history_s = 2.5 * PACKET_LEN * self.symbol_s if s.history_s is None else s.history_s
        if not self.history_s >= PACKET_LEN * self.symbol_s:
            # A decode needs a whole packet of samples (it waits for PACKET_LEN - 2 symbols).
            raise ValueError(f"history_s must hold a whole packet ({PACKET_LEN * self.symbol_s:g} s), "
                             f"not {self.history_s:g} s")
        self.n_phases = N_PHASES
        self.guard = GUARD
        self.sync_margin = SYNC_MARGIN
        self.min_margin = MIN_MARGIN
        self.min_samples = MIN_SAMPLES
        self.switch_steps = s.switch_steps
        # the samples' times (s, from the first) and signed soft XORs: a ring of two buffers
        # whose live part is [_lo, _hi) (`_t`, `_x`), appended in place instead of np.append
        self._tb = np.empty(_RING0)
        self._xb = np.empty(_RING0)
        self._lo = self._hi = 0
        self._first = 0.0  # _tb[_lo] as a Python float (the trim test of every step)
        self._last = -np.inf  # the latest time: while the times only grow, a trim is a slice
        self._rising = True
        self._t0: float | None = None
        self.phase_every = PHASE_EVERY
        self._phase: float | None = None  # symbol-grid phase in symbols, from the last search
        self._calls = 0
        self.samples = 0
        self.led_id: int | None = None
        self.confidence = 0.0
        self._cand: int | None = None
        self._cand_n = 0

    @property
    def _t(self) -> np.ndarray:
        """The kept samples' times (s since the first sample), oldest first (a view)."""
        return self._tb[self._lo:self._hi]

    @property
    def _x(self) -> np.ndarray:
        """The kept samples' signed soft XORs, aligned with `_t` (a view)."""
        return self._xb[self._lo:self._hi]

    def _trim(self, since: float) -> None:
        """Drop the samples older than `since` (s): those with t < since, as a boolean mask
        would (a slice while the times only grew, else the mask's compaction)."""
        lo, hi, tb = self._lo, self._hi, self._tb
        if self._rising:
            while lo < hi and tb[lo] < since:
                lo += 1
            self._lo = lo
        else:
            keep = tb[lo:hi] >= since
            n = int(keep.sum())
            tb[:n], self._xb[:n] = tb[lo:hi][keep], self._xb[lo:hi][keep]
            self._lo, self._hi = 0, n

    def _append(self, t: float, x: float) -> None:
        """One sample at the end of the ring (moved to the front, or doubled, when full)."""
        if self._hi == self._tb.size:
            n = self._hi - self._lo
            if 2 * n > self._tb.size:
                tb, xb = np.empty(2 * self._tb.size), np.empty(2 * self._tb.size)
            else:
                tb, xb = self._tb, self._xb
            tb[:n], xb[:n] = self._tb[self._lo:self._hi].copy(), self._xb[self._lo:self._hi].copy()
            self._tb, self._xb, self._lo, self._hi = tb, xb, 0, n
        self._tb[self._hi] = t
        self._xb[self._hi] = x
        self._hi += 1
        if t < self._last:
            self._rising = False
        self._last = t

    def folded_packet(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean soft symbol and sample count per stream position mod 30, (30,) each, at the
        best symbol-grid phase (zeros when there are no samples); see `folded_sums`."""
        sums, cnt, _ = self.folded_sums()
        return np.where(cnt > 0, sums / np.maximum(cnt, 1e-12), 0.0), cnt

    def folded_sums(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sum of the soft samples, their count and the sum of their squares per stream
        position mod 30, (30,) each, at the best symbol-grid phase (zeros when there are no
        samples). The phase is searched over all `N_PHASES` every `PHASE_EVERY` calls and
        reused in between (it only drifts with the emitter's clock error)."""
        t, x = self._t, self._x
        if t.size == 0:
            return np.zeros(PACKET_LEN), np.zeros(PACKET_LEN), np.zeros(PACKET_LEN)
        if self._phase is None or self._calls % self.phase_every == 0:
            phases = np.arange(self.n_phases) / self.n_phases  # in symbols
        else:
            phases = np.array([self._phase])
        self._calls += 1
        u = t[None, :] / self.symbol_s - phases[:, None]  # (P, N) time in symbols
        sym = np.floor(u)
        frac = u - sym
        use = (frac >= self.guard) & (frac <= 1.0 - self.guard)
        sym = sym.astype(np.int64)
        smin = int(sym.min())
        nsym = int(sym.max()) - smin + 1
        npz = phases.size
        flat = (np.arange(npz)[:, None] * nsym + (sym - smin)).ravel()
        w = use.ravel().astype(np.float64)
        sums = np.bincount(flat, (use * x[None, :]).ravel(), npz * nsym).reshape(npz, nsym)
        cnt = np.bincount(flat, w, npz * nsym).reshape(npz, nsym)
        best = int(np.argmax(np.abs(sums).sum(axis=1)))
        self._phase = float(phases[best])
        pos = (np.arange(nsym) + smin) % PACKET_LEN
        ub = use[best]
        sq = np.bincount((sym[best] - smin)[ub], x[ub] ** 2, nsym)
        return (np.bincount(pos, sums[best], PACKET_LEN), np.bincount(pos, cnt[best], PACKET_LEN),
                np.bincount(pos, sq, PACKET_LEN))

    def step(self, t_s: float, soft_xor: float, decode: bool = True) -> S2pskState:
        """Feed one frame: its timestamp (s, source clock) and the pair's `pair_xor`.
        `decode` False: only store the sample (a pair whose ID is known is re-checked every few
        frames, receiver.decode.policy). No decode is tried either while the samples span less
        than 28 symbols: they cannot cover all 30 packet positions yet."""
        self.samples += 1
        if self._t0 is None:
            self._t0 = float(t_s)
        t = float(t_s) - self._t0  # small numbers keep the symbol arithmetic exact
        if self._hi > self._lo and self._first < t - self.history_s:
            self._trim(t - self.history_s)
            self._first = float(self._tb[self._lo]) if self._hi > self._lo else t
        elif self._hi == self._lo:
            self._first = t
        self._append(t, self.sign * float(soft_xor))
        if not decode:
            return _state(self.led_id, self.samples, self.confidence)
        return self._decide(t, decode)

    def _decide(self, t: float, decode: bool) -> S2pskState:
        """`step`'s decode of the kept samples, the latest at `t` (s since the first)."""
        if not decode or t - self._first < (PACKET_LEN - 2) * self.symbol_s:
            if decode:
                self._calls += 1
                self._phase = None  # the first decode searches every phase
            return _state(self.led_id, self.samples, self.confidence)
        sums, c, squares = self.folded_sums()
        if c.min() < self.min_samples:
            self.confidence = 0.0
            return _state(self.led_id, self.samples, 0.0)
        led_id, conf = decode_symbols(sums / np.maximum(c, 1e-12), sync_margin=self.sync_margin,
                                      min_margin=self.min_margin)
        if led_id is None and self.settings.soft_min_z > 0:
            s = self.settings
            led_id, conf = decode_soft(sums, c, squares, min_z=s.soft_min_z, min_snr=SOFT_MIN_SNR,
                                       max_contradiction=SOFT_MAX_CONTRADICTION, sigma_floor=SOFT_SIGMA_FLOOR)
        self.confidence = conf
        if led_id is not None and led_id != self.led_id:
            if self.led_id is None:
                self.led_id = led_id
            else:
                self._cand_n = self._cand_n + 1 if led_id == self._cand else 1
                self._cand = led_id
                if self._cand_n >= self.switch_steps:
                    self.led_id, self._cand, self._cand_n = led_id, None, 0
        elif led_id is not None:
            self._cand, self._cand_n = None, 0
        return _state(self.led_id, self.samples, conf)
