"""Envelope merge across frames: a striped LED's envelope is the convex hull of its blobs of
the last few frames (the rows hidden by OFF chips in one frame are lit in another).
"""

from __future__ import annotations


import cv2
import numpy as np
from receiver.core.records import Blob
from receiver.vision.detect import _hull_stats_many


def merge_envelopes_many(items: list[tuple[Blob, list[np.ndarray]]], shape: tuple[int, int]) -> list[Blob]:
    """Each `blob` of (blob, others) with its envelope replaced by the convex hull of its own and
    the `others` (K_i, 2) polygons (px, already moved into this frame). Rolling-shutter stripes
    hide the rows of an LED that fall in OFF chips; the same LED's envelopes from the previous
    frames (other chip phases) fill in its caps. The merged envelope is flagged `border` when it
    reaches the image edge, as `detect` flags a blob. The per-blob work is cut to the OpenCV
    calls: the merge runs for every tracked light in every frame."""
    h, w = shape[:2]
    merged = [i for i, (_, others) in enumerate(items) if others]
    hulls = [cv2.convexHull(np.concatenate([items[i][0].hull] + list(items[i][1])).astype(np.float32)
                            .reshape(-1, 1, 2)) for i in merged]
    out = [blob for blob, _ in items]
    if not merged:
        return out
    cxs, cys, areas = (v.tolist() for v in _hull_stats_many(hulls))
    for i, hull, cx, cy, area in zip(merged, hulls, cxs, cys, areas):
        blob = items[i][0]
        # boundingRect of float points: floor of the extremes, width floor(max) - floor(min) + 1
        x0, y0, bw, bh = cv2.boundingRect(hull)
        x1, y1 = x0 + bw, y0 + bh
        # An envelope carried in from earlier frames can reach past the edge even when this
        # frame's blob does not: its area and centroid are then cut just the same.
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
    `forget(track_ids)` drops the history of ended tracks."""

    def __init__(self, frames: int):
        self.frames = max(1, int(frames))
        self._hulls: dict[int, list] = {}  # track id -> [(frame index, hull (K, 2))]

    def step(self, tracks, k: int, shape) -> dict:
        if self.frames <= 1:
            return {t.track_id: t.blob for t in tracks}
        items = []
        for t in tracks:
            keep = [(kh, h) for kh, h in self._hulls.get(t.track_id, ()) if 0 < k - kh < self.frames]
            items.append((t.blob, [h + (t.vx * (k - kh), t.vy * (k - kh)) for kh, h in keep]))
            self._hulls[t.track_id] = keep + [(k, t.blob.hull)]
        return {t.track_id: env for t, env in zip(tracks, merge_envelopes_many(items, shape))}

    def forget(self, track_ids) -> None:
        for i in track_ids:
            self._hulls.pop(i, None)
