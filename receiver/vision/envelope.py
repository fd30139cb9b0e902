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
