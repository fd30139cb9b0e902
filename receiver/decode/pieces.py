"""Packets from short pieces placed by the frame times (PROTOCOL.md section 1: the stream is
periodic, so pieces of it seen in different frames belong to one packet).

A light whose image shows only a few chips per frame (5-10 kHz chips on a small or far panel:
6-13 chips) rarely shows the sync, and two frames' pieces rarely overlap enough to be aligned
by their chips. Their times place them instead: frame f's chip 0 sits at packet position

    s_f = phi + q_f (mod 54),   q_f = rate * t_f + Y_f / p,

with t_f the frame's timestamp, Y_f the image row where its chip 0 starts, p rows per chip and
phi the light's unknown packet phase. The frame's true start differs from its timestamp by the
camera's jitter (about 100-200 us: one or two chips at 10 kHz), so each piece may sit up to
`jitter_chips` either side. The light's ID and phase are then chosen by maximum likelihood over
the map's IDs at this chip rate (`candidates`) and phi: every frame contributes its best
normalised correlation with the candidate's packet within its jitter window; the winner must
correlate strongly on average (`min_corr`), beat every other ID by `min_gap`, and its pieces
must cover the whole packet.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

PACKET_LEN = 54
# Sub-chip steps of the packet phase phi searched.
PHASE_STEPS = 4


class PieceAssembler:
    """One light's recent pieces and the ML choice of its ID among `candidates`.

    templates: (K, 54) +-1 packets of the candidate IDs `ids` (K,). shift_penalty: correlation
    taken off per chip a piece sits away from its timestamp's place (a jitter of one or two
    chips is likelier than the window's edge; it also denies wrong IDs the window's freedom)."""

    def __init__(self, ids: np.ndarray, templates: np.ndarray, *, jitter_chips: int, history: int,
                 min_frames: int, min_corr: float, min_gap: float, shift_penalty: float = 0.2):
        self.ids = np.asarray(ids)
        self.templates = np.asarray(templates, dtype=np.float32)
        self._wrapped = None if self.templates.size == 0 else np.concatenate(
            (self.templates, self.templates), axis=1)  # the packets twice: cyclic windows as slices
        self.jitter = int(jitter_chips)
        # (K, 55, 54): [:, k] is the packets' window from chip k on (the products' other factor)
        self._windows = None if self.templates.size == 0 else sliding_window_view(self._wrapped, PACKET_LEN, axis=1)
        # the shift penalty at each of the jitter window's 2 J + 1 places, float32 (1, 2 J + 1, 1)
        d = [abs(i - self.jitter) for i in range(2 * self.jitter + 1)]
        self._pens = np.array([shift_penalty * v for v in d], dtype=np.float32)[None, :, None]
        self.history = history
        # per piece: (best (K, 54) float32 windowed correlation, weight, q, n)
        self.pieces: deque = deque()
        self._raw: list = []  # pieces kept until min_frames are there: (x, q)
        self.min_frames = min_frames
        self.min_corr = min_corr
        self.min_gap = min_gap
        self.shift_penalty = shift_penalty
        self.phis = np.arange(PACKET_LEN * PHASE_STEPS) / PHASE_STEPS
        self.ll: np.ndarray | None = None  # sum over pieces of weight * best[:, s(phi)] (K, 54 * steps)
        self.total = 0.0
        self.score = 0.0  # the latest decision's mean correlation, gap and best ID (diagnostics)
        self.gap = 0.0
        self.best_id: int | None = None

    def _slots(self, q: float) -> np.ndarray:
        """Packet position of a piece's chip 0 under every phase hypothesis."""
        return np.floor(q + self.phis + 0.5).astype(np.int64) % PACKET_LEN

    def add(self, soft: np.ndarray, cw: np.ndarray, q: float) -> None:
        """Keep a piece (soft chips, weights, packet time q); its correlations with the
        candidates are computed once `min_frames` pieces are there (a light that shows a short
        piece for a frame or two, entering the image, costs nothing)."""
        x = (np.clip(soft, -1.0, 1.0) * cw).astype(np.float32)
        if float(np.abs(x).sum()) <= 0 or self.ids.size == 0:
            return
        self._raw.append((x, float(q) % PACKET_LEN))
        if len(self.pieces) + len(self._raw) >= self.min_frames:
            for x, q in self._raw:
                self._add(x, q)
            self._raw.clear()

    def _add(self, x: np.ndarray, q: float) -> None:
        den = float(np.abs(x).sum())
        n = x.size
        # (K, 54): the piece at each packet position, sum_k x_k T[:, (s + k) % 54]: all the
        # products at once (K, n, 54), summed over k in chip order (a reduction over an outer
        # axis adds its slices one after another, as a loop over k would)
        corr = np.add.reduce(self._windows[:, :n] * x[None, :, None], axis=1)
        corr /= den
        # the best within the jitter window of each position, less the penalty of its distance:
        # corr with J columns of the other end on each side, whose windows are the cyclic shifts
        J = self.jitter
        ext = np.concatenate((corr[:, PACKET_LEN - J:], corr, corr[:, :J]), axis=1)
        best = np.maximum.reduce(sliding_window_view(ext, PACKET_LEN, axis=1) - self._pens, axis=1)
        if self.ll is None:  # made with the first piece: most lights never show enough short ones
            self.ll = np.zeros((self.ids.size, self.phis.size))
        if len(self.pieces) >= self.history:
            old, w, q0, _ = self.pieces.popleft()
            self.ll -= w * old[:, self._slots(q0)]
            self.total -= w
        self.pieces.append((best, den, q, n))
        self.ll += den * best[:, self._slots(q)]
        self.total += den

    def decide(self) -> int | None:
        """The ID of the best (ID, phase) hypothesis when it passes the checks, else None."""
        if len(self.pieces) < self.min_frames or self.total <= 0:
            return None
        mean = self.ll / self.total
        c, ph = np.unravel_index(int(np.argmax(mean)), mean.shape)
        top = float(mean[c, ph])
        second = float(np.delete(mean, c, axis=0).max()) if self.ids.size > 1 else -1.0
        self.score, self.gap, self.best_id = top, top - second, int(self.ids[c])
        if top < self.min_corr or top - second < self.min_gap:
            return None
        # the winner's pieces, each where it fits best in its window, must cover the packet
        seen = np.zeros(PACKET_LEN, bool)
        J = self.jitter
        for best, _, q, n in self.pieces:
            s0 = int(self._slots(q)[ph])
            window = (s0 + np.arange(-J, J + 1)) % PACKET_LEN
            # (the window's correlations are the penalised ones: the place the score used)
            at = int(window[int(np.argmax(best[c, window]))]) if J else s0
            seen[(at + np.arange(n)) % PACKET_LEN] = True
        return int(self.ids[c]) if seen.all() else None


def jitter_chips(jitter_us: float, rate_hz: float) -> int:
    """Chips either side a piece may sit off its timestamp's place."""
    return int(math.ceil(jitter_us * rate_hz * 1e-6))
