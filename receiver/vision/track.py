"""Frame-to-frame blob tracking: gated optimal assignment, tracks that coast through misses.

Each `Track` keeps its last blob (the envelope is where an S2-PSK emitter's intensity is read
while it is dark), a constant-velocity prediction in px/frame, the decoder objects the
pipeline attached and the decoded ID, which stays with the track.

Assignment: cost = distance (px) between a track's predicted centroid and a blob centroid,
solved by `scipy.optimize.linear_sum_assignment`; pairs beyond the gate or with an
implausible area change are left unassigned (new track / missed track). When no gate holds
two candidates (no track sees two blobs, no blob is in two tracks' gates) the gated pairs
are the assignment itself and the solver is skipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from receiver.core.native import require
from receiver.core.records import Blob
from receiver.vision.settings import TrackSettings
from receiver.core.settings import resolve_settings

# Cost standing in for "not allowed" in the assignment matrix (finite: scipy needs a solution).
_FORBIDDEN = 1e9
# The gate grows by this many blob diameters (sqrt(area)) beyond `TrackSettings.gate_px`, so big
# near lights may move more per frame than small far ones.
GATE_SIZE = 1.5
# A larger area change between frames (either way) is another light.
MAX_AREA_RATIO = 4.0
# Smoothing of the px/frame velocity estimate (1 = the last step only).
VELOCITY_GAIN = 0.5

# the compiled step (receiver/vision/_track.pyx): the one implementation of `Tracker.step`'s
# assignment and updates
_k = require("receiver.vision._track")


@dataclass
class Track:
    """One tracked light. Positions in px (image frame, see receiver.core.records)."""

    track_id: int
    blob: Blob
    first_frame: int
    last_frame: int
    vx: float = 0.0  # px per frame
    vy: float = 0.0
    hits: int = 1
    misses: int = 0  # consecutive frames without a blob
    seen: bool = True  # a blob was assigned in the latest frame
    shift0: tuple = (0.0, 0.0)  # the tracker's accumulated image shift when its blob was taken

    @property
    def cx(self) -> float:
        return self.blob.cx

    @property
    def cy(self) -> float:
        return self.blob.cy

    def predict(self, frame_index: int) -> tuple[float, float]:
        dt = frame_index - self.last_frame
        return self.blob.cx + self.vx * dt, self.blob.cy + self.vy * dt


def preload() -> None:
    """Import scipy.optimize now (~0.8 s CPU), before a stream's first frame: the assignment
    below and the locate stage's fallbacks import it where they need it, which a single photo
    never does (its frame has no tracks to assign)."""
    import scipy.optimize  # noqa: F401


def gated_assignment(d: np.ndarray, ok: np.ndarray) -> dict[int, int]:
    """{row: column} of the minimum-cost assignment of the (T, B) costs `d` (px) restricted to
    the pairs `ok` (bool (T, B)); pairs outside `ok` are never assigned.

    When no row and no column has two allowed pairs (no track sees two blobs in its gate, no
    blob lies in two gates: the common case) the allowed pairs are the assignment itself (any
    other leaves one of them out and pays _FORBIDDEN), so the solver is skipped; otherwise
    `scipy.optimize.linear_sum_assignment` on the costs with _FORBIDDEN outside `ok`."""
    if not ok.size:
        return {}
    if np.maximum.reduce(np.add.reduce(ok, axis=0)) <= 1 and np.maximum.reduce(np.add.reduce(ok, axis=1)) <= 1:
        rows, cols = ok.nonzero()
        return dict(zip(rows.tolist(), cols.tolist()))
    return _solver_assignment(d, ok)


def _solver_assignment(d: np.ndarray, ok: np.ndarray) -> dict[int, int]:
    """`gated_assignment` by the solver alone (the compiled step calls it when a gate holds two
    candidates)."""
    cost = np.where(ok, d, _FORBIDDEN)
    from scipy.optimize import linear_sum_assignment  # lazy: scipy.optimize costs ~0.8 s to import (a stream preloads it: `preload` below)
    rows, cols = linear_sum_assignment(cost)
    return {r: c for r, c in zip(rows.tolist(), cols.tolist()) if cost[r, c] < _FORBIDDEN}


class Tracker:
    """Gated assignment tracker (init/step).

    Tunables: `TrackSettings` (receiver.vision.settings), given as `settings=` or as keyword
    overrides of its fields.
    """

    def __init__(self, *, settings: TrackSettings | None = None, **overrides):
        s = self.settings = resolve_settings(settings, TrackSettings, overrides)
        self.gate_px = s.gate_px
        self.gate_size = GATE_SIZE
        self.max_area_ratio = MAX_AREA_RATIO
        self.max_missed = s.max_missed
        self.velocity_gain = VELOCITY_GAIN
        self.tracks: list[Track] = []
        self._next_id = 0
        self.ended: list[Track] = []  # tracks dropped in the latest step
        self.shift_sum = (0.0, 0.0)  # accumulated common image shift (camera shake), px

    def new_id(self) -> int:
        """A fresh id from the tracks' id counter (never a track's), for records that stand for
        an LED without a track of their own (an S2-PSK pair's emitters, receiver.vision.pairing)."""
        self._next_id += 1
        return self._next_id - 1

    def step(self, frame_index: int, blobs: list[Blob], shift=None) -> list[Track]:
        """Assign this frame's blobs; returns the live tracks (those with `seen` True got a blob).
        `shift`: this frame's common image shift (dx, dy) px from the previous frame (camera
        shake, receiver.vision.motion) or None: added to every prediction, and taken out of the
        velocities (a track's velocity is its light's own motion). All tracks x blobs at once, by
        the compiled kernel (receiver/vision/_track.pyx): a track's predicted centroid is its
        blob's plus velocity times the frame gap plus the shift since its blob; pairs within the
        gate `gate_px + GATE_SIZE * sqrt(area)` and the area ratio bounds are the candidates,
        `gated_assignment` picks among them, and each assigned track's velocity is blended by
        VELOCITY_GAIN (its first step taken whole)."""
        if shift is not None:
            self.shift_sum = (self.shift_sum[0] + shift[0], self.shift_sum[1] + shift[1])
        sx, sy = self.shift_sum
        shifted = shift is not None or bool(sx) or bool(sy)
        alive, self.ended, used = _k.step(self.tracks, blobs, frame_index, sx, sy, self.shift_sum, shifted,
                                          self.gate_px, self.gate_size, self.max_area_ratio,
                                          self.velocity_gain, self.max_missed, _solver_assignment)
        if 0 in used:  # a blob no track took (most frames: none) starts a new track
            for j, b in enumerate(blobs):
                if not used[j]:
                    alive.append(Track(self._next_id, b, frame_index, frame_index, shift0=self.shift_sum))
                    self._next_id += 1
        self.tracks = alive
        return alive
