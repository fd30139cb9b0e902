"""The image side's compiled kernels (receiver/vision/_pixels.pyx) against their pure numpy
references: the same numbers bit for bit, on frames of every bundled recording and on random
scenes (the pure path runs with the module's `_k` set to None)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from receiver.core.native import load
from receiver.io.sources import open_source
from receiver.vision import outline
from receiver.vision.detect import detect

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = ("indoor-walk", "indoor-static", "indoor-sparse", "vehicle")
_px = load("receiver.vision._pixels")
needs_kernel = pytest.mark.skipif(_px is None, reason="kernels not built or OCCLOC_PURE=1 (test_native checks the build)")


def _frames(name: str, every: int = 9, limit: int = 5):
    """Every `every`-th frame of a bundled recording, at most `limit` of them."""
    out = []
    for i, f in enumerate(open_source(str(ROOT / "recordings" / name))):
        if i % every == 0:
            out.append(f.gray)
            if len(out) == limit:
                break
    return out


def _pure(module, monkeypatch, fn, *args, **kw):
    with monkeypatch.context() as m:
        m.setattr(module, "_k", None)
        return fn(*args, **kw)


def _same_points(a, b):
    assert len(a) == len(b)
    for (p, s), (q, t) in zip(a, b):
        assert p.shape == q.shape and s.shape == t.shape
        assert np.array_equal(p, q) and np.array_equal(s, t)


def _random_scene(rng, h=240, w=320, n=6):
    """A dark noisy frame with n striped rectangles (some clipped, some at the border)."""
    g = rng.normal(rng.uniform(0, 30), rng.uniform(0.3, 4), (h, w))
    for _ in range(n):
        x0, y0 = int(rng.integers(-10, w - 20)), int(rng.integers(-10, h - 20))
        bw, bh = int(rng.integers(6, 90)), int(rng.integers(3, 90))
        period = int(rng.integers(2, 20))
        rows = np.arange(max(y0, 0), min(y0 + bh, h))
        lit = ((rows // max(period // 2, 1)) % 2 == 0)
        g[rows[lit], max(x0, 0):min(x0 + bw, w)] += rng.uniform(20, 300)
    g = np.clip(g, 0, 255)
    # blur the edges a little (sub-pixel crossings)
    g[:, 1:] = 0.7 * g[:, 1:] + 0.3 * g[:, :-1]
    return np.ascontiguousarray(np.rint(g).astype(np.uint8))


@needs_kernel
def test_byte_scans_equal_numpy():
    rng = np.random.default_rng(1)
    for n in list(range(0, 40)) + [63, 64, 65, 200]:
        for _ in range(5):
            row = (rng.integers(0, 256, n) // rng.integers(1, 40)).astype(np.uint8)
            t = int(rng.integers(0, 256))
            m, first, last = _px.u8_scan(row, t)
            on = np.flatnonzero(row >= t)
            assert m == (int(row.max()) if n else 0)
            assert first == (int(on[0]) if on.size else -1)
            assert last == (int(on[-1]) if on.size else -1)


@needs_kernel
@pytest.mark.parametrize("name", RECORDINGS)
def test_edge_points_kernel_equals_numpy_on_recordings(name, monkeypatch):
    total = 0
    for gray in _frames(name):
        blobs = detect(gray)
        for bin_rows in (1, 4):
            a = outline.stripe_edge_points_batch(gray, blobs, bin_rows=bin_rows)
            b = _pure(outline, monkeypatch, outline.stripe_edge_points_batch, gray, blobs, bin_rows=bin_rows)
            _same_points(a, b)
            total += sum(len(p) for p, _ in a)
    assert total > 0 or name == "vehicle"  # S2-PSK heads are too small for runs


@needs_kernel
def test_edge_points_kernel_equals_numpy_on_random_scenes(monkeypatch):
    rng = np.random.default_rng(7)
    total = 0
    for _ in range(30):
        gray = _random_scene(rng)
        blobs = detect(gray, stripe_gap_px=12)
        polys = [b.hull + rng.normal(0, 2, b.hull.shape) for b in blobs]  # polygons: own background
        for items in (blobs, polys):
            for kw in ({}, {"bin_rows": 3}, {"border_px": 0, "min_contrast": 8.0}, {"bin_rows": 1, "pad": 1}):
                a = outline.stripe_edge_points_batch(gray, items, **kw)
                b = _pure(outline, monkeypatch, outline.stripe_edge_points_batch, gray, items, **kw)
                _same_points(a, b)
                total += sum(len(p) for p, _ in a)
    assert total > 100
