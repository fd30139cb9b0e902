"""Photos: the search image of a big frame, and the run summary's percentile
(numpy's numbers without numpy.ma).

Speed is not tested here (benchmarks, never timed unit tests); what the fast path must keep is:
search pixel (i, j) is the rounded mean of full-resolution rows [i f, (i + 1) f) and columns
[j f, (j + 1) f) (what `_refine` maps it back to), whatever the frame's size mod f.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from receiver.vision.detect import detect, detect_scale, search_image
from tests.vision.test_detect import same_blob


def _block_means(gray: np.ndarray, f: int) -> np.ndarray:
    """Reference: the rounded mean of each whole f x f block, in float64."""
    h, w = gray.shape[0] // f, gray.shape[1] // f
    blocks = gray[:h * f, :w * f].astype(np.float64).reshape(h, f, w, f)
    return blocks.mean(axis=(1, 3))


@pytest.mark.parametrize("shape,f", [((4352, 7712), 6), ((61, 83), 4), ((40, 40), 2), ((37, 50), 3),
                                     ((2160, 3840), 4), ((131, 77), 8)])
def test_search_image_is_the_mean_of_whole_blocks(shape, f):
    g = np.random.default_rng(f).integers(0, 256, shape, dtype=np.uint8)
    small = search_image(g, f)
    assert small.shape == (shape[0] // f, shape[1] // f) and small.dtype == np.uint8
    # INTER_AREA's fixed-point sum rounds to the nearest gray level (half-way cases either way);
    # a power of two is made by halvings, each rounded
    tol = 0.5 * math.log2(f) if f & (f - 1) == 0 else 0.5
    assert np.abs(small - _block_means(g, f)).max() <= tol + 1e-9


def test_search_factor_is_one_opencv_serves_fast():
    assert [detect_scale((h, w)) for h, w in ((720, 1280), (1080, 1920), (2160, 3840), (4352, 7712))] == [1, 2, 4, 6]


def test_search_image_keeps_the_blocks_in_place():
    """One lit full-resolution pixel at (y, x) lights search pixel (y // f, x // f) only, also
    at the far end of a frame whose size is not a multiple of f (the general area resampler
    at 7712 / 1285 = 6.0016 drifts a block by a pixel there)."""
    f, h, w = 6, 4352, 7712
    for y, x in ((0, 0), (4345, 7703), (2175, 3857), (4349, 7709)):
        g = np.zeros((h, w), np.uint8)
        g[y, x] = 252
        small = search_image(g, f)
        lit = np.argwhere(small > 0)
        if y < h // f * f and x < w // f * f:
            assert lit.tolist() == [[y // f, x // f]], (y, x, lit.tolist())
            assert small[y // f, x // f] == 7  # 252 / 36
        else:
            assert lit.size == 0  # in the left-out remainder (less than one block)


def test_search_image_at_scale_one_is_the_frame_itself():
    g = np.zeros((10, 12), np.uint8)
    assert search_image(g, 1) is g


def _paint_led(img, cx, cy, r, period_rows=24):
    """A saturated striped disc of radius r (px) with a dim glow out to 2r, as a phone shoots a
    bright LED: its envelope is the disc's lit rows plus the glow above the (near-background)
    level a clipped blob is refined at, so it depends on where the search mask lies."""
    y0, x0 = int(cy - 2 * r) - 2, int(cx - 2 * r) - 2
    ys, xs = np.mgrid[y0:int(cy + 2 * r) + 3, x0:int(cx + 2 * r) + 3]
    d = np.hypot(xs - cx, ys - cy)
    glow = np.clip(40.0 * (2.0 - d / r), 0, None)
    on = (d <= r) & ((ys % period_rows) < period_rows // 2)
    roi = img[y0:y0 + ys.shape[0], x0:x0 + xs.shape[1]]
    roi[:] = np.where(on, 255, np.maximum(roi, glow)).astype(np.uint8)


def test_a_big_frame_is_searched_the_same_everywhere():
    """The same light, moved by whole search pixels (6 px at f = 6) from the top-left to the far
    corner of a 7712 x 4352 frame (not a multiple of 6 wide or high), gives the same envelope
    moved by exactly as much: the search blocks do not drift across the frame."""
    f, dx, dy = 6, 6 * 1100, 6 * 600
    g = np.full((4352, 7712), 3, np.uint8)
    _paint_led(g, 600.3, 500.6, 45.0)
    _paint_led(g, 600.3 + dx, 500.6 + dy, 45.0)
    assert detect_scale(g.shape) == f
    a, b = detect(g, stripe_gap_px=14)
    assert b.cx - a.cx == pytest.approx(dx, abs=1e-6) and b.cy - a.cy == pytest.approx(dy, abs=1e-6)
    assert b.area_px == pytest.approx(a.area_px, abs=1e-6)
    assert np.allclose(b.hull - a.hull, (dx, dy))
    assert (b.x0 - a.x0, b.y0 - a.y0, b.x1 - a.x1, b.y1 - a.y1) == (dx, dy, dx, dy)


@pytest.mark.parametrize("n", [1, 2, 3, 7, 100, 1001])
def test_percentile_is_numpys(n):
    from receiver.core.budget import percentile
    rng = np.random.default_rng(n)
    for values in (rng.exponential(5.0, n), rng.integers(0, 4, n).astype(float),
                   np.round(rng.normal(3, 1, n), 2)):
        for q in (0, 1, 10, 25, 33.3, 50, 66.7, 90, 99, 99.9, 100):
            assert percentile(list(values), q) == float(np.percentile(values, q)), (n, q)
    assert math.isnan(percentile([], 50)) and math.isnan(percentile([1.0, float("nan")], 50))


@pytest.mark.parametrize("shape", [(2160, 3840), (1080, 1920), (4352, 7712)])
def test_a_downsampled_search_refines_in_one_batch_as_one_by_one(shape, monkeypatch):
    """Isolated components of a downsampled search are refined together (their boxes mapped back
    to full resolution, masked as `_refine` masks them) with the same blobs (`same_blob`) as
    `_refine` one by one: clipped lights with a glow (refined near the background, where the
    mask decides), lights in the frame's corners, and two lights close enough to share a box."""
    import receiver.vision.detect as det
    rng = np.random.default_rng(shape[0])
    g = rng.integers(0, 6, shape, dtype=np.uint8)
    h, w = shape
    r = w / 160.0
    for cx, cy in ((0.3 * w, 0.3 * h), (0.7 * w, 0.4 * h), (2.5 * r, 2.5 * r), (w - 2.5 * r, h - 2.5 * r)):
        _paint_led(g, cx, cy, r)
    # two lights side by side (their boxes overlap): refined one by one either way
    _paint_led(g, 0.5 * w, 0.75 * h, r)
    _paint_led(g, 0.5 * w + 4.2 * r, 0.75 * h + 2.0 * r, r)
    # a dimmer, unclipped light (refined at half maximum)
    yy, xx = np.mgrid[:h, :w]
    g[(xx - 0.2 * w) ** 2 + (yy - 0.8 * h) ** 2 <= r * r] = 150
    assert det.detect_scale(g.shape) > 1
    batched = detect(g, stripe_gap_px=14)
    calls = []
    real = det._refine_alone_batch
    monkeypatch.setattr(det, "_refine_alone_batch",
                        lambda gray, rects, *a, **k: calls.append(len(rects)) or (None if len(rects) else real(gray, rects, *a, **k)))
    one_by_one = detect(g, stripe_gap_px=14)
    assert calls and calls[0] >= 4  # the isolated ones did go through the batch
    assert len(batched) == len(one_by_one) >= 6
    for a, b in zip(batched, one_by_one):
        assert same_blob(a, b)
