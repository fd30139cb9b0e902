"""Frame clock: where the OOK packets of a frame sit, measured by lights already decoded.

All lights of one frame are read by the same rolling shutter, started at the frame's true
start time t_k = k / fps + j_k (the jitter j_k is common to every light; ~100 us = 2 chips at
20 kHz). For an OOK light whose packet position is known in frame k (its decoder placed the
frame by its sync, or by its decoded packet), the packet coordinate of sensor row 0 is

    u = shift - Y / p   (mod 54 chips)

with `shift` the packet position of the frame's chip 0, `Y` the image row where that chip
starts and `p` rows per chip (`OokDecoder.row0_coordinate`). For two lights i, r at one chip
rate, u_i - u_r = constant + (e_i - e_r) * rate * t_k: the jitter cancels, what is left is a
constant and a slow linear drift from their crystals (tens of ppm: a few hundredths of a chip
per frame at 30 fps; on recordings/indoor-static the residual of a line fit is < 0.07 chip).

`FrameClock` turns the u of the reference lights of each frame into one clock value c_k (mod
54): the u of a reference, made continuous across references by each reference's fitted
offset d_r(k) = u_r - c (a line over its last `WINDOW_FRAMES` frames). A decoder then learns its own
light's offset o(k) = u_i - c_k the same way (`OokDecoder`, timing hint) and places a frame
without sync and without enough overlap for a correlation at shift = round(c_k + Y / p + o(k)).

The clock's zero is arbitrary (the first reference's packet); when no reference with a fitted
offset remains, the chain is broken and `epoch` increments: offsets learned against the old
epoch are then meaningless and decoders drop them.

Safety: a reference's u is only reported for a frame placed by its sync or by a unique, strong
match with its CRC-valid packet (`OokDecoder.row0_coordinate`); references that disagree with
the consensus by more than `MAX_RESID_CHIPS` chips are dropped (and the frame has no clock value if
no majority is left).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from receiver.decode.ook import DIAGNOSTICS_LEN, PACKET_LEN, line_predict, wrap_chips as wrap

# Frames of a reference's offset history in its line fit (its crystal drift is linear over them).
WINDOW_FRAMES = 12
# A reference unseen for more frames than this loses its offset (the drift is then unknown).
MAX_GAP_FRAMES = 6
# Chips a reference may disagree with the consensus before it is dropped as slipped.
MAX_RESID_CHIPS = 0.2


def _mean(vals: list[float]) -> float:
    """float(np.mean(vals)), the same number without numpy's call overhead for the few
    references of a frame: numpy's pairwise sum adds fewer than 8 terms in order."""
    if len(vals) >= 8:
        return float(np.mean(vals))
    s = -0.0
    for v in vals:
        s += v
    return (0.0 + s) / len(vals)


@dataclass(frozen=True)
class ClockTick:
    """The clock of frame k: `value` (chips, mod 54) is the reference packet coordinate of
    sensor row 0; `epoch` numbers the unbroken chains of references; `refs` how many
    references agreed; `resid` their largest disagreement with the consensus (chips)."""

    k: int
    value: float
    epoch: int
    refs: int
    resid: float


class FrameClock:
    """Per-frame clock of one OOK chip rate, fed by reference lights.

    Per frame: `begin(k)`, then `observe(key, u)` for each reference light (u from
    `OokDecoder.row0_coordinate`), then `close()` -> ClockTick or None. Its constants are
    this module's WINDOW_FRAMES, MAX_GAP_FRAMES and MAX_RESID_CHIPS.
    """

    def __init__(self):
        self.window = WINDOW_FRAMES
        self.max_gap = MAX_GAP_FRAMES
        self.max_resid = MAX_RESID_CHIPS
        self.epoch = 0
        self.refs: dict = {}  # key -> deque of (k, d) with d = u - c (unwrapped)
        self.k: int | None = None
        self._obs: dict = {}
        self.tick: ClockTick | None = None
        # the references' latest |disagreement|s, chips (diagnostics; bounded for long streams)
        self.residuals: deque = deque(maxlen=DIAGNOSTICS_LEN)

    def begin(self, k: int) -> None:
        self.k, self._obs, self.tick = k, {}, None

    def observe(self, key, u: float) -> None:
        self._obs[key] = float(u) % PACKET_LEN

    def close(self) -> ClockTick | None:
        k = self.k
        for key in [key for key, h in self.refs.items() if k - h[-1][0] > self.max_gap]:
            del self.refs[key]
        if not self._obs:
            return None
        cand = {key: self._obs[key] - line_predict(self.refs[key], k, self.window)
                for key in self._obs if key in self.refs}
        resid = 0.0
        if cand:
            # consensus: the largest group of candidates within MAX_RESID_CHIPS of one another
            # (ties: the group with the longer histories; a full tie gives no clock)
            def group(key):
                return [o for o in cand if abs(wrap(cand[o] - cand[key])) <= self.max_resid]

            scored = sorted(((len(g), sum(len(self.refs[o]) for o in g), g) for g in map(group, cand)),
                            key=lambda x: x[:2], reverse=True)
            n_best, h_best, good = scored[0]
            if any(n == n_best and h == h_best and set(g) != set(good) for n, h, g in scored[1:]):
                return None
            c0 = cand[good[0]]
            c = (c0 + _mean([wrap(cand[o] - c0) for o in good])) % PACKET_LEN
            devs = [abs(wrap(cand[o] - c)) for o in good]
            if len(good) > 1:
                self.residuals.extend(devs)
            resid = max(devs)
            for key in cand:
                if key not in good:
                    del self.refs[key]  # a reference that slipped (or was misplaced) starts over
            refs = len(good)
        else:
            # no reference with a history: a new chain, zero at the first reference
            self.epoch += 1
            key0 = next(iter(self._obs))
            c = self._obs[key0]
            refs = 1
        for key, u in self._obs.items():
            h = self.refs.get(key)
            if h is None:
                self.refs[key] = deque([(k, wrap(u - c))], maxlen=self.window)
            else:
                pred = line_predict(h, k, self.window)
                h.append((k, pred + wrap(u - c - pred)))
        self.tick = ClockTick(k, c, self.epoch, refs, resid)
        return self.tick
