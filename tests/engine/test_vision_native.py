"""The image side's compiled kernels (receiver/vision/_pixels.pyx) against OpenCV and numpy, on
frames of every bundled recording and on random scenes: each blob's envelope is cv2.convexHull
of its lit pixels with cv2.moments' centroid and cv2.contourArea / cv2.arcLength's area and
rim; masks and histograms are cv2.threshold's and cv2.calcHist's; the row profiles and mask
means OpenCV's sums."""

from __future__ import annotations

from pathlib import Path

import math

import cv2
import numpy as np
import pytest

from receiver.core.native import require
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.io.sources import open_source
from receiver.pipeline import Receiver
from receiver.vision import detect as detect_mod
from receiver.vision.detect import detect
from tests.vision.test_detect import cyclic, detect_with_pool, same_blob

ROOT = Path(__file__).resolve().parents[2]
RECORDINGS = ("indoor-walk", "indoor-static", "indoor-sparse", "vehicle")
_px = require("receiver.vision._pixels")


def _frames(name: str, every: int = 9, limit: int = 5):
    """Every `every`-th frame of a bundled recording, at most `limit` of them."""
    out = []
    for i, f in enumerate(open_source(str(ROOT / "recordings" / name))):
        if i % every == 0:
            out.append(f.gray)
            if len(out) == limit:
                break
    return out


def _settings(name: str):
    """The detection settings the pipeline uses on a bundled recording (its camera and map)."""
    folder = ROOT / "recordings" / name
    rx = Receiver(load_camera(str(folder / "camera.yaml")), load_map(str(folder / "map.json")))
    return rx.settings.detect


def _same_blobs(a, b):
    assert len(a) == len(b)
    for p, q in zip(a, b):
        assert same_blob(p, q), (p, q)


def _opencv_envelopes(gray, blobs) -> int:
    """Each blob whose box overlaps no other blob's against OpenCV: its hull is cv2.convexHull of
    the pixels above its level in its box (the same vertices, any start), its centroid
    cv2.moments' (1e-6 px), its area cv2.contourArea + cv2.arcLength / 2 + pi / 4 (1e-6
    relative), its peak at least the box's maximum. Returns how many were checked."""
    rects = np.array([(b.x0, b.y0, b.x1 - b.x0, b.y1 - b.y0) for b in blobs], np.int64).reshape(-1, 4)
    alone = detect_mod._isolated(rects).tolist() if len(rects) else []
    n = 0
    for b, ok in zip(blobs, alone):
        if not ok:
            continue
        roi = gray[b.y0:b.y1, b.x0:b.x1]
        pts = cv2.findNonZero((roi > b.level).astype(np.uint8))
        hull = cv2.convexHull(pts).reshape(-1, 2).astype(np.float64) + (b.x0, b.y0)
        assert cyclic(hull) == cyclic(b.hull) or cyclic(hull[::-1]) == cyclic(b.hull)
        h32 = hull.astype(np.float32)   # integer pixel centres: exact in float32
        if len(hull) >= 3 and cv2.contourArea(h32) > 1e-6:
            m = cv2.moments(h32)
            assert abs(b.cx - m["m10"] / m["m00"]) <= 1e-6 and abs(b.cy - m["m01"] / m["m00"]) <= 1e-6
            rim = cv2.contourArea(h32) + 0.5 * cv2.arcLength(h32, True) + math.pi / 4
            assert b.area_px == pytest.approx(rim, rel=1e-6)  # arcLength sums in float32
        assert b.peak >= float(roi.max())
        n += 1
    return n


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


@pytest.mark.parametrize("name", RECORDINGS)
def test_detect_envelopes_are_opencv_hulls_on_recordings(name):
    """`detect`'s envelopes on each recording (the pipeline's settings; row-pooled and full
    resolution search) against OpenCV (`_opencv_envelopes`); both searches find the same blobs."""
    s = _settings(name)
    n = 0
    for gray in _frames(name):
        a, b = (detect_with_pool(gray, pool, settings=s) for pool in (detect_mod.ROW_POOL, 1))
        assert [(p.x0, p.y0, p.x1, p.y1) for p in a] == [(q.x0, q.y0, q.x1, q.y1) for q in b]
        n += _opencv_envelopes(gray, a)
    assert n > 0


def test_detect_envelopes_are_opencv_hulls_on_random_scenes():
    rng = np.random.default_rng(11)
    n = 0
    for _ in range(40):
        gray = _random_scene(rng, n=int(rng.integers(0, 9)))
        pool = int(rng.integers(1, 3))
        kw = {"stripe_gap_px": int(rng.integers(0, 20)),
              "fine_noise": bool(rng.integers(0, 2)), "min_contrast": float(rng.uniform(3, 30))}
        n += _opencv_envelopes(gray, detect_with_pool(gray, pool, **kw))
    assert n > 20


def _row_max(gray: np.ndarray, pool: int) -> np.ndarray:
    """The maximum of each `pool` rows (the last group may be shorter)."""
    return np.stack([gray[i:i + pool].max(axis=0) for i in range(0, gray.shape[0], pool)])


def test_search_mask_equals_threshold_of_the_row_maxima():
    """`_pixels.search_mask` = cv2.threshold of the row maxima (pool 1, 2; odd heights, narrow and
    odd widths, levels below 0 and at 255) and cv2.boundingRect of that mask."""
    rng = np.random.default_rng(5)
    for h, w in ((1, 1), (3, 5), (7, 16), (9, 17), (30, 33), (31, 64), (120, 200)):
        gray = np.ascontiguousarray((rng.integers(0, 256, (h, w)) * (rng.random((h, w)) < 0.1)).astype(np.uint8))
        for pool in (1, 2):
            search = _row_max(gray, pool)
            for level in (-3.0, 0.0, 0.5, 24.0, 100.7, 254.2, 255.0, 300.0):
                _, want = cv2.threshold(search, level, 255, cv2.THRESH_BINARY)
                mask = np.empty_like(want)
                on = min(max(int(np.floor(level)) + 1, 0), 256)
                box = _px.search_mask(gray, pool, on, mask)
                assert np.array_equal(mask, want), (h, w, pool, level)
                assert tuple(box) == tuple(cv2.boundingRect(want))


def test_sample_histogram_equals_calchist():
    rng = np.random.default_rng(9)
    for h, w in ((1, 1), (5, 7), (720, 1280), (33, 65)):
        gray = np.ascontiguousarray(rng.integers(0, 256, (h, w)).astype(np.uint8))
        for step in (1, 3, 4):
            want = cv2.calcHist([np.ascontiguousarray(gray[::step, ::step])], [0], None, [256], [0, 256]).ravel()
            got = np.empty(256, np.float32)
            _px.sample_hist(gray, step, got)
            assert got.dtype == want.dtype and np.array_equal(got, want)


@pytest.mark.parametrize("name", RECORDINGS)
def test_row_profile_and_mask_mean_are_opencv_sums(name):
    """`row_profile` and `mean_in_mask` (the compiled masked sums) against OpenCV's sums of the
    envelope's pixels (cv2.reduce per row, cv2.sumElems / cv2.countNonZero), on each recording's
    blobs and on boxes moved past the frame's edges (a pair's predicted emitter)."""
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
                mask = profile.envelope_mask(blob)
                roi = gray[blob.y0:blob.y1, blob.x0:blob.x1]
                assert p.dtype == wt.dtype == np.float32 and y0 == blob.y0
                if roi.shape == mask.shape and roi.size:
                    weights = cv2.reduce(mask, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32F).ravel()
                    sums = cv2.reduce(np.multiply(roi, mask), 1, cv2.REDUCE_SUM, dtype=cv2.CV_32F).ravel()
                    assert np.array_equal(wt, weights) and np.array_equal(p, sums / np.maximum(weights, 1.0))
                    k = cv2.countNonZero(mask)
                    want = cv2.sumElems(np.multiply(roi, mask))[0] / k if k else 0.0
                    assert profile.mean_in_mask(gray, blob) == want
                else:
                    assert not p.any() and not wt.any()
                assert type(profile.mean_in_mask(gray, blob)) is float
                n += 1
    assert n > 0


def test_box_kernels_refuse_boxes_outside_the_frame():
    """The box scans never read outside the frame: pooled_boxes says False (its caller takes the
    numpy path), refine_alone -1 (tests/engine/test_detect_kernels.py)."""
    gray = np.zeros((20, 30), np.uint8)
    for box in ((-1, 0, 5, 5), (26, 0, 5, 5), (0, 16, 5, 5), (0, 0, 31, 1)):
        rects = np.array([box], np.int64)
        assert _px.pooled_boxes(gray, rects, 1, 2, 0, np.empty((1, 4), np.int64)) is False


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
