"""The LED's outline from its lit stripes: sub-pixel edge points, and shape fits to them.

A rolling-shutter frame shows an OOK LED as lit stripes (rows whose exposure fell in ON chips).
The caps of the striped blob (its first and last lit rows) lie on the LED's outline only when
the LED's top or bottom edge happens to fall in an ON chip, but the two ends of *every* lit row
lie on the outline: the row crosses the LED's boundary there. `stripe_edge_points` measures
those ends sub-pixel from the intensity profile along the row: the crossing of the half level
between the dark outside and the lit plateau next to the edge (a box-sampled, symmetrically
blurred step crosses its half level at the true edge, whatever the blur), interpolated linearly
between the two pixel centres that straddle it. Rows whose exposure straddled a chip boundary
are dimmer but uniform along the row, so their ends count as well (the half level is the row's
own). Points next to the image border or in runs too short to hold an edge on each side are
dropped.

The points are distorted pixels (as in the frame); `receiver.locate.outline_pose` undistorts them
and fits the map's fixture outlines (square/rect: four straight edges, circle: a circle on the
ceiling, i.e. an ellipse in the image) with the camera pose.

Per-point 1-sigma (px): ``sigma = read noise * sqrt(2) / slope`` with the slope of the edge
(half the contrast per pixel for an edge blurred over ~2 px), floored at `MIN_SIGMA_PX` for
what the model leaves out (PSF asymmetry, quantisation).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.core.native import require

# the compiled row scans (receiver/vision/_pixels.pyx: `edge_points`, `edge_points_blobs`), the
# one implementation of the edge points; they sample SIDE_PX = 2 and need MIN_RUN_PX = 9
_k = require("receiver.vision._pixels")

# Smallest contrast (gray levels) between the lit plateau and the outside for a row to count.
MIN_CONTRAST = 20.0
# Pixels of plateau and of outside sampled next to each edge.
SIDE_PX = 2
# Shortest lit run (px) in a row: an edge on each side plus its plateau.
MIN_RUN_PX = 2 * SIDE_PX + 5
# Floor of a point's sigma, px.
MIN_SIGMA_PX = 0.05
# Rows per averaged edge point (`stripe_edge_points`' bin_rows).
DEFAULT_BIN_ROWS = 4
# Noise of one pixel's gray value assumed for the sigma (gray levels, incl. quantisation).
NOISE_GRAY = 2.0
# A point's sigma times its edge's slope (`sigma = _SIGMA_NUM / slope`), the kernels' form.
_SIGMA_NUM = NOISE_GRAY * math.sqrt(2.0)


def _bbox(blob_or_contour, shape, pad: int):
    if hasattr(blob_or_contour, "hull"):
        hull = np.asarray(blob_or_contour.hull, float).reshape(-1, 2)
        bg = float(getattr(blob_or_contour, "background", 0.0))
    else:
        hull = np.asarray(blob_or_contour, float).reshape(-1, 2)
        bg = None
    h, w = shape[:2]
    lo, hi = hull.min(axis=0), hull.max(axis=0)
    x0 = max(math.floor(lo[0]) - pad, 0)
    x1 = min(math.ceil(hi[0]) + pad + 1, w)
    y0 = max(math.floor(lo[1]) - 1, 0)
    y1 = min(math.ceil(hi[1]) + 2, h)
    return x0, x1, y0, y1, bg


def _boxes(gray: np.ndarray, blobs, pad: int) -> list[tuple]:
    """(index, x0, x1, y0, y1, background) of the blobs (or polygons) whose box (`_bbox`) can
    hold a run: the boxes of `Blob`s all at once (the same floor / ceil of their hulls'
    extremes), a polygon's background the 5th percentile of its box."""
    hh, ww = gray.shape[:2]
    boxes = []
    if all(hasattr(b, "hull") for b in blobs):
        if not blobs:
            return boxes
        hulls = [np.asarray(b.hull, float).reshape(-1, 2) for b in blobs]
        starts = np.zeros(len(hulls), np.int64)
        np.cumsum([len(p) for p in hulls[:-1]], out=starts[1:])
        pts = np.concatenate(hulls)
        lo, hi = np.minimum.reduceat(pts, starts), np.maximum.reduceat(pts, starts)
        x0 = np.maximum(np.floor(lo[:, 0]).astype(np.int64) - pad, 0).tolist()
        x1 = np.minimum(np.ceil(hi[:, 0]).astype(np.int64) + pad + 1, ww).tolist()
        y0 = np.maximum(np.floor(lo[:, 1]).astype(np.int64) - 1, 0).tolist()
        y1 = np.minimum(np.ceil(hi[:, 1]).astype(np.int64) + 2, hh).tolist()
        for i, b in enumerate(blobs):
            if x1[i] - x0[i] >= MIN_RUN_PX + 2 and y1[i] > y0[i]:
                boxes.append((i, x0[i], x1[i], y0[i], y1[i], float(getattr(b, "background", 0.0))))
        return boxes
    for i, b in enumerate(blobs):
        x0, x1, y0, y1, bg = _bbox(b, gray.shape, pad)
        if x1 - x0 < MIN_RUN_PX + 2 or y1 <= y0:
            continue
        if bg is None:
            bg = np.percentile(np.asarray(gray[y0:y1, x0:x1], dtype=np.float32), 5)
        boxes.append((i, x0, x1, y0, y1, bg))
    return boxes


def stripe_edge_points(gray: np.ndarray, blob_or_contour, *, pad: int = 4, border_px: int = 2,
                       min_contrast: float = MIN_CONTRAST, bin_rows: int = DEFAULT_BIN_ROWS
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel left and right ends of the lit rows of one LED blob (module doc).

    `gray`: (H, W) uint8 frame; `blob_or_contour`: a `Blob` (its `hull`, `background`) or a
    (K, 2) envelope polygon, px. Each row of the envelope's bounding box (grown by `pad` px
    sideways) whose brightest run is lit contributes its first and last crossing of the half
    level. Points within `border_px` of the image edge are dropped (a cut LED keeps its
    visible edges). `bin_rows` > 1: the points of each side are averaged over bins of that many
    rows (the mean of points on a straight edge lies on it; sigma / sqrt(n)), which cuts the
    pose solve's work by that factor at no cost in information along straight edges. Returns
    ((N, 2) float64 distorted px (x, y) with y the row's centre, (N,) float64 1-sigma px), the
    left side's points first, each side by row; empty arrays when nothing qualifies.
    One LED of `stripe_edge_points_batch`.
    """
    return stripe_edge_points_batch(gray, [blob_or_contour], pad=pad, border_px=border_px,
                                    min_contrast=min_contrast, bin_rows=bin_rows)[0]


def stripe_edge_points_batch(gray: np.ndarray, blobs, *, pad: int = 4, border_px: int = 2,
                             min_contrast: float = MIN_CONTRAST, bin_rows: int = DEFAULT_BIN_ROWS
                             ) -> list[tuple[np.ndarray, np.ndarray]]:
    """`stripe_edge_points` of every blob (or envelope polygon) of one (H, W) uint8 frame, by the
    compiled row scans. Returns one (points, sigma) pair per blob, in order. Blobs with float64 hulls
    take one call (`_pixels.edge_points_blobs`: boxes and points), other items `_boxes` and the
    box kernel (`_edge_points_native`). `min_contrast` is compared in float32."""
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise TypeError(f"expected an (H, W) uint8 frame, got {gray.dtype} {gray.shape}")
    if blobs:
        # Blobs (float64 hulls) of a uint8 frame: boxes and points in one compiled call
        got = _k.edge_points_blobs(gray, blobs, int(pad), int(border_px), float(min_contrast), int(bin_rows),
                                   MIN_SIGMA_PX, _SIGMA_NUM, MIN_RUN_PX + 2)
        if got is not None:
            return got
    out = [(np.zeros((0, 2)), np.zeros(0))] * len(blobs)
    boxes = _boxes(gray, blobs, pad)
    if not boxes:
        return out
    return _edge_points_native(gray, boxes, out, border_px, min_contrast, bin_rows)


def _edge_points_native(gray, boxes, out, border_px, min_contrast, bin_rows):
    """`stripe_edge_points_batch` by the compiled kernel (`_pixels.edge_points`), row by row
    straight from the frame."""
    bx = np.array([b[1:5] for b in boxes], dtype=np.int64)
    x0, x1, y0, y1 = (np.ascontiguousarray(c) for c in bx.T)
    bg = np.array([b[5] for b in boxes], dtype=np.float32)
    n = 2 * int((y1 - y0).sum())
    pts, sig = np.empty((n, 2)), np.empty(n)
    ends = np.empty(len(boxes) + 1, np.int64)
    _k.edge_points(np.ascontiguousarray(gray), x0, x1, y0, y1, bg, int(border_px), float(min_contrast),
                   int(bin_rows), MIN_SIGMA_PX, _SIGMA_NUM, pts, sig, ends)
    el = ends.tolist()
    for k, b in enumerate(boxes):
        if el[k + 1] > el[k]:
            out[b[0]] = (pts[el[k]:el[k + 1]], sig[el[k]:el[k + 1]])
    return out
