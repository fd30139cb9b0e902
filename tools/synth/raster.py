"""Anti-aliased polygon coverage and polygon moments (image plane, pixels).

Pixel (u, v) covers [u-0.5, u+0.5] x [v-0.5, v+0.5] (OpenCV: centres at integers).
Coverage is exact along x (each sub-row's span is intersected with each pixel analytically)
and supersampled along y with `subrows` sample lines per pixel row, which is what a
`subrows x infinity` supersampling of the shape gives. Shapes are projected LED outlines:
convex in the scene, and still convex (or very nearly, under lens distortion) in the image,
so each sample line crosses the outline at most twice; the span is taken from the outermost
crossings.
"""

from __future__ import annotations

import numpy as np

SUBROWS_DEFAULT = 4


def polygon_area_centroid(poly: np.ndarray):
    """Signed-area-independent (area_px, cx, cy) of a simple polygon (M, 2), shoelace formula."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a2 = cross.sum()
    if abs(a2) < 1e-12:
        return 0.0, float(x.mean()), float(y.mean())
    cx = ((x + xn) * cross).sum() / (3.0 * a2)
    cy = ((y + yn) * cross).sum() / (3.0 * a2)
    return abs(a2) / 2.0, float(cx), float(cy)


def coverage(poly: np.ndarray, r0: int, r1: int, c0: int, c1: int, subrows: int = SUBROWS_DEFAULT) -> np.ndarray:
    """Fraction of each pixel of rows r0..r1-1, columns c0..c1-1 covered by `poly` (M, 2).

    Returns a float32 array of shape (r1 - r0, c1 - c0) with values in [0, 1].
    """
    nr, nc = r1 - r0, c1 - c0
    if nr <= 0 or nc <= 0:
        return np.zeros((max(nr, 0), max(nc, 0)), dtype=np.float32)
    ys = (np.arange(nr * subrows, dtype=np.float64) + 0.5) / subrows + (r0 - 0.5)
    xa, ya = poly[:, 0], poly[:, 1]
    xb, yb = np.roll(xa, -1), np.roll(ya, -1)
    lo, hi = np.minimum(ya, yb), np.maximum(ya, yb)
    dy = yb - ya
    slope = np.divide(xb - xa, dy, out=np.zeros_like(dy), where=dy != 0)
    Y = ys[:, None]
    hit = (Y >= lo) & (Y < hi)
    X = xa + (Y - ya) * slope
    xl = np.where(hit, X, np.inf).min(axis=1)
    xr = np.where(hit, X, -np.inf).max(axis=1)
    valid = xr > xl
    xl = np.where(valid, xl, 0.0)[:, None]
    xr = np.where(valid, xr, 0.0)[:, None]
    cols = np.arange(c0, c1, dtype=np.float64)[None, :]
    cov = np.clip(np.minimum(xr, cols + 0.5) - np.maximum(xl, cols - 0.5), 0.0, 1.0)
    return cov.reshape(nr, subrows, nc).mean(axis=1).astype(np.float32)
