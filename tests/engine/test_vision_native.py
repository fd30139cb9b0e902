"""The image side's compiled kernels (receiver/vision/_pixels.pyx) against the OpenCV / numpy
paths the stage takes where the kernel does not answer (`_k` set to None): the same blobs
(`same_blob`: same boxes and decisions, same hull vertices, centroid and area within float
rounding) and the same edge points, on frames of every bundled recording and on random scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from receiver.core.native import load
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.io.sources import open_source
from receiver.pipeline import Receiver
from receiver.vision import detect as detect_mod
from receiver.vision import outline
from receiver.vision.detect import detect
from tests.vision.test_detect import detect_with_pool, same_blob

ROOT = Path(__file__).resolve().parents[2]
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


def _settings(name: str):
    """The detection settings the pipeline uses on a bundled recording (its camera and map)."""
    folder = ROOT / "recordings" / name
    rx = Receiver(load_camera(str(folder / "camera.yaml")), load_map(str(folder / "map.json")))
    return rx.settings.detect


def _same_blobs(a, b):
    assert len(a) == len(b)
    for p, q in zip(a, b):
        assert same_blob(p, q), (p, q)


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


@needs_kernel
@pytest.mark.parametrize("name", RECORDINGS)
def test_detect_kernels_equal_numpy_on_recordings(name, monkeypatch):
    """`detect` with the compiled box scans (peaks, row ends, the pooled search's boxes) gives
    the numpy path's blobs, on the pipeline's settings of each recording and at full resolution
    (ROW_POOL 1)."""
    s = _settings(name)
    n = 0
    for gray in _frames(name):
        for pool in (detect_mod.ROW_POOL, 1):
            a = detect_with_pool(gray, pool, settings=s)
            b = _pure(detect_mod, monkeypatch, detect_with_pool, gray, pool, settings=s)
            _same_blobs(a, b)
            n += len(a)
    assert n > 0


@needs_kernel
def test_detect_kernels_equal_numpy_on_random_scenes(monkeypatch):
    rng = np.random.default_rng(11)
    n = 0
    for _ in range(40):
        gray = _random_scene(rng, n=int(rng.integers(0, 9)))
        pool = int(rng.integers(1, 3))
        kw = {"stripe_gap_px": int(rng.integers(0, 20)),
              "fine_noise": bool(rng.integers(0, 2)), "min_contrast": float(rng.uniform(3, 30))}
        a = detect_with_pool(gray, pool, **kw)
        b = _pure(detect_mod, monkeypatch, detect_with_pool, gray, pool, **kw)
        _same_blobs(a, b)
        n += len(a)
    assert n > 20


@needs_kernel
def test_search_mask_equals_threshold_of_the_row_maxima():
    """`_pixels.search_mask` = cv2.threshold of `_row_max` (pool 1, 2; odd heights, narrow and
    odd widths, levels below 0 and at 255) and cv2.boundingRect of that mask."""
    import cv2
    rng = np.random.default_rng(5)
    for h, w in ((1, 1), (3, 5), (7, 16), (9, 17), (30, 33), (31, 64), (120, 200)):
        gray = np.ascontiguousarray((rng.integers(0, 256, (h, w)) * (rng.random((h, w)) < 0.1)).astype(np.uint8))
        for pool in (1, 2):
            search = detect_mod._row_max(gray, pool) if pool > 1 else gray
            for level in (-3.0, 0.0, 0.5, 24.0, 100.7, 254.2, 255.0, 300.0):
                _, want = cv2.threshold(search, level, 255, cv2.THRESH_BINARY)
                mask = np.empty_like(want)
                on = min(max(int(np.floor(level)) + 1, 0), 256)
                box = _px.search_mask(gray, pool, on, mask)
                assert np.array_equal(mask, want), (h, w, pool, level)
                assert tuple(box) == tuple(cv2.boundingRect(want))


@needs_kernel
def test_sample_histogram_equals_calchist():
    import cv2
    rng = np.random.default_rng(9)
    for h, w in ((1, 1), (5, 7), (720, 1280), (33, 65)):
        gray = np.ascontiguousarray(rng.integers(0, 256, (h, w)).astype(np.uint8))
        for step in (1, 3, 4):
            want = cv2.calcHist([np.ascontiguousarray(gray[::step, ::step])], [0], None, [256], [0, 256]).ravel()
            got = np.empty(256, np.float32)
            _px.sample_hist(gray, step, got)
            assert got.dtype == want.dtype and np.array_equal(got, want)


@needs_kernel
@pytest.mark.parametrize("name", RECORDINGS)
def test_row_profile_and_mask_mean_kernels_equal_opencv(name, monkeypatch):
    """`row_profile` and `mean_in_mask` by the compiled masked sums equal the OpenCV path (the
    profile's dtype and every value), on each recording's blobs and on boxes moved past the
    frame's edges (a pair's predicted emitter)."""
    from dataclasses import replace
    from receiver.vision import profile
    s = _settings(name)
    n = 0
    for gray in _frames(name, limit=3):
        h, w = gray.shape
        for b in detect(gray, settings=s):
            moved = [b, replace(b, hull=b.hull + (w - b.x1 + 2, 0), x0=w - (b.x1 - b.x0) + 2, x1=w + 2),
                     replace(b, hull=b.hull - (0, b.y0 + 1), y0=-1, y1=b.y1 - b.y0 - 1)]
            for blob in moved:
                p, wt, y0 = profile.row_profile(gray, blob)
                q, wq, z0 = _pure(profile, monkeypatch, profile.row_profile, gray, blob)
                assert p.dtype == q.dtype and wt.dtype == wq.dtype and y0 == z0
                assert np.array_equal(p, q) and np.array_equal(wt, wq)
                a = profile.mean_in_mask(gray, blob)
                assert a == _pure(profile, monkeypatch, profile.mean_in_mask, gray, blob)
                assert type(a) is float
                n += 1
    assert n > 0


@needs_kernel
def test_box_kernels_refuse_boxes_outside_the_frame():
    """The box scans never read outside the frame: pooled_boxes says False (its caller takes the
    numpy path), refine_alone -1 (tests/engine/test_detect_kernels.py)."""
    gray = np.zeros((20, 30), np.uint8)
    for box in ((-1, 0, 5, 5), (26, 0, 5, 5), (0, 16, 5, 5), (0, 0, 31, 1)):
        rects = np.array([box], np.int64)
        assert _px.pooled_boxes(gray, rects, 1, 2, 0, np.empty((1, 4), np.int64)) is False


@needs_kernel
def test_edge_points_kernel_refuses_boxes_outside_the_frame_or_short_outputs():
    """edge_points reads its boxes and writes pts / sig / ends unchecked: mis-sized input raises."""
    gray = np.zeros((20, 30), np.uint8)
    gray[5:10, 5:15] = 200

    def call(x0=5, x1=15, y0=5, y1=10, rows=None, n_bg=1, n_ends=2):
        n = 2 * (y1 - y0) if rows is None else rows
        i64 = lambda v: np.array([v], np.int64)  # noqa: E731
        return _px.edge_points(gray, i64(x0), i64(x1), i64(y0), i64(y1), np.zeros(n_bg, np.float32), 2, 20.0,
                               1, 0.05, 4.0, np.empty((max(n, 0), 2)), np.empty(max(n, 0)), np.empty(n_ends, np.int64))

    call()                                              # a well-formed call works
    for bad in (dict(x0=-1), dict(x1=31), dict(y0=-2), dict(y1=21), dict(x0=16), dict(rows=9), dict(n_bg=0),
                dict(n_ends=1)):
        with pytest.raises(ValueError):
            call(**bad)


@needs_kernel
@pytest.mark.parametrize("name", RECORDINGS)
def test_detect_same_with_and_without_avx2(name):
    """detect() on each recording gives the same blobs with the byte loops' AVX2 versions
    (where the CPU has them) and with the SSE2 / plain ones."""
    if not _px.avx2():
        pytest.skip("no AVX2 on this CPU / build")
    s = _settings(name)
    try:
        for gray in _frames(name):
            a = detect(gray, settings=s)
            _px.avx2(False)
            b = detect(gray, settings=s)
            _px.avx2(True)
            _same_blobs(a, b)
            assert a
    finally:
        _px.avx2(True)
