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

import cv2
import numpy as np

from receiver.core.native import load
from receiver.vision.detect import Scratch

# the compiled row scans (receiver/vision/_pixels.pyx), or None: the numpy path below
_k = load("receiver.vision._pixels")

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
                             min_contrast: float = MIN_CONTRAST, bin_rows: int = DEFAULT_BIN_ROWS,
                             scratch: Scratch | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """`stripe_edge_points` of every blob (or envelope polygon) of one frame, in one pass: the
    bounding-box rows of all blobs are gathered into one (rows, widest box) uint8 array (zero
    padded: never lit) and every step after that is one numpy operation over all rows of all
    blobs. `scratch`: work buffers kept across frames (receiver.vision.detect.Scratch), or None.
    Returns one (points, sigma) pair per blob, in order. With the compiled kernels, Blobs with
    float64 hulls take one call (`_pixels.edge_points_blobs`: boxes and points), other items
    `_boxes` and the box kernel (`_edge_points_native`); this numpy path is their reference."""
    if _k is not None and blobs and SIDE_PX == 2 and MIN_RUN_PX == 9:
        # Blobs (float64 hulls) of a uint8 frame: boxes and points in one compiled call
        got = _k.edge_points_blobs(gray, blobs, int(pad), int(border_px), float(min_contrast), int(bin_rows),
                                   MIN_SIGMA_PX, _SIGMA_NUM, MIN_RUN_PX + 2)
        if got is not None:
            return got
    empty = (np.zeros((0, 2)), np.zeros(0))
    out = [empty] * len(blobs)
    h, w = gray.shape[:2]
    boxes = _boxes(gray, blobs, pad)
    if not boxes:
        return out
    if (_k is not None and SIDE_PX == 2 and MIN_RUN_PX == 9 and gray.ndim == 2 and gray.dtype == np.uint8
            and np.float32(min_contrast) == min_contrast):
        return _edge_points_native(gray, boxes, out, border_px, min_contrast, bin_rows)
    if scratch is None:
        scratch = Scratch()
    nb = len(boxes)
    bx = np.array([b[1:5] for b in boxes], dtype=np.int64)
    X0, X1, Y0, Y1 = bx.T
    Rb, Wb = Y1 - Y0, X1 - X0
    r_off = np.concatenate([[0], np.cumsum(Rb)])
    Wmax = int(Wb.max())
    nrows = int(r_off[-1])
    buf = scratch.get("edge_rows", (nrows, Wmax))
    for (_, x0, x1, y0, y1, _), r0, r1 in zip(boxes, r_off[:-1].tolist(), r_off[1:].tolist()):
        buf[r0:r1, :x1 - x0] = gray[y0:y1, x0:x1]
        buf[r0:r1, x1 - x0:] = 0
    # Per-row constants of each row's blob.
    led = np.repeat(np.arange(nb), Rb)
    bg = np.repeat(np.array([b[5] for b in boxes], dtype=np.float32), Rb)
    Wr1 = (Wb - 1)[led]
    rmax = buf.max(axis=1).astype(np.float32)
    thr_lit = bg + np.float32(0.5) * (rmax - bg)
    # uint8 v >= thr  <=>  v >= ceil(thr); rows with thr outside 0..255 fail `has` below.
    lit = np.greater_equal(buf, np.clip(np.ceil(thr_lit), 0, 255).astype(np.uint8)[:, None],
                           out=scratch.get("edge_lit", (nrows, Wmax)).view(bool))
    has = (rmax - bg) >= min_contrast
    # Coarse crossings: first and last lit pixel of each row (the zero padding is never lit
    # for a row that has contrast).
    first = np.argmax(lit, axis=1)
    flipped = cv2.flip(lit.view(np.uint8), 1, dst=scratch.get("edge_flip", (nrows, Wmax)))
    last = np.minimum(Wmax - 1 - np.argmax(flipped.view(bool), axis=1), Wr1)
    ok = has & (last - first + 1 >= MIN_RUN_PX)
    rows = np.flatnonzero(ok)
    if rows.size == 0:
        return out
    n = rows.size
    # Both sides at once: the left ends, then the right ends.
    rows2 = np.concatenate([rows, rows])
    start = np.concatenate([first[rows], last[rows]])
    side = np.repeat(np.array([-1, 1]), n)
    led2 = led[rows2]
    W1 = Wr1[rows2]
    # One gather of every pixel used, per point along its side's outward direction: the
    # plateau (SIDE_PX pixels from 2 px inside the coarse crossing), the outside (SIDE_PX pixels
    # from 3 px outside it) and the walk -1..3 (clamped into the box; clear of the ~0.6 px blur).
    # Offsets along axis 0, points along axis 1 (long rows: no per-point inner loops).
    ar = np.arange(SIDE_PX)
    offs = np.concatenate([-(2 + ar), 3 + ar, np.arange(-1, 4)])
    cols = np.minimum(np.maximum(offs[:, None] * side + start, 0), W1)
    vals = buf.ravel()[cols + rows2 * Wmax].astype(np.float32)
    plateau = vals[:SIDE_PX].sum(axis=0) / np.float32(SIDE_PX)
    outside = vals[SIDE_PX:2 * SIDE_PX].sum(axis=0) / np.float32(SIDE_PX)
    thr = 0.5 * (plateau + outside)
    # The straddling pair around `start`: the first of the walk's pixel pairs (nearer the inside,
    # one pixel further out) that crosses the half level, at most 3 px out.
    a, v = cols[2 * SIDE_PX:], vals[2 * SIDE_PX:]
    hit = (v[:-1] >= thr) & (v[1:] < thr) & (a[:-1] != a[1:])
    k = np.zeros(2 * n, np.int64)
    for j in range(len(hit) - 1, 0, -1):          # the first pair that hits (0 when none)
        k[hit[j]] = j
    k[hit[0]] = 0
    ii = np.arange(2 * n)
    va, vb = v[k, ii], v[k + 1, ii]
    frac = (va - thr) / np.maximum(va - vb, 1e-6)
    pos = np.where(hit[k, ii], a[k, ii] + side * frac, np.nan)
    contrast = plateau - outside
    good = np.isfinite(pos) & (contrast >= min_contrast)
    s = np.maximum(MIN_SIGMA_PX, NOISE_GRAY * np.sqrt(2.0) / np.maximum(0.5 * contrast, 1e-3))
    x0r, x1r = X0[led2], X1[led2]
    x = pos + x0r
    yl = rows2 - r_off[led2]                          # row within its box
    y = (yl + Y0[led2]).astype(np.float64)
    good &= (x >= border_px) & (x <= w - 1 - border_px) & (y >= border_px) & (y <= h - 1 - border_px)
    # An edge pixel sampled at the box's own border (the blob reaches past it) is not an edge.
    good &= (x > x0r + 1) & (x < x1r - 2)
    s = s.astype(np.float64)
    if bin_rows > 1:
        # Bins of `bin_rows` rows per blob and side, numbered blob by blob, left side first.
        nbin = (Rb + bin_rows - 1) // bin_rows
        b_off = np.concatenate([[0], np.cumsum(2 * nbin)])
        key = (b_off[led2] + (side > 0) * nbin[led2] + yl // bin_rows)[good]
        m = int(b_off[-1])
        cnt = np.bincount(key, minlength=m)
        used = np.flatnonzero(cnt)
        c = cnt[used]
        px = np.bincount(key, x[good], m)[used] / c
        py = np.bincount(key, y[good], m)[used] / c
        ps = np.sqrt(np.bincount(key, (s * s)[good], m)[used]) / c
        owner = np.searchsorted(b_off, used, side="right") - 1
    else:
        order = np.argsort(led2 * 2 + (side > 0), kind="stable")
        sel = order[good[order]]
        px, py, ps, owner = x[sel], y[sel], s[sel], led2[sel]
    pts = np.column_stack([px, py])
    ends = np.searchsorted(owner, np.arange(nb + 1), side="left")
    for k in range(nb):
        e0, e1 = ends[k], ends[k + 1]
        if e1 > e0:
            out[boxes[k][0]] = (pts[e0:e1], ps[e0:e1])
    return out


def _edge_points_native(gray, boxes, out, border_px, min_contrast, bin_rows):
    """`stripe_edge_points_batch` by the compiled kernel (`_pixels.edge_points`), row by row
    straight from the frame: the same points and sigmas, bit for bit (tests/vision/test_outline.py)."""
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
