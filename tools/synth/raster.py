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


def _lower_left_integral(xa, ya, xb, yb, X, Y):
    """Per edge and per corner (X, Y): the edge's share of ``area(poly ∩ {x < X, y < Y})``.

    By Green's theorem the area of the polygon inside the quadrant ``{x < X, y < Y}`` is
    ``∮ min(x, X) * [y < Y] dy`` around the outline (counter-clockwise in (x, y); the other
    orientation gives its negative). For a straight edge, ``min(x(y), X)`` over the clipped
    y-range is the integral of ``min(f, 0) + X`` with f linear, closed-form:
    ``∫_0^L min(f, 0) = L (min(b, 0)^2 - min(a, 0)^2) / (2 (b - a))`` for f going from a to b.
    Shapes: edges (E, 1, 1), X (1, 1, C), Y (1, R, 1) -> (E, R, C).
    """
    up = yb > ya
    lo = np.where(up, ya, yb)
    hi = np.where(up, yb, ya)
    sign = np.where(up, 1.0, -1.0)
    x_lo = np.where(up, xa, xb)
    dy = hi - lo
    slope = np.divide(xb - xa, yb - ya, out=np.zeros_like(dy), where=dy > 0)
    q = np.minimum(hi, Y)
    length = np.maximum(q - lo, 0.0)  # (E, R, 1)
    a = x_lo - X  # f = x - X at y = lo
    b = x_lo + slope * length - X  # at y = q
    d = b - a
    na, nb = np.minimum(a, 0.0), np.minimum(b, 0.0)
    safe = np.abs(d) > 1e-12
    neg = np.where(safe, length * (nb * nb - na * na) / np.where(safe, 2.0 * d, 1.0), length * 0.5 * (na + nb))
    return sign * (neg + X * length)


def coverage_exact(poly: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """Exact area fraction of each pixel of rows r0..r1-1, columns c0..c1-1 inside `poly` (M, 2).

    Unlike `coverage`, nothing is sampled: each pixel's value is the exact area of the
    polygon inside it (any simple polygon, convex or not), so the sum over a region that
    holds the polygon equals its shoelace area to rounding. This is what a shape only a
    fraction of a pixel tall needs (a far street-light panel seen almost edge-on, ~0.2 px
    tall): `subrows` sample lines would see it in 0, 1 or 2 of them and its flux would jump
    between frames. Cost grows as edges x rows x columns, so the renderer uses it only for
    shapes a few rows tall (`RenderParams.exact_coverage_rows`).
    """
    nr, nc = r1 - r0, c1 - c0
    if nr <= 0 or nc <= 0:
        return np.zeros((max(nr, 0), max(nc, 0)), dtype=np.float32)
    p = np.asarray(poly, dtype=np.float64)
    xa, ya = p[:, 0], p[:, 1]
    xb, yb = np.roll(xa, -1), np.roll(ya, -1)
    e = (slice(None), None, None)
    X = (np.arange(c0, c1 + 1, dtype=np.float64) - 0.5)[None, None, :]
    Y = (np.arange(r0, r1 + 1, dtype=np.float64) - 0.5)[None, :, None]
    F = _lower_left_integral(xa[e], ya[e], xb[e], yb[e], X, Y).sum(axis=0)  # (R+1, C+1)
    cells = F[1:, 1:] - F[1:, :-1] - F[:-1, 1:] + F[:-1, :-1]
    signed = float((xa * (yb - ya) + xb * (yb - ya)).sum() / 2.0)  # ∮ x dy, the orientation
    if signed < 0:
        cells = -cells
    return np.clip(cells, 0.0, 1.0).astype(np.float32)
