"""S2-PSK pairing: which two tracked blobs are the A/B emitters of one transmitter.

A pair (PROTOCOL.md section 3: two taillights of a car, two halves of a street-light head):
* the same row band: |cy_a - cy_b| <= `row_band` x the mean blob diameter,
* similar size: area ratio <= `max_area_ratio`,
* a plausible baseline: horizontal centre distance between `min_baseline` and
  `max_baseline` blob diameters (taillights 1.4 m apart, 0.15 m wide: ~9 diameters),
* a consistent on/off pattern: both emitters blink (each is lit in about half the frames),
  checked over the frames seen so far once `min_frames` are in.
Candidates are paired greedily, best score first, each track in at most one pair; a pair stays
until one of its tracks ends.

Per frame, each emitter's intensity is the mean gray inside its last envelope (also when dark,
so no frame is lost); `EmitterLevels` learns its on/off levels from recent frames, and
`pair_xor` (receiver.decode_s2psk) turns the two intensities into the soft XOR of one sample.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from receiver.track import Track


class EmitterLevels:
    """Running on/off levels of one emitter from its last `history` intensities (gray):
    on = the `q_on` percentile, off = the `q_off` percentile."""

    def __init__(self, *, history: int = 48, q_on: float = 90.0, q_off: float = 10.0):
        self.values: deque = deque(maxlen=history)
        self.q_on, self.q_off = q_on, q_off

    def add(self, value: float) -> None:
        self.values.append(float(value))

    @property
    def on(self) -> float:
        return float(np.percentile(self.values, self.q_on)) if self.values else 0.0

    @property
    def off(self) -> float:
        return float(np.percentile(self.values, self.q_off)) if self.values else 0.0

    def blinks(self, min_swing: float) -> bool:
        """Both levels seen, apart by at least `min_swing` gray values."""
        return len(self.values) >= 2 and self.on - self.off >= min_swing


@dataclass
class Pair:
    """Two tracks paired as one S2-PSK transmitter (`a` is the left one in the image)."""

    a: Track
    b: Track
    levels_a: EmitterLevels = field(default_factory=EmitterLevels)
    levels_b: EmitterLevels = field(default_factory=EmitterLevels)
    decoder: object = None  # the pipeline's decoders of this pair
    state: object = None  # their latest state
    led_id: int | None = None
    kind: str | None = None
    fresh: bool = True  # formed this frame: its levels already hold this frame's intensities

    @property
    def key(self) -> tuple[int, int]:
        return (self.a.track_id, self.b.track_id)


def pair_score(a: Track, b: Track, *, row_band: float = 1.0, max_area_ratio: float = 2.5,
               min_baseline: float = 1.2, max_baseline: float = 25.0) -> float | None:
    """Geometric pairing cost (lower is better) of two tracks, None when implausible."""
    da, db = math.sqrt(max(a.blob.area_px, 1.0)), math.sqrt(max(b.blob.area_px, 1.0))
    diam = 0.5 * (da + db)
    dy = abs(a.cy - b.cy)
    dx = abs(a.cx - b.cx)
    ratio = max(a.blob.area_px, 1.0) / max(b.blob.area_px, 1.0)
    if dy > row_band * diam or not (1 / max_area_ratio <= ratio <= max_area_ratio):
        return None
    if not (min_baseline * diam <= dx <= max_baseline * diam):
        return None
    return dy / diam + abs(math.log(ratio)) + 0.01 * dx / diam


class Pairer:
    """Keeps S2-PSK pairs over frames (init/step).

    Tunables: row_band [1.0], max_area_ratio [2.5], min_baseline [1.2], max_baseline [25]
    (see `pair_score`, units of blob diameters); min_frames [4]: frames of intensity history
    before the on/off check; min_swing [20]: gray levels between an emitter's on and off.
    """

    def __init__(self, *, row_band: float = 1.0, max_area_ratio: float = 2.5, min_baseline: float = 1.2,
                 max_baseline: float = 25.0, min_frames: int = 4, min_swing: float = 20.0):
        self.geom = dict(row_band=row_band, max_area_ratio=max_area_ratio,
                         min_baseline=min_baseline, max_baseline=max_baseline)
        self.min_frames = min_frames
        self.min_swing = min_swing
        self.pairs: list[Pair] = []
        self.levels: dict[int, EmitterLevels] = {}  # per unpaired track, for the on/off check

    def step(self, gray: np.ndarray, tracks: list[Track], intensity) -> list[Pair]:
        """Update pairs with this frame. `intensity(gray, track) -> float` reads an emitter's
        mean gray in its envelope. Returns the live pairs; their levels are updated."""
        live = {t.track_id: t for t in tracks}
        self.pairs = [p for p in self.pairs if p.a.track_id in live and p.b.track_id in live]
        paired = {tid for p in self.pairs for tid in p.key}
        for tid in list(self.levels):
            if tid not in live or tid in paired:
                del self.levels[tid]
        for t in tracks:
            if t.track_id not in paired:
                self.levels.setdefault(t.track_id, EmitterLevels()).add(intensity(gray, t))
        free = [t for t in tracks if t.track_id not in paired and len(self.levels[t.track_id].values) >= self.min_frames
                and self.levels[t.track_id].blinks(self.min_swing)]
        cands = []
        for i, a in enumerate(free):
            for b in free[i + 1:]:
                s = pair_score(a, b, **self.geom)
                if s is not None:
                    cands.append((s, a, b))
        cands.sort(key=lambda c: c[0])
        taken: set[int] = set()
        for _, a, b in cands:
            if a.track_id in taken or b.track_id in taken:
                continue
            if a.cx > b.cx:
                a, b = b, a
            p = Pair(a, b)
            # The history that proved the blinking also seeds the pair's level estimates.
            for lv, t in ((p.levels_a, a), (p.levels_b, b)):
                lv.values.extend(self.levels.pop(t.track_id).values)
            taken.update((a.track_id, b.track_id))
            self.pairs.append(p)
        return self.pairs

    @staticmethod
    def sample(p: Pair, gray: np.ndarray, intensity) -> tuple[float, float]:
        """This frame's (a, b) intensities of a pair; updates its levels."""
        if p.fresh:
            p.fresh = False
            return p.levels_a.values[-1], p.levels_b.values[-1]
        ia, ib = intensity(gray, p.a), intensity(gray, p.b)
        p.levels_a.add(ia)
        p.levels_b.add(ib)
        return ia, ib
