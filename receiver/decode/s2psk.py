"""S2-PSK decoding from frame-rate samples of an emitter pair (PROTOCOL.md sections 1, 3).

Each frame gives one soft XOR of the two emitters A and B (`pair_xor`, thesis eq. 42:
bit = s1 XOR s2, in phase = 0). A symbol lasts `symbol_clocks / clk_hz` seconds (80 ms at
the defaults, about 2.4 frames at 30 fps) and the camera is not synchronised, so symbol timing
comes from the frame timestamps:

1. keep the last `history_s` seconds of (t, soft XOR) samples;
2. for each candidate phase of the symbol grid (`n_phases` over one symbol) give every sample
   a symbol number floor((t - phase) / T); samples within `guard` of a boundary are left out
   (their exposure may straddle a symbol change). The right phase is the one under which the
   samples of each symbol agree best: maximum of sum |sum of the symbol's samples|;
3. fold the symbols modulo the 30-symbol packet (the stream repeats with no gap), find the
   sync `111000` by cyclic search (every sync symbol right by `sync_margin`), Manchester-decode
   the 12 data bits by soft decision on each symbol pair, and check CRC-4;
4. accept only when every packet position has been seen, every pair and sync symbol is right
   by `min_margin`, and the CRC holds. CRC-4 alone passes 1 in 16 random packets, so the
   margins carry most of the protection against wrong IDs.

IDs 0x00-0x7F are street lights (SL), 0x80-0xFF vehicles (FV).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmware_tx.crc import crc4
from firmware_tx.framing import S2PSK_CRC_BITS, S2PSK_ID_BITS, S2PSK_PACKET_LEN, SYNC
from receiver.decode.settings import S2pskSettings
from receiver.core.settings import resolve_settings
from receiver.core import protocol

PACKET_LEN = S2PSK_PACKET_LEN  # 30 symbols
SYNC_LEN = len(SYNC)
N_BITS = S2PSK_ID_BITS + S2PSK_CRC_BITS  # 12
_SYNC_T = np.array([1.0 if c else -1.0 for c in SYNC])
_BIT_WEIGHTS = (1 << np.arange(N_BITS - 1, -1, -1)).astype(np.int64)
_SYNC_IDX = (np.arange(PACKET_LEN)[:, None] + np.arange(SYNC_LEN)[None, :]) % PACKET_LEN
_CRC4 = np.array([crc4(i) for i in range(1 << S2PSK_ID_BITS)], dtype=np.int64)


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


def decode_symbols(m: np.ndarray, *, sync_margin: float = 0.3, min_margin: float = 0.25
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


def kind_of(led_id: int | None) -> str | None:
    """'SL' (street light, 0x00-0x7F) or 'FV' (vehicle, 0x80-0xFF)."""
    if led_id is None:
        return None
    return "FV" if led_id >= protocol.FV_ID_MIN else "SL"


@dataclass(frozen=True)
class S2pskState:
    """`led_id`: CRC-4-valid ID or None (stays until another valid ID persists for
    `switch_steps` steps); `kind`: 'SL' | 'FV' | None; `samples`: frames fed;
    `confidence`: weakest Manchester pair reliability of the latest packet estimate."""

    led_id: int | None
    kind: str | None
    samples: int
    confidence: float


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
        self.n_phases = s.n_phases
        self.guard = s.guard
        self.sync_margin = s.sync_margin
        self.min_margin = s.min_margin
        self.min_samples = s.min_samples
        self.switch_steps = s.switch_steps
        self._t = np.zeros(0)
        self._x = np.zeros(0)
        self._t0: float | None = None
        self.phase_every = s.phase_every
        self._phase: float | None = None  # symbol-grid phase in symbols, from the last search
        self._calls = 0
        self.samples = 0
        self.led_id: int | None = None
        self.confidence = 0.0
        self._cand: int | None = None
        self._cand_n = 0

    def folded_packet(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean soft symbol and sample count per stream position mod 30, (30,) each, at the
        best symbol-grid phase (zeros when there are no samples). The phase is searched over
        all `n_phases` every `phase_every` calls and reused in between (it only drifts with
        the emitter's clock error)."""
        t, x = self._t, self._x
        if t.size == 0:
            return np.zeros(PACKET_LEN), np.zeros(PACKET_LEN)
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
        m = np.bincount(pos, sums[best], PACKET_LEN)
        c = np.bincount(pos, cnt[best], PACKET_LEN)
        return np.where(c > 0, m / np.maximum(c, 1e-12), 0.0), c

    def step(self, t_s: float, soft_xor: float, decode: bool = True) -> S2pskState:
        """Feed one frame: its timestamp (s, source clock) and the pair's `pair_xor`.
        `decode` False: only store the sample (a pair whose ID is known is re-checked every few
        frames, receiver.decode.policy). No decode is tried either while the samples span less
        than 28 symbols: they cannot cover all 30 packet positions yet."""
        self.samples += 1
        if self._t0 is None:
            self._t0 = float(t_s)
        t = float(t_s) - self._t0  # small numbers keep the symbol arithmetic exact
        if self._t.size and self._t[0] < t - self.history_s:
            keep = self._t >= t - self.history_s
            self._t, self._x = self._t[keep], self._x[keep]
        self._t = np.append(self._t, t)
        self._x = np.append(self._x, self.sign * float(soft_xor))
        if not decode or t - self._t[0] < (PACKET_LEN - 2) * self.symbol_s:
            if decode:
                self._calls += 1
                self._phase = None  # the first decode searches every phase
            return S2pskState(self.led_id, kind_of(self.led_id), self.samples, self.confidence)
        m, c = self.folded_packet()
        if c.min() < self.min_samples:
            self.confidence = 0.0
            return S2pskState(self.led_id, kind_of(self.led_id), self.samples, 0.0)
        led_id, conf = decode_symbols(m, sync_margin=self.sync_margin, min_margin=self.min_margin)
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
        return S2pskState(self.led_id, kind_of(self.led_id), self.samples, conf)
