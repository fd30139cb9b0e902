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

import numpy as np

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


def _bbox(blob_or_contour, shape, pad: int):
    if hasattr(blob_or_contour, "hull"):
        hull = np.asarray(blob_or_contour.hull, float).reshape(-1, 2)
        bg = float(getattr(blob_or_contour, "background", 0.0))
    else:
        hull = np.asarray(blob_or_contour, float).reshape(-1, 2)
        bg = None
    h, w = shape[:2]
    x0 = max(int(np.floor(hull[:, 0].min())) - pad, 0)
    x1 = min(int(np.ceil(hull[:, 0].max())) + pad + 1, w)
    y0 = max(int(np.floor(hull[:, 1].min())) - 1, 0)
    y1 = min(int(np.ceil(hull[:, 1].max())) + 2, h)
    return x0, x1, y0, y1, bg


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
    pose solve's work by that factor at no cost in information along straight edges. Returns ((N, 2) float64 distorted px (x, y) with y the row's centre,
    (N,) float64 1-sigma px); empty arrays when nothing qualifies. Vectorised over rows.
    """
    x0, x1, y0, y1, bg_blob = _bbox(blob_or_contour, gray.shape, pad)
    empty = (np.zeros((0, 2)), np.zeros(0))
    if x1 - x0 < MIN_RUN_PX + 2 or y1 <= y0:
        return empty
    roi = np.asarray(gray[y0:y1, x0:x1], dtype=np.float32)
    R, W = roi.shape
    rmax = roi.max(axis=1)
    bg = np.float32(bg_blob if bg_blob is not None else np.percentile(roi, 5))
    lit = roi >= (bg + 0.5 * (rmax - bg))[:, None]
    has = (rmax - bg) >= min_contrast
    # Coarse crossings: first and last lit pixel of each row.
    first = np.argmax(lit, axis=1)
    last = W - 1 - np.argmax(lit[:, ::-1], axis=1)
    ok = has & (last - first + 1 >= MIN_RUN_PX)
    rows = np.flatnonzero(ok)
    if rows.size == 0:
        return empty
    pts, sig = [], []
    ar = np.arange(SIDE_PX)
    for side, start in ((-1, first[rows]), (1, last[rows])):
        # Plateau: SIDE_PX pixels inside, from 2 px past the coarse crossing; outside: SIDE_PX
        # pixels from 3 px outside it (clamped into the ROI), clear of the ~0.6 px blur.
        inner = np.clip(start[:, None] - side * (2 + ar)[None, :], 0, W - 1)
        outer = np.clip(start[:, None] + side * (3 + ar)[None, :], 0, W - 1)
        plateau = roi[rows[:, None], inner].mean(axis=1)
        outside = roi[rows[:, None], outer].mean(axis=1)
        thr = 0.5 * (plateau + outside)
        # The straddling pair around `start`: walk from the inner pixel outward (at most 3 px).
        pos = np.full(rows.size, np.nan)
        for k in range(-1, 3):
            a = np.clip(start + side * k, 0, W - 1)          # nearer the inside
            b = np.clip(start + side * (k + 1), 0, W - 1)    # one pixel further out
            va, vb = roi[rows, a], roi[rows, b]
            hit = np.isnan(pos) & (va >= thr) & (vb < thr) & (a != b)
            frac = (va - thr) / np.maximum(va - vb, 1e-6)
            pos = np.where(hit, a + side * frac, pos)
        contrast = plateau - outside
        good = np.isfinite(pos) & (contrast >= min_contrast)
        s = np.maximum(MIN_SIGMA_PX, NOISE_GRAY * np.sqrt(2.0) / np.maximum(0.5 * contrast, 1e-3))
        x = pos + x0
        y = (rows + y0).astype(np.float64)
        h, w = gray.shape[:2]
        good &= (x >= border_px) & (x <= w - 1 - border_px) & (y >= border_px) & (y <= h - 1 - border_px)
        # An edge pixel sampled at the ROI's own border (the blob reaches past it) is not an edge.
        good &= (x > x0 + 1) & (x < x1 - 2)
        x, y, s = x[good], y[good], s[good].astype(np.float64)
        if bin_rows > 1 and x.size:
            b = ((y - y0) // bin_rows).astype(np.int64)
            _, inv, cnt = np.unique(b, return_inverse=True, return_counts=True)
            x = np.bincount(inv, x) / cnt
            y = np.bincount(inv, y) / cnt
            s = np.sqrt(np.bincount(inv, s * s)) / cnt
        pts.append(np.column_stack([x, y]))
        sig.append(s)
    return np.concatenate(pts).astype(np.float64), np.concatenate(sig).astype(np.float64)
