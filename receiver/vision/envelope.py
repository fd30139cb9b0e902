"""Envelope merge across frames: a striped LED's envelope is the convex hull of its blobs of
the last few frames (the rows hidden by OFF chips in one frame are lit in another).
"""

from __future__ import annotations

from receiver.core.native import require

# the compiled merge of all lights of a frame (receiver/vision/_envelope.pyx), the one
# implementation (its share of a frame: docs/kernels.md)
_k = require("receiver.vision._envelope")


class EnvelopeHistory:
    """Each tracked light's envelope over its last `frames` frames (init/step).

    `step(tracks, k, shape)` returns {track_id: envelope Blob} for the tracks seen in frame `k`:
    this frame's blob merged with its hulls of the previous `frames - 1` frames, each moved by
    the track's px/frame velocity (its jitter from the hidden caps limits how much a static
    scene gains; a moving one needs the motion). `frames` 1 = this frame's blob alone.

    The history is one record per frame (the seen tracks' ids and hulls, all in one array),
    kept while a later frame can still use it: frame indices must grow (gaps are fine); a frame
    index at or below an earlier one starts the history afresh. All lights of a frame are merged
    by one call of the compiled kernel (receiver/vision/_envelope.pyx), which takes (K, 2)
    float64 hulls, as `detect` makes them (ValueError for others). An ended track's hulls age
    out with their frame's record (track ids are never reused)."""

    def __init__(self, frames: int):
        self.frames = max(1, int(frames))
        # [(frame index, ids (m,) int64, starts (m + 1,) int64, hull points (., 2) float64,
        #   hulls (list))], oldest first
        self._recent: list[tuple] = []

    def step(self, tracks, k: int, shape) -> dict:
        if self.frames <= 1:
            return {t.track_id: t.blob for t in tracks}
        frames = self.frames
        recent = [r for r in self._recent if 0 < k - r[0] < frames]
        # the compiled merge returns this frame's record too (None: a hull it does not take)
        got = _k.merge(tracks, int(k), recent, int(shape[1]), int(shape[0]))
        if got is None:
            raise ValueError("envelope hulls must be (K, 2) float64 arrays")
        env, ids, starts, pts, hulls = got
        self._recent = [r for r in recent if k - r[0] < frames - 1] + [(k, ids, starts, pts, hulls)]
        return env

