"""Detection's whole-frame kernels (receiver/vision/_pixels.pyx) against what they replace:
OpenCV's convex hull (vertices and their order), the numpy hull statistics, and the Blob
records of the numpy path, bit for bit (the pure path runs with detect's `_k` set to None)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from receiver.core.native import load
from receiver.core.records import Blob
from receiver.vision import detect as detect_mod
from receiver.vision.detect import _hull_stats_points, _new_blob, _refine_alone_batch

_px = load("receiver.vision._pixels")
needs_kernel = pytest.mark.skipif(_px is None, reason="kernels not built or OCCLOC_PURE=1 (test_native checks the build)")


def _point_sets(rng, count):
    """Random integer point sets: clouds with many equal points, collinear runs, tiny grids and
    the row-extreme sets detection builds (left ends top to bottom, then right ends)."""
    for t in range(count):
        n = int(rng.integers(1, 12 if t % 5 == 0 else 160))
        kind = t % 4
        if kind == 0:
            pts = rng.integers(0, int(rng.integers(1, 60)), size=(n, 2))
        elif kind == 1:
            h = max(1, n // 2)
            rows = np.sort(rng.choice(np.arange(h + 5), size=h, replace=False))
            half = rng.uniform(1, 30) * np.sqrt(np.clip(1 - ((rows - h / 2) / (h / 2 + 1)) ** 2, 0, 1))
            left = np.maximum(np.rint(30 - half + rng.integers(-1, 2, h)), 0).astype(int)
            right = np.maximum(left, np.rint(30 + half + rng.integers(-1, 2, h)).astype(int))
            pts = np.concatenate([np.stack([left, rows], 1), np.stack([right, rows], 1)])
        elif kind == 2:
            d = rng.integers(-3, 4, size=2)
            pts = np.clip(rng.integers(20, 40, size=2) + np.outer(rng.integers(0, 8, n), d), 0, None)
        else:
            pts = rng.integers(0, 3, size=(n, 2)) + int(rng.integers(0, 100))
        yield np.ascontiguousarray(pts, np.int32)


@needs_kernel
def test_convex_hull_equals_opencv_vertices_and_order():
    rng = np.random.default_rng(3)
    n_rot = 0
    for pts in _point_sets(rng, 6000):
        want = cv2.convexHull(pts.reshape(-1, 1, 2)).reshape(-1, 2).tolist()
        got = [list(p) for p in _px.convex_hull(pts)]
        assert got == want, pts.tolist()
        n_rot += len(want) >= 3 and want[0] != min(want)
    assert n_rot > 100  # the cyclic shift was exercised


@needs_kernel
def test_convex_hull_refuses_points_it_cannot_key():
    with pytest.raises(ValueError):
        _px.convex_hull(np.array([[-1, 0], [2, 3]], np.int32))
    assert _px.convex_hull(np.zeros((0, 2), np.int32)) == []


@needs_kernel
def test_hull_stats_equal_numpy_reduceat_sums():
    rng = np.random.default_rng(4)
    hulls = [cv2.convexHull(p.reshape(-1, 1, 2)) for p in _point_sets(rng, 3000)]
    hulls += [np.array([[[5, 5]]], np.int32), np.array([[[1, 1]], [[4, 1]]], np.int32)]  # flat ones
    cx, cy, area, poly, starts = _hull_stats_points(hulls)
    out = np.empty((len(hulls), 3))
    _px.hull_stats(np.ascontiguousarray(poly), np.append(starts, len(poly)), out)
    assert np.array_equal(out[:, 0], cx) and np.array_equal(out[:, 1], cy) and np.array_equal(out[:, 2], area)


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


def _fields(b):
    return None if b is None else (b.cx, b.cy, b.area_px, b.x0, b.y0, b.x1, b.y1, b.border, b.peak, b.level,
                                   b.background, b.hull.dtype, b.hull.shape, b.hull.tobytes())


@needs_kernel
@pytest.mark.parametrize("seed", range(6))
def test_refine_alone_kernel_equals_numpy_batch(seed, monkeypatch, simd):
    rng = np.random.default_rng(seed)
    gray, rects = _scene(rng)
    for level, frac in ((30.0, 0.5), (15.0, 0.2), (60.0, 0.9)):
        got = _refine_alone_batch(gray, rects, 10.0, level, frac)
        with monkeypatch.context() as m:
            m.setattr(detect_mod, "_k", None)
            want = _refine_alone_batch(gray, rects, 10.0, level, frac)
        assert [_fields(b) for b in got] == [_fields(b) for b in want]
        assert sum(b is not None for b in got) >= 4
        # the kernel's records are the dataclass's instances (the field dict in field order,
        # each value of the numpy path's type: Python float / int / bool, a float64 hull)
        names = [f.name for f in dataclasses.fields(Blob)]
        for a, b in zip(got, want):
            if a is not None:
                assert type(a) is Blob and list(a.__dict__) == names and a == a
                assert [type(v) for v in a.__dict__.values()] == [type(v) for v in b.__dict__.values()]
                assert dataclasses.replace(a, cx=1.0).cx == 1.0 and repr(a) == repr(dataclasses.replace(a))


@needs_kernel
def test_refine_alone_kernel_declines_what_numpy_decides():
    """A box past the frame or a negative level: the kernel returns -1 and the numpy path
    answers (None for the negative level: the caller refines one by one)."""
    gray = np.full((20, 20), 40, np.uint8)
    assert _refine_alone_batch(gray, np.array([(0, 0, 5, 5)], np.int64), -100.0, 20.0, 0.5,
                               min_refine_contrast=-500.0, saturated_gray=30.0) is None
    args = [np.empty(1), np.empty(1), np.empty(1, np.int64), np.empty((1, 3)), np.empty((1, 4), np.int64),
            np.empty((40, 2)), np.empty(2, np.int64)]
    assert _px.refine_alone(gray, np.array([(18, 0, 5, 5)], np.int64), 0.0, 20.0, 0.5, 250.0, 0.03, 6.0, *args) == -1
    assert _px.refine_alone(gray, np.array([(0, 0, 5, 5)], np.int64), 0.0, float("nan"), 0.5, 250.0, 0.03, 6.0,
                            *args) == -1


def test_new_blob_is_the_dataclass_instance():
    assert not hasattr(Blob, "__post_init__") and not hasattr(Blob, "__slots__")
    values = (1.5, 2.5, 30.0, np.zeros((3, 2)), 1, 2, 3, 4, False, 200.0, 100.0, 5.0)
    a, b = _new_blob(*values), Blob(*values)
    assert type(a) is Blob and list(a.__dict__) == list(b.__dict__) == [f.name for f in dataclasses.fields(Blob)]
    assert all(x is y for x, y in zip(a.__dict__.values(), b.__dict__.values()))
    assert dataclasses.replace(a, cx=9.0).cx == 9.0 and repr(a) == repr(b)
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.cx = 0.0


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


@needs_kernel
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


@needs_kernel
def test_auto_level_kernel_equals_numpy(monkeypatch):
    """`_pixels.sample_stats` (histogram, median and MAD in one pass) gives auto_level's
    numbers, on noisy, flat, clipped and tiny frames, every sampling step."""
    rng = np.random.default_rng(5)
    frames = [np.zeros((1, 1), np.uint8), np.full((7, 9), 255, np.uint8)]
    for _ in range(40):
        h, w = int(rng.integers(1, 90)), int(rng.integers(1, 130))
        g = rng.normal(rng.uniform(0, 60), rng.uniform(0, 12), (h, w))
        g[rng.random((h, w)) < 0.03] = 255
        frames.append(np.ascontiguousarray(np.clip(np.rint(g), 0, 255).astype(np.uint8)))
    for gray in frames:
        for step in (1, 2, 3, 4, 5):
            for fine in (False, True):
                got = detect_mod.auto_level(gray, sample_step=step, fine_noise=fine)
                with monkeypatch.context() as m:
                    m.setattr(detect_mod, "_k", None)
                    want = detect_mod.auto_level(gray, sample_step=step, fine_noise=fine)
                assert got == want


@needs_kernel
def test_isolated_kernel_equals_numpy(monkeypatch):
    rng = np.random.default_rng(6)
    for _ in range(300):
        n = int(rng.integers(0, 30))
        rects = np.stack([rng.integers(0, 100, n), rng.integers(0, 100, n),
                          rng.integers(0, 25, n), rng.integers(0, 25, n)], axis=1).astype(np.int64).reshape(-1, 4)
        got = detect_mod._isolated(rects)
        with monkeypatch.context() as m:
            m.setattr(detect_mod, "_k", None)
            want = detect_mod._isolated(rects)
        assert got.dtype == want.dtype == bool and np.array_equal(got, want)


@needs_kernel
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


@needs_kernel
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


@needs_kernel
@pytest.mark.parametrize("seed", range(6))
def test_search_without_outlines_equals_the_contour_search(seed, monkeypatch):
    """`_search(..., outlines=False)` (run labelling, on the mosaic or the lit box) gives the
    boxes, in the same order, and the contour areas of the contour search; None for the
    contours only when it took the labelling, and then which boxes are isolated (the numpy
    `_isolated` of the contour search's boxes)."""
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
            with monkeypatch.context() as m:
                m.setattr(detect_mod, "_k", None)
                want_alone = detect_mod._isolated(want[1])
            assert got[3].dtype == bool and np.array_equal(got[3], want_alone)
            isolated += int(got[3].sum())
    assert labelled >= 15 and isolated > 50


@needs_kernel
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


@needs_kernel
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


@needs_kernel
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
        kw = dict(stripe_gap_px=int(rng.integers(0, 14)), join_x_px=int(rng.integers(0, 4)),
                  row_pool=int(rng.integers(1, 3)), min_fill=float(rng.uniform(0.2, 0.9)), min_area_px=4.0)
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


@needs_kernel
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


@needs_kernel
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



@needs_kernel
def test_hull_perimeter_table_gives_hypots_bits():
    """The hull perimeter's hypot table (integer differences under 64) and its fall-back to
    hypot (fractional, negative, larger differences) give libm hypot's own results."""
    assert _px.hypot_table_equals_hypot()
