"""Envelope merge across frames: a striped LED's envelope is the convex hull of its blobs of
the last few frames (the rows hidden by OFF chips in one frame are lit in another).
"""

from __future__ import annotations


import cv2
import numpy as np
from receiver.core.native import load
from receiver.core.records import Blob
from receiver.vision.detect import _hull_stats_many

# the compiled merge of all lights of a frame (receiver/vision/_envelope.pyx), or None: `_merge`
_k = load("receiver.vision._envelope")


def merge_envelopes_many(items: list[tuple[Blob, list[np.ndarray]]], shape: tuple[int, int]) -> list[Blob]:
    """Each `blob` of (blob, others) with its envelope replaced by the convex hull of its own and
    the `others` (K_i, 2) polygons (px, already moved into this frame). Rolling-shutter stripes
    hide the rows of an LED that fall in OFF chips; the same LED's envelopes from the previous
    frames (other chip phases) fill in its caps. The merged envelope is flagged `border` when it
    reaches the image edge, as `detect` flags a blob. The per-blob work is cut to the OpenCV
    calls: the merge runs for every tracked light in every frame."""
    merged = [i for i, (_, others) in enumerate(items) if others]
    pieces = [p for i in merged for p in [items[i][0].hull, *items[i][1]]]
    counts = [1 + len(items[i][1]) for i in merged]
    return _merge(items, merged, pieces, counts, None, shape)


def _merge(items, merged: list[int], pieces: list[np.ndarray], counts: list[int], moves, shape) -> list[Blob]:
    """`merge_envelopes_many` of the items `merged` (indices into `items`), whose polygons are
    `pieces` in order: counts[j] consecutive ones (the blob's own hull first) for merged[j].
    `moves`: None, or (len(pieces), 2) px added to each piece's points (0 for the own hulls).
    One light at a time, with OpenCV (the path where the compiled merge does not answer)."""
    out = [blob for blob, _ in items]
    h, w = shape[:2]
    hulls, a = [], 0
    for c in counts:
        own = pieces[a:a + c]
        if moves is not None:
            own = [own[0]] + [p + mv for p, mv in zip(own[1:], moves[a + 1:a + c])]
        hulls.append(cv2.convexHull(np.concatenate(own).astype(np.float32).reshape(-1, 1, 2)))
        a += c
    cxs, cys, areas = (v.tolist() for v in _hull_stats_many(hulls))
    for i, hull, cx, cy, area in zip(merged, hulls, cxs, cys, areas):
        blob = out[i]
        # boundingRect of float points: floor of the extremes, width floor(max) - floor(min) + 1
        x0, y0, bw, bh = cv2.boundingRect(hull)
        x1, y1 = x0 + bw, y0 + bh
        border = blob.border or x0 <= 0 or y0 <= 0 or x1 >= w or y1 >= h
        out[i] = Blob(cx, cy, area, hull.reshape(-1, 2).astype(np.float64), max(x0, 0), max(y0, 0),
                      min(x1, w), min(y1, h), border, blob.peak, blob.level, blob.background)
    return out


class EnvelopeHistory:
    """Each tracked light's envelope over its last `frames` frames (init/step).

    `step(tracks, k, shape)` returns {track_id: envelope Blob} for the tracks seen in frame `k`:
    this frame's blob merged with its hulls of the previous `frames - 1` frames, each moved by
    the track's px/frame velocity (its jitter from the hidden caps limits how much a static
    scene gains; a moving one needs the motion). `frames` 1 = this frame's blob alone.

    The history is one record per frame (the seen tracks' ids and hulls, all in one array),
    kept while a later frame can still use it: frame indices must grow (gaps are fine); a frame
    index at or below an earlier one starts the history afresh. All lights of a frame are merged
    by one call of the compiled kernel (receiver/vision/_envelope.pyx) when it is built, else
    (or where it declines a hull) one by one with OpenCV (`_merge`: the same numbers). An
    ended track's hulls age out with their frame's record (track ids are never reused)."""

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
        got = _k.merge(tracks, int(k), recent, int(shape[1]), int(shape[0])) if _k is not None else None
        if got is not None:
            env, ids, starts, pts, hulls = got
        else:
            n = len(tracks)
            hulls = [t.blob.hull for t in tracks]
            pts = (np.ascontiguousarray(np.concatenate(hulls, dtype=np.float64).reshape(-1, 2)) if n
                   else np.zeros((0, 2)))
            ids = np.array([t.track_id for t in tracks], np.int64)
            starts = np.zeros(n + 1, np.int64)
            np.cumsum([len(p) for p in hulls], out=starts[1:])
            env = _step_pure(tracks, recent, k, shape) if recent and n else {t.track_id: t.blob for t in tracks}
        self._recent = [r for r in recent if k - r[0] < frames - 1] + [(k, ids, starts, pts, hulls)]
        return env


def _step_pure(tracks, recent, k: int, shape) -> dict:
    """`EnvelopeHistory.step` by `_merge`: each light's own hull, then its hulls of the earlier
    frames (oldest first) moved by its velocity."""
    items, merged, pieces, counts, moves = [], [], [], [], []
    hull_of = [dict(zip(r[1].tolist(), r[4])) for r in recent]
    for i, t in enumerate(tracks):
        keep = [(r[0], h[t.track_id]) for r, h in zip(recent, hull_of) if t.track_id in h]
        if keep:
            merged.append(i)
            counts.append(1 + len(keep))
            pieces.append(t.blob.hull)
            moves.append((0.0, 0.0))
            for kh, hh in keep:  # moved by the track's velocity into this frame
                pieces.append(hh)
                moves.append((t.vx * (k - kh), t.vy * (k - kh)))
        items.append((t.blob, None))
    env = _merge(items, merged, pieces, counts, moves if moves else None, shape)
    return {t.track_id: e for t, e in zip(tracks, env)}
