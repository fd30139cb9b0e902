"""Detection's whole-frame kernels (receiver/vision/_pixels.pyx) against OpenCV, numpy and their
definitions: the envelopes of isolated blobs against `_refine` (cv2.threshold and
cv2.convexHull), the search and labelling against cv2.findContours, the masks and histograms
against numpy, the sampled median and MAD against order statistics, box overlap pair by pair."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from receiver.core.native import require
from receiver.core.records import Blob
from receiver.vision import detect as detect_mod
from receiver.vision.detect import _refine_alone_batch

_px = require("receiver.vision._pixels")


def _scene(rng, h=200, w=300):
    g = rng.normal(10, 2, (h, w))
    rects = []
    for k in range(8):
        x0, y0 = 10 + 35 * k, int(rng.integers(0, h - 60))
        bw, bh = int(rng.integers(4, 30)), int(rng.integers(1, 55))
        yy, xx = np.mgrid[0:bh, 0:bw]
        disc = ((yy - bh / 2) / (bh / 2 + 0.5)) ** 2 + ((xx - bw / 2) / (bw / 2 + 0.5)) ** 2 < 1
        g[y0:y0 + bh, x0:x0 + bw] += disc * rng.uniform(5, 400) * ((yy // 3) % 2 == 0)
        rects.append((x0, y0, bw, bh))
    rects.append((0, 0, 4, 3))  # background only: no hull, or one from noise
    return np.ascontiguousarray(np.clip(np.rint(g), 0, 255).astype(np.uint8)), np.array(rects, np.int64)


def _cyclic(hull: np.ndarray) -> list:
    """A polygon's vertices from its largest (x, y) one: the same list for any start vertex."""
    pts = [tuple(p) for p in np.asarray(hull).reshape(-1, 2).tolist()]
    k = pts.index(max(pts))
    return pts[k:] + pts[:k]


@pytest.mark.parametrize("seed", range(6))
def test_refine_alone_kernel_gives_the_opencv_refinement(seed, simd):
    """The kernel's envelopes against `_refine` (cv2.threshold, the row extremes and
    cv2.convexHull): the same blobs, the same hull vertices in the same orientation, centroid
    and area within float rounding; the records are the dataclass's instances."""
    rng = np.random.default_rng(seed)
    gray, rects = _scene(rng)
    n_start = 0
    for level, frac in ((30.0, 0.5), (15.0, 0.2), (60.0, 0.9)):
        got = _refine_alone_batch(gray, rects, 10.0, level, frac)
        want = [detect_mod._refine(gray, None, tuple(r), 1, 10.0, level, frac, True) for r in rects.tolist()]
        assert [b is None for b in got] == [b is None for b in want]
        assert sum(b is not None for b in got) >= 4
        names = [f.name for f in dataclasses.fields(Blob)]
        for a, b in zip(got, want):
            if a is None:
                continue
            assert _cyclic(a.hull) == _cyclic(b.hull)
            n_start += np.array_equal(a.hull, b.hull)
            assert (a.x0, a.y0, a.x1, a.y1, a.border, a.peak, a.level, a.background) == \
                (b.x0, b.y0, b.x1, b.y1, b.border, b.peak, b.level, b.background)
            assert a.cx == pytest.approx(b.cx, abs=1e-9) and a.cy == pytest.approx(b.cy, abs=1e-9)
            assert a.area_px == pytest.approx(b.area_px, rel=1e-12)
            # the field dict in field order, each value of the dataclass's type
            assert type(a) is Blob and list(a.__dict__) == names and a.hull.dtype == np.float64
            assert [type(v) for v in a.__dict__.values()] == [type(v) for v in b.__dict__.values()]
            assert dataclasses.replace(a, cx=1.0).cx == 1.0 and repr(a) == repr(dataclasses.replace(a))
    assert n_start > 0  # where cv2.convexHull starts at its largest-x vertex, the same vertex list


def test_refine_alone_kernel_hull_of_lines_and_points():
    """Degenerate envelopes: one pixel, a row, a column, a diagonal (collinear rows)."""
    gray = np.zeros((40, 60), np.uint8)
    gray[2, 3] = 200  # a pixel
    gray[10, 5:15] = 200  # a row
    gray[20:30, 2] = 200  # a column
    for i in range(8):  # a diagonal, one pixel per row
        gray[30 + i, 30 + 2 * i] = 200
    rects = np.array([(0, 0, 8, 5), (4, 8, 14, 4), (0, 18, 5, 14), (28, 29, 20, 10)], np.int64)
    got = _refine_alone_batch(gray, rects, 0.0, 50.0, 0.5)
    for a, r in zip(got, rects.tolist()):
        b = detect_mod._refine(gray, None, tuple(r), 1, 0.0, 50.0, 0.5, True)
        assert _cyclic(a.hull) == _cyclic(b.hull)
        assert a.cx == pytest.approx(b.cx, abs=1e-9) and a.area_px == pytest.approx(b.area_px, rel=1e-12)
    assert [len(b.hull) for b in got] == [1, 2, 2, 2]


def test_refine_alone_kernel_declines_what_it_does_not_take():
    """A box past the frame, a negative or a NaN level: the kernel declines (None) and the
    caller refines one by one."""
    gray = np.full((20, 20), 40, np.uint8)
    assert _refine_alone_batch(gray, np.array([(0, 0, 5, 5)], np.int64), -100.0, 20.0, 0.5,
                               min_refine_contrast=-500.0, saturated_gray=30.0) is None
    assert _refine_alone_batch(gray, np.array([(18, 0, 5, 5)], np.int64), 0.0, 20.0, 0.5) is None
    assert _refine_alone_batch(gray, np.array([(0, 0, 5, 5)], np.int64), 0.0, float("nan"), 0.5) is None


def _lit_scene(rng, h, w):
    """A uint8 frame of dark noise with striped blobs of every size, many at the frame's edges
    and corners, some close together (one group) and some overlapping."""
    g = rng.normal(8, 2, (h, w))
    for _ in range(int(rng.integers(0, 14))):
        bh, bw = int(rng.integers(1, 50)), int(rng.integers(1, 50))
        y0 = int(rng.choice([0, h - bh] + [int(rng.integers(-5, h))] * 3))
        x0 = int(rng.choice([0, w - bw] + [int(rng.integers(-5, w))] * 6))
        if y0 + bh <= 0 or x0 + bw <= 0:
            continue
        yy, xx = np.mgrid[max(y0, 0):min(y0 + bh, h), max(x0, 0):min(x0 + bw, w)]
        period = int(rng.integers(2, 9))
        lit = ((yy // max(period // 2, 1)) % 2 == 0) & (rng.random(yy.shape) > 0.05)
        g[yy[lit], xx[lit]] += rng.uniform(30, 200)
    return np.ascontiguousarray(np.clip(np.rint(g), 0, 255).astype(np.uint8))


@pytest.mark.parametrize("seed", range(8))
def test_mosaic_search_equals_the_lit_box_search(seed, monkeypatch):
    """The close and contour search on a mosaic of the lit groups (`_search_mosaic`) gives the
    contours (points and order), boxes and areas of the search over the whole lit box."""
    rng = np.random.default_rng(seed)
    used = 0
    for _ in range(25):
        h, w = int(rng.integers(20, 260)), int(rng.integers(20, 330))
        gray = _lit_scene(rng, h, w)
        gap, join, pool = int(rng.integers(0, 20)), int(rng.integers(0, 6)), int(rng.integers(1, 3))
        calls = []
        real = detect_mod._search_mosaic
        with monkeypatch.context() as m:
            m.setattr(detect_mod, "_search_mosaic", lambda *a: calls.append(real(*a)) or calls[-1])
            got = detect_mod._search(gray, 40.0, gap, join, 1, pool, detect_mod.Scratch())
        with monkeypatch.context() as m:
            m.setattr(detect_mod, "_search_mosaic", lambda *a: None)
            want = detect_mod._search(gray, 40.0, gap, join, 1, pool)
        assert len(got[0]) == len(want[0])
        assert all(np.array_equal(a, b) and a.shape == b.shape for a, b in zip(got[0], want[0]))
        assert np.array_equal(got[1], want[1])
        if got[2] is not None:
            used += 1
            assert got[2].tolist() == [cv2.contourArea(c) for c in want[0]]
    assert used >= 1  # the mosaic was taken, not only the fallback (3000 scenes checked once: no difference)


def _lower_median(v: np.ndarray) -> int:
    """The smallest value with at least half the samples at or below it (an order statistic)."""
    v = np.sort(v.ravel())
    return int(v[max(-(-v.size // 2) - 1, 0)])


def test_sample_stats_are_the_sampled_pixels_histogram_median_and_mad():
    """`_pixels.sample_stats` (what auto_level reads): the histogram of every step-th pixel in
    both directions, its lower median and the lower median of the absolute deviations from it,
    on noisy, flat, clipped and tiny frames, every sampling step; auto_level's level from them."""
    rng = np.random.default_rng(5)
    frames = [np.zeros((1, 1), np.uint8), np.full((7, 9), 255, np.uint8)]
    for _ in range(40):
        h, w = int(rng.integers(1, 90)), int(rng.integers(1, 130))
        g = rng.normal(rng.uniform(0, 60), rng.uniform(0, 12), (h, w))
        g[rng.random((h, w)) < 0.03] = 255
        frames.append(np.ascontiguousarray(np.clip(np.rint(g), 0, 255).astype(np.uint8)))
    for gray in frames:
        for step in (1, 2, 3, 4, 5):
            sample = gray[::step, ::step].astype(np.int64)
            hist = np.empty(256, np.float32)
            med, mad = _px.sample_stats(gray, step, hist)
            assert np.array_equal(hist, np.bincount(sample.ravel(), minlength=256).astype(np.float32))
            assert med == _lower_median(sample) and mad == _lower_median(np.abs(sample - med))
            level, bg = detect_mod.auto_level(gray, sample_step=step)
            assert bg == med and level == min(max(med + 8.0 * (1.4826 * mad), med + 24.0), 254.0)


def _overlap_free(rects: np.ndarray) -> list[bool]:
    """Box i (x, y, w, h) overlaps exactly one box, pair by pair: itself and no other (an empty
    box does not overlap itself)."""
    r = rects.tolist()

    def over(a, b):
        return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]
    return [sum(over(a, b) for b in r) == 1 for a in r]


def test_isolated_boxes_overlap_no_other():
    rng = np.random.default_rng(6)
    for _ in range(300):
        n = int(rng.integers(0, 30))
        rects = np.stack([rng.integers(0, 100, n), rng.integers(0, 100, n),
                          rng.integers(0, 25, n), rng.integers(0, 25, n)], axis=1).astype(np.int64).reshape(-1, 4)
        got = detect_mod._isolated(rects)
        assert got.dtype == bool and got.tolist() == _overlap_free(rects)


def test_search_mask_cells_marks_the_lit_32_column_cells():
    rng = np.random.default_rng(8)
    for _ in range(200):
        h, w = int(rng.integers(1, 40)), int(rng.integers(1, 150))
        gray = ((rng.random((h, w)) < rng.uniform(0, 0.05)) * 200).astype(np.uint8)
        for pool in (1, 2):
            ho = -(-h // pool)
            mask, cells = np.empty((ho, w), np.uint8), np.full((ho, -(-w // 32)), 7, np.uint8)
            box = _px.search_mask_cells(gray, pool, 100, mask, cells)
            assert box == _px.search_mask(gray, pool, 100, np.empty_like(mask))
            padded = np.zeros((ho, cells.shape[1] * 32), bool)
            padded[:, :w] = mask > 0
            assert np.array_equal(cells, padded.reshape(ho, -1, 32).any(axis=2).astype(np.uint8))


def _masks(rng, count):
    """Random 0 / 255 masks: noise, closed noise (blobs with holes and concavities), ellipses
    with dark specks; all sizes from one pixel, components touching every edge."""
    for t in range(count):
        h, w = int(rng.integers(1, 60)), int(rng.integers(1, 140))
        kind = t % 3
        if kind == 0:
            m = (rng.random((h, w)) < rng.uniform(0, 0.7)).astype(np.uint8) * 255
        elif kind == 1:
            m = (rng.random((h, w)) < rng.uniform(0.2, 0.6)).astype(np.uint8) * 255
            m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, np.ones((int(rng.integers(1, 6)), int(rng.integers(1, 4))), np.uint8))
        else:
            m = np.zeros((h, w), np.uint8)
            for _ in range(int(rng.integers(1, 8))):
                axes = (int(rng.integers(0, 20)), int(rng.integers(0, 20)))
                cv2.ellipse(m, (int(rng.integers(0, w)), int(rng.integers(0, h))), axes, float(rng.uniform(0, 180)),
                            0, 360, 255, -1)
            m[rng.random((h, w)) < 0.1] = 0
        yield np.ascontiguousarray(m)


def test_label_runs_equals_find_contours():
    """`_pixels.label_runs` gives every 8-connected component's bounding box, first point and
    hole count as findContours (RETR_CCOMP: outer contours and their holes) does, and for those
    without holes the outer contour's cv2.contourArea (twice it, exactly)."""
    rng = np.random.default_rng(11)
    cap = 4096
    no_crops = np.zeros((0, 7), np.int64)
    checked = holed = 0
    for m in _masks(rng, 1500):
        ox, oy = int(rng.integers(0, 50)), int(rng.integers(0, 50))
        rects, area2 = np.empty((cap, 4), np.int64), np.empty(cap, np.int64)
        holes, keys = np.empty(cap, np.int64), np.empty(cap, np.int64)
        n = _px.label_runs(m, no_crops, 0, ox, oy, rects, area2, holes, keys)
        cont, hier = cv2.findContours(m, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE, offset=(ox, oy))
        outer = [i for i in range(len(cont)) if hier[0][i][3] < 0]
        inner = [hier[0][i][3] for i in range(len(cont)) if hier[0][i][3] >= 0]
        want = sorted(((int(cont[i][0, 0, 1]), int(cont[i][0, 0, 0])), cv2.boundingRect(cont[i]),
                       cv2.contourArea(cont[i]), inner.count(i)) for i in outer)
        assert n == len(want)
        got = sorted(((int(k >> 31), int(k & (2 ** 31 - 1))), tuple(r), a * 0.5, int(nh))
                     for k, r, a, nh in zip(keys[:n], rects[:n].tolist(), area2[:n], holes[:n]))
        for g, wt in zip(got, want):
            assert g[:2] == wt[:2] and (g[3] > 0) == (wt[3] > 0)
            if wt[3] == 0:
                assert g[2] == wt[2]
                checked += 1
            else:
                holed += 1
        assert _px.label_runs(m, no_crops, 0, 0, 0, rects[:max(n - 1, 0)], area2, holes, keys) == (-1 if n else 0)
    assert checked > 10000 and holed > 500


@pytest.mark.parametrize("seed", range(6))
def test_search_without_outlines_equals_the_contour_search(seed):
    """`_search(..., outlines=False)` (run labelling, on the mosaic or the lit box) gives the
    boxes, in the same order, and the contour areas of the contour search; None for the
    contours only when it took the labelling, and then which boxes are isolated (pair by pair,
    of the contour search's boxes)."""
    rng = np.random.default_rng(100 + seed)
    labelled = isolated = 0
    for _ in range(25):
        h, w = int(rng.integers(20, 260)), int(rng.integers(20, 330))
        gray = _lit_scene(rng, h, w)
        gap, join, pool = int(rng.integers(0, 20)), int(rng.integers(0, 6)), int(rng.integers(1, 3))
        got = detect_mod._search(gray, 40.0, gap, join, 1, pool, detect_mod.Scratch(), False)
        want = detect_mod._search(gray, 40.0, gap, join, 1, pool)
        assert np.array_equal(got[1], want[1])
        want_areas = [cv2.contourArea(c) for c in want[0]]
        if want[2] is not None:
            assert want[2].tolist() == want_areas
        if got[0] is None:
            labelled += 1
            assert got[2].tolist() == want_areas
            assert got[3].dtype == bool and got[3].tolist() == _overlap_free(want[1])
            isolated += int(got[3].sum())
    assert labelled >= 15 and isolated > 50


def test_label_says_which_boxes_overlap():
    """`_label`'s isolation flags: an L and a dot inside its box overlap, a far square does not;
    boxes in findContours' order (by descending first point)."""
    m = np.zeros((40, 60), np.uint8)
    m[2:20, 2:4] = m[18:20, 2:20] = 255  # an L
    m[5:7, 12:14] = 255  # a dot in the L's box
    m[30:35, 40:45] = 255  # far away
    rects, areas, alone = detect_mod._label(m, None, 0, 3, 4)
    assert rects.tolist() == [[43, 34, 5, 5], [15, 9, 2, 2], [5, 6, 18, 18]]
    assert alone.tolist() == [True, False, False] and areas.tolist()[:2] == [16.0, 1.0]


def test_label_runs_refuses_short_outputs():
    m = np.full((3, 3), 255, np.uint8)
    with pytest.raises(ValueError):
        _px.label_runs(m, np.zeros((0, 7), np.int64), 0, 0, 0, np.empty((4, 4), np.int64),
                       np.empty(3, np.int64), np.empty(4, np.int64), np.empty(4, np.int64))
    with pytest.raises(ValueError):
        _px.label_runs(m, np.zeros((1, 7), np.int64), 2, 0, 0, np.empty((4, 4), np.int64),
                       np.empty(4, np.int64), np.empty(4, np.int64), np.empty(4, np.int64))


def _blob_tuple(b):
    return (b.cx, b.cy, b.area_px, b.hull.tobytes(), b.hull.shape, b.x0, b.y0, b.x1, b.y1, b.border,
            b.peak, b.level, b.background)


@pytest.mark.parametrize("seed", range(4))
def test_detect_with_run_labelling_equals_the_contour_search(seed, monkeypatch):
    """detect() with the run labelling (`_label`) gives the blobs of the contour search, also
    on frames where boxes overlap (the outlines are then searched after all) and with the
    shape test deciding on the contour areas."""
    rng = np.random.default_rng(200 + seed)
    fell_back = labelled = 0
    real_search = detect_mod._search
    for _ in range(40):
        gray = _lit_scene(rng, int(rng.integers(30, 160)), int(rng.integers(30, 200)))
        kw = dict(stripe_gap_px=int(rng.integers(0, 14)), min_area_px=4.0)
        monkeypatch.setattr(detect_mod, "JOIN_X_PX", int(rng.integers(0, 4)))
        monkeypatch.setattr(detect_mod, "ROW_POOL", int(rng.integers(1, 3)))
        monkeypatch.setattr(detect_mod, "MIN_FILL", float(rng.uniform(0.2, 0.9)))
        calls = []  # (outlines asked for, contours returned)
        with monkeypatch.context() as m:
            m.setattr(detect_mod, "_search",
                      lambda *a: calls.append((a[-1], real_search(*a))) or calls[-1][1])
            got = detect_mod.detect(gray, scratch=detect_mod.Scratch(), **kw)
        with monkeypatch.context() as m:
            m.setattr(detect_mod, "_label", lambda *a: None)
            want = detect_mod.detect(gray, **kw)
        assert [_blob_tuple(b) for b in got] == [_blob_tuple(b) for b in want]
        labelled += any(found[0] is None for _, found in calls)
        fell_back += calls[-1][0] is True
    assert labelled >= 20 and fell_back >= 1


def test_mosaic_declines_a_box_mostly_lit():
    """`_pixels.mosaic` gives up early when more than max_fill of the lit box's cells are lit,
    and packs the same groups when allowed."""
    mask = np.zeros((60, 200), np.uint8)
    mask[0:4, 0:4] = mask[50:54, 150:154] = 255  # two far groups: few cells lit
    mask[20:24, 70:74] = 255
    cells = np.empty((60, 7), np.uint8)
    box = _px.search_mask_cells(mask, 1, 1, np.empty_like(mask), cells)
    crops, out = np.empty((256, 7), np.int64), np.empty(mask.size, np.uint8)
    packed = _px.mosaic(mask, cells, *box, 5, 3, crops, out, 1.0)
    assert packed[0] == 3
    assert _px.mosaic(mask, cells, *box, 5, 3, crops, out, 0.4) == packed  # 3 of 11 x 5 cells lit
    assert _px.mosaic(mask, cells, *box, 5, 3, crops, out, 0.03) == (-1, 0, 0)


@pytest.fixture(params=[True, False], ids=["avx2", "sse2"])
def simd(request):
    """The byte loops' AVX2 versions (where the CPU has them) and the SSE2 / plain ones."""
    if request.param and not _px.avx2():
        pytest.skip("no AVX2 on this CPU / build")
    _px.avx2(request.param)
    yield request.param
    _px.avx2(True)


def test_search_mask_and_histogram_same_with_and_without_avx2(simd):
    """The threshold (mask, lit box, 32-column cells) and the sampled histogram of random frames
    of every width from 1 to 200 (all the vector loops' tails) and a 1280 x 720 frame, by the
    loops in force, against numpy."""
    rng = np.random.default_rng(21)
    sizes = [(int(rng.integers(1, 9)), w) for w in range(1, 201)] + [(720, 1280), (37, 333)]
    for h, w in sizes:
        gray = (rng.integers(0, 256, (h, w)) * (rng.random((h, w)) < rng.uniform(0.001, 0.3))).astype(np.uint8)
        for pool in (1, 2):
            ho = -(-h // pool)
            rows = gray[0::pool].copy()
            if pool == 2:
                rows[:gray[1::2].shape[0]] = np.maximum(rows[:gray[1::2].shape[0]], gray[1::2])
            for on in (0, 1, 100, 255, 256):
                want = np.where(rows >= on, 255, 0).astype(np.uint8)
                mask, cells = np.empty((ho, w), np.uint8), np.full((ho, -(-w // 32)), 7, np.uint8)
                box = _px.search_mask_cells(gray, pool, on, mask, cells)
                assert np.array_equal(mask, want), (h, w, pool, on)
                assert tuple(box) == tuple(cv2.boundingRect(want)), (h, w, pool, on)
                padded = np.zeros((ho, cells.shape[1] * 32), bool)
                padded[:, :w] = want > 0
                assert np.array_equal(cells, padded.reshape(ho, -1, 32).any(axis=2).astype(np.uint8))
        for step in (1, 3, 4):
            got = np.empty(256, np.float32)
            _px.sample_hist(gray, step, got)
            want = np.bincount(gray[::step, ::step].ravel(), minlength=256).astype(np.float32)
            assert np.array_equal(got, want), (h, w, step)
