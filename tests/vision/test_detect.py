"""LED blob detection against synthetic images with known truth, and the real phone photos."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from receiver.cli.benchscene import bench_scene, render_bench_frame
from receiver.vision import detect as detect_mod
from receiver.vision.detect import auto_level, detect, detect_scale
from receiver.vision.profile import envelope_mask, row_profile, stripe_depth



def detect_with_pool(gray, pool, **kw):
    """detect() with its row pooling (detect.ROW_POOL) set to `pool` for this call."""
    old = detect_mod.ROW_POOL
    detect_mod.ROW_POOL = pool
    try:
        return detect(gray, **kw)
    finally:
        detect_mod.ROW_POOL = old


def draw_led(img, cx, cy, r, *, on=230.0, period_rows=0, phase_rows=0, square=False):
    """Paint a disc (or square of side 2r) centred at (cx, cy) px; with `period_rows` its rows
    are ON for the first half of each period (rolling-shutter stripes). Pixel (u, v) is inside
    when its centre is. Returns the truth (area_px = inside pixel count, centroid of them)."""
    h, w = img.shape
    ys, xs = np.mgrid[0:h, 0:w]
    if square:
        inside = (np.abs(xs - cx) <= r) & (np.abs(ys - cy) <= r)
    else:
        inside = (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r
    lit = inside.copy()
    if period_rows:
        lit &= ((ys + phase_rows) % period_rows) < period_rows / 2
    img[lit] = on
    return {"area": float(inside.sum()), "cx": float(xs[inside].mean()), "cy": float(ys[inside].mean())}


def blank(w=640, h=480, bg=10.0, noise=0.0, seed=0):
    img = np.full((h, w), bg, np.float64)
    if noise:
        img += np.random.default_rng(seed).normal(0, noise, img.shape)
    return img


def u8(img):
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("square", [False, True])
def test_envelope_area_and_centroid_of_a_plain_led(square):
    img = blank()
    truth = draw_led(img, 200.3, 150.6, 30.0, square=square)
    (b,) = detect(u8(img))
    assert b.area_px == pytest.approx(truth["area"], rel=0.02)
    assert b.cx == pytest.approx(truth["cx"], abs=0.15)
    assert b.cy == pytest.approx(truth["cy"], abs=0.15)
    assert not b.border


def test_stripes_merge_into_one_envelope_not_lit_pixels():
    img = blank()
    # Rows 211..269 (59 = 7 * 8 + 3), phase chosen so that the disc's top and bottom rows are
    # lit: the envelope is then the whole disc.
    truth = draw_led(img, 320.0, 240.0, 29.5, period_rows=8, phase_rows=(8 - 211 % 8) % 8)
    blobs = detect(u8(img), stripe_gap_px=5)
    assert len(blobs) == 1
    b = blobs[0]
    lit_pixels = float((u8(img) > 100).sum())
    assert lit_pixels < 0.6 * truth["area"]
    assert b.area_px == pytest.approx(truth["area"], rel=0.03)
    assert (b.cx, b.cy) == pytest.approx((truth["cx"], truth["cy"]), abs=0.3)


def test_without_bridging_the_stripes_fall_apart():
    img = blank()
    draw_led(img, 320.0, 240.0, 31.0, period_rows=16)
    # Unbridged, each stripe is a thin bar: split up or rejected as a line, never one LED.
    assert len(detect(u8(img), stripe_gap_px=0)) != 1
    assert len(detect(u8(img), stripe_gap_px=9)) == 1


def test_ambient_light_and_noise():
    img = blank(bg=110.0, noise=6.0, seed=4)
    truths = [draw_led(img, x, y, 18.0, on=250.0, period_rows=6)
              for x, y in ((100.5, 100.2), (300.0, 120.7), (500.2, 380.9), (160.0, 400.0))]
    blobs = detect(u8(img), stripe_gap_px=5)
    assert len(blobs) == 4
    for t in truths:
        b = min(blobs, key=lambda b: math.hypot(b.cx - t["cx"], b.cy - t["cy"]))
        # A cap falling in a 3-row dark stripe shortens the envelope: centroid within 1.5 rows.
        assert abs(b.cx - t["cx"]) < 0.5 and abs(b.cy - t["cy"]) < 1.6
    level, bg = auto_level(u8(img))
    assert 105 <= bg <= 115 and level > bg + 24


def test_rejects_specks_lines_and_flat_saturated_regions():
    img = blank()
    img[50:52, 50:52] = 255  # speck
    img[300:303, 100:300] = 255  # a lit edge / line, aspect > 4
    for i in range(120):  # a thin diagonal bar: square box, nearly empty
        img[20 + i, 200 + i:203 + i] = 255
    draw_led(img, 450.0, 150.0, 30.0, on=255.0)  # flat: no stripes
    striped = draw_led(img, 450.0, 350.0, 30.0, on=255.0, period_rows=8)
    assert len(detect(u8(img), stripe_gap_px=5)) == 2  # flat disc kept without stripe check
    blobs = detect(u8(img), stripe_gap_px=5, stripe_check_rows=1)
    assert len(blobs) == 1
    assert blobs[0].cy == pytest.approx(striped["cy"], abs=1.0)


def test_window_sized_region_is_not_a_light():
    img = blank()
    img[100:400, 100:500] = 250
    assert detect(u8(img)) == []


def test_border_cut_led_is_flagged():
    img = blank()
    draw_led(img, 3.0, 200.0, 20.0)
    draw_led(img, 300.0, 200.0, 20.0)
    blobs = sorted(detect(u8(img)), key=lambda b: b.cx)
    assert [b.border for b in blobs] == [True, False]


def test_neighbours_stay_apart():
    img = blank()
    draw_led(img, 200.0, 200.0, 15.0, period_rows=6)
    draw_led(img, 236.0, 200.0, 15.0, period_rows=6)  # 6 px gap side by side
    draw_led(img, 400.0, 200.0, 15.0, period_rows=6)
    draw_led(img, 400.0, 245.0, 15.0, period_rows=6)  # 15 px gap below
    assert len(detect(u8(img), stripe_gap_px=4)) == 4


def test_row_profile_matches_brute_force():
    img = blank(noise=3.0)
    draw_led(img, 100.4, 80.2, 12.0, period_rows=6)
    g = u8(img)
    (b,) = detect(g, stripe_gap_px=4)
    prof, wts, y0 = row_profile(g, b)
    mask = envelope_mask(b)
    assert prof.dtype == np.float32 and wts.dtype == np.float32
    assert y0 == b.y0 and len(prof) == b.y1 - b.y0
    roi = g[b.y0:b.y1, b.x0:b.x1].astype(np.float64)
    for r in range(len(prof)):
        n = mask[r].sum()
        assert wts[r] == n
        if n:
            assert prof[r] == pytest.approx(roi[r][mask[r] > 0].mean(), abs=1e-3)
    assert stripe_depth(prof, wts, background=10.0) > 0.9


def test_big_frames_are_searched_downsampled_and_refined_in_full_resolution():
    img = blank(4000, 3000, noise=2.0)
    truths = [draw_led(img, x, y, 40.0, period_rows=20) for x, y in ((800.3, 700.6), (3000.0, 2200.4))]
    g = u8(img)
    assert detect_scale(g.shape) > 1
    blobs = detect(g, stripe_gap_px=12)
    assert len(blobs) == 2
    for b, t in zip(blobs, truths):
        assert math.hypot(b.cx - t["cx"], b.cy - t["cy"]) < 0.5
        assert b.area_px == pytest.approx(t["area"], rel=0.05)


# -- real photos (../shared/real/luxapose) -----------------------------------------------

PHOTO_LEDS = {  # approximate LED centres (px, sensor orientation) read off the photos
    "x_0_y_1.27.jpg": [(3056, 1341), (4745, 1346), (3894, 2164), (3047, 2969), (4736, 2984)],
    "small_blob.jpg": [(3986, 592), (1466, 2386), (3784, 2559), (6151, 2692)],
    "chandelier0_2013-05-11--02-08-21-25.jpg": [(4039, 1214), (3864, 1695), (3411, 1744), (4344, 1838)],
}


def load_photo(luxapose, name):
    g = cv2.imread(str(luxapose / name), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    if g.shape[0] > g.shape[1]:  # the chandelier photo is stored portrait: back to sensor rows
        g = cv2.rotate(g, cv2.ROTATE_90_COUNTERCLOCKWISE)
    return g


@pytest.mark.parametrize("name", sorted(PHOTO_LEDS))
def test_real_photos_find_every_led_and_nothing_else(luxapose, name):
    g = load_photo(luxapose, name)
    # 2 kHz stripes of the Lumia 1020 (21.03 us rows): 12-row dark half-periods.
    blobs = detect(g, stripe_gap_px=14, stripe_check_rows=24, min_rel_area=0.25)
    want = PHOTO_LEDS[name]
    assert len(blobs) == len(want)
    for x, y in want:
        b = min(blobs, key=lambda b: math.hypot(b.cx - x, b.cy - y))
        assert math.hypot(b.cx - x, b.cy - y) < 15
        assert b.area_px > 1500  # radius > 22 px: the whole striped disc, not one stripe


def test_bench_detect_1280x720_16_leds(benchmark):
    leds = bench_scene()
    g = render_bench_frame(leds, 0, rng=np.random.default_rng(0))
    blobs = benchmark(detect, g, stripe_gap_px=12, stripe_check_rows=20)
    assert len(blobs) == 16


def test_bench_detect_33_megapixel_photo(benchmark, luxapose):
    g = load_photo(luxapose, "x_0_y_1.27.jpg")
    blobs = benchmark(detect, g, stripe_gap_px=14, stripe_check_rows=24)
    assert len(blobs) == 5


def _coarse_components(gray, stripe_gap_px=8, join_x_px=2, pool=1):
    """Contours and boxes of the coarse search, as `detect` makes them (full resolution,
    rows pooled by `pool`)."""
    from receiver.vision.detect import _components
    level, bg = auto_level(gray)
    contours, rects = _components(gray, level, stripe_gap_px, join_x_px, 1, pool)
    return contours, rects, level, bg


def cyclic(hull) -> list:
    """A polygon's vertices from its largest (x, y) one: the same list for any start vertex."""
    pts = [tuple(p) for p in np.asarray(hull).reshape(-1, 2).tolist()]
    k = pts.index(max(pts))
    return pts[k:] + pts[:k]


def same_blob(a, b) -> bool:
    """The same envelope: the same box, border, peak, level and background, the same hull
    vertices in the same orientation (any start vertex), centroid within 1e-9 px and area within
    1e-12 of itself (sums in another order)."""
    return ((a.x0, a.y0, a.x1, a.y1, a.border, a.peak, a.level, a.background)
            == (b.x0, b.y0, b.x1, b.y1, b.border, b.peak, b.level, b.background)
            and a.hull.dtype == b.hull.dtype and cyclic(a.hull) == cyclic(b.hull)
            and abs(a.cx - b.cx) <= 1e-9 and abs(a.cy - b.cy) <= 1e-9
            and abs(a.area_px - b.area_px) <= 1e-12 * abs(b.area_px))


@pytest.mark.parametrize("pool", [1, 2])
def test_batched_refinement_equals_the_per_blob_one(pool):
    """The batched refinement of isolated blobs gives `_refine`'s envelopes (`same_blob`): striped
    discs of several sizes, a clipped one, one on the border, a speck and a square; also on
    the boxes of a row-pooled search, which both tighten to the same rows."""
    from receiver.vision.detect import _refine, _refine_alone_batch
    img = blank(noise=2.0, seed=3)
    draw_led(img, 100.3, 120.7, 30, period_rows=7)
    draw_led(img, 300.0, 100.0, 12, period_rows=5, phase_rows=2)
    draw_led(img, 500.5, 300.2, 45, on=255.0, period_rows=9)  # saturated
    draw_led(img, 3.0, 400.0, 20, period_rows=6)  # cut by the left border
    draw_led(img, 200.0, 400.0, 25, square=True)
    img[50:52, 600:602] = 200  # a speck
    gray = u8(img)
    contours, rects, level, bg = _coarse_components(gray, pool=pool)
    assert len(rects) >= 6
    batch = _refine_alone_batch(gray, rects, bg, level, 0.5)
    for c, r, got in zip(contours, rects.tolist(), batch):
        want = _refine(gray, c, tuple(r), 1, bg, level, 0.5, True)
        assert (want is None) == (got is None)
        assert want is None or same_blob(want, got)


def test_row_pooled_search_finds_the_same_envelopes():
    """The component search on pooled rows (detect.ROW_POOL) yields the full-resolution
    search's blobs exactly: isolated ones, ones whose boxes overlap (component masks) and
    border-cut ones, on striped lights at every row phase; clipped lights too, whose edge level
    is just above the noisy background (a box row too many would let noise into the hull)."""
    img = blank(bg=110.0, noise=6.0, seed=7)
    for i, y in enumerate((60.3, 61.0, 61.7, 62.4)):
        draw_led(img, 80.0 + 140 * i, y, 25.0, on=(230.0, 255.0)[i % 2], period_rows=10, phase_rows=i)
    draw_led(img, 100.0, 300.0, 22.0, on=255.0, period_rows=10)  # boxes of these two overlap
    for i in range(40):  # a diagonal bar beside it: its box overlaps the disc's
        img[270 + i, 118 + i:122 + i] = 230
    draw_led(img, 400.0, 477.0, 20.0, period_rows=10)  # cut by the bottom edge
    g = u8(img)
    full = detect_with_pool(g, 1, stripe_gap_px=8)
    assert len(full) >= 6
    pooled = detect_with_pool(g, 2, stripe_gap_px=8)
    assert [(b.x0, b.y0, b.x1, b.y1, b.border) for b in pooled] == \
        [(b.x0, b.y0, b.x1, b.y1, b.border) for b in full]
    for a, b in zip(pooled, full):
        assert (a.cx, a.cy, a.area_px) == (b.cx, b.cy, b.area_px)


def test_row_pooled_search_bridges_every_gap_up_to_stripe_gap_px():
    """Two lit bars `gap` rows apart are one light for every gap <= stripe_gap_px, wherever
    the gap falls among the pooled rows; a gap of stripe_gap_px + 3 * pool - 1 rows never is."""
    gap_px, pool = 8, 2
    for gap in list(range(1, gap_px + 1)) + [gap_px + 3 * pool - 1]:
        for start in range(100, 100 + pool):
            img = blank(w=200, h=200)
            img[start - 20:start, 80:120] = 230
            img[start + gap:start + gap + 20, 80:120] = 230
            n = len(detect_with_pool(u8(img), pool, stripe_gap_px=gap_px, max_aspect=0))
            assert n == (1 if gap <= gap_px else 2), (gap, start, n)


@pytest.mark.parametrize("height", [477, 479, 480])
def test_row_pooled_search_equals_full_resolution_at_the_top_and_bottom_edges(height):
    """Lights cut by the top or bottom edge, whose last rows there may be a dark stripe, in
    frames of odd and even height: the full-resolution close reaches the edge from a component
    within half its kernel of it (outside the image counts as lit), and the pooled search's
    boxes must follow it exactly; clipped lights in noise make any row too many visible."""
    for seed in range(6):
        img = blank(w=400, h=height, bg=110.0, noise=6.0, seed=seed)
        rng = np.random.default_rng(seed)
        for y in (rng.uniform(-10, 10), rng.uniform(height - 10, height + 10),
                  rng.uniform(40, height - 40)):
            draw_led(img, rng.uniform(20, 380), y, rng.uniform(8, 25), on=rng.choice([230.0, 255.0]),
                     period_rows=int(rng.integers(6, 12)), phase_rows=int(rng.integers(0, 6)))
        g = u8(img)
        def key(blobs):
            return [(b.x0, b.y0, b.x1, b.y1, b.border, b.cx, b.cy, b.area_px) for b in blobs]
        full = key(detect_with_pool(g, 1, stripe_gap_px=8))
        assert len(full) >= 2
        assert key(detect_with_pool(g, 2, stripe_gap_px=8)) == full, seed


@pytest.mark.parametrize("pool", [1, 2])
def test_cropped_close_and_contours_equal_the_whole_frame_search(pool):
    """`_components` closes and searches only the box of the lit pixels (grown by the kernel)
    in reused buffers: its contours (in order) and boxes equal those of a close and contour
    search of the whole frame, also for lights at every edge and corner (the close treats the
    outside of the frame as lit) and for an empty frame."""
    from receiver.vision.detect import Scratch, _close_reach, _close_size, _components, _pooled_boxes_exact
    rng = np.random.default_rng(7)
    scratch = Scratch()
    for trial in range(12):
        img = blank(noise=2.0, seed=trial)
        for _ in range(int(rng.integers(0, 7))):
            x, y = float(rng.uniform(-5, img.shape[1] + 5)), float(rng.uniform(-5, img.shape[0] + 5))
            draw_led(img, x, y, float(rng.uniform(3, 40)), period_rows=float(rng.uniform(4, 9)),
                     square=bool(rng.integers(0, 2)))
        gray = u8(img)
        level, _ = auto_level(gray)
        for gap, join in ((8, 2), (3, 0), (0, 0)):
            got_c, got_r = _components(gray, level, gap, join, 1, pool, scratch)
            search = np.stack([gray[i:i + pool].max(axis=0) for i in range(0, gray.shape[0], pool)])
            gap_y = math.ceil((2 * _close_reach(gap) + 1) / pool) - 1 if pool > 1 else gap
            _, mask = cv2.threshold(search, level, 255, cv2.THRESH_BINARY)
            if gap_y >= 1 or join >= 1:
                kernel = np.ones((_close_size(gap_y), _close_size(join)), np.uint8)
                mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
            want_c, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            want_r = np.array([cv2.boundingRect(c) for c in want_c], np.int64).reshape(-1, 4)
            if pool > 1 and len(want_r):
                want_r = _pooled_boxes_exact(gray, want_r, level, pool, _close_reach(gap))
            assert len(got_c) == len(want_c)
            assert all(np.array_equal(a, b) for a, b in zip(got_c, want_c))
            assert np.array_equal(got_r, want_r)


def test_mean_in_mask_of_a_box_past_the_frame_reads_only_the_pixels_inside():
    """An emitter moved past the frame's edge (a pair's prediction): the mean over the part of
    its envelope inside the frame, never pixels wrapped around from the other side, never an
    error (the box past the right edge used to raise, a negative start to wrap)."""
    from receiver.core.records import Blob
    from receiver.vision.profile import envelope_mask, mean_in_mask
    gray = np.zeros((40, 50), np.uint8)
    gray[:, :25] = 100          # left half 100, right half 0
    gray[:, 45:] = 200          # the right edge 200

    def square(x0, y0, w=7):
        hull = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + w - 1], [x0, y0 + w - 1]], float)
        return Blob(x0 + w / 2, y0 + w / 2, float(w * w), hull, x0, y0, x0 + w, y0 + w, True, 200.0, 50.0, 10.0)

    assert mean_in_mask(gray, square(46, 10)) == 200.0      # 5 px past the right edge
    assert mean_in_mask(gray, square(-3, 10)) == 100.0      # 3 px past the left edge: no wrap to 200
    assert mean_in_mask(gray, square(20, -4)) == float((envelope_mask(square(20, -4))[4:, :].astype(int)
                                                         * gray[0:3, 20:27]).sum()) / envelope_mask(square(20, -4))[4:, :].sum()
    assert mean_in_mask(gray, square(60, 10)) == 0.0        # wholly outside


def test_mean_in_mask_is_the_mean_of_the_envelope_pixels():
    """mean_in_mask (cv2 sums) equals the plain numpy mean over the filled envelope, float for
    float, on blobs anywhere in the frame and of any size down to a point."""
    from receiver.core.records import Blob
    from receiver.vision.profile import mean_in_mask
    rng = np.random.default_rng(11)
    gray = rng.integers(0, 256, size=(60, 80), dtype=np.uint8)
    checked = edge = 0
    for _ in range(300):
        cx, cy = rng.uniform(-2, 82), rng.uniform(-2, 62)
        r = rng.uniform(0.0, 9.0)
        ang = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 9)))
        hull = np.stack((cx + r * np.cos(ang), cy + r * np.sin(ang)), axis=1)
        x0, y0 = max(int(np.floor(hull[:, 0].min())), 0), max(int(np.floor(hull[:, 1].min())), 0)
        # up to one past the frame (an envelope on its last row / column): roi and mask differ
        x1, y1 = min(int(np.floor(hull[:, 0].max())) + 1, 81), min(int(np.floor(hull[:, 1].max())) + 1, 61)
        if x1 <= x0 or y1 <= y0:
            continue
        b = Blob(cx, cy, 1.0, hull, x0, y0, x1, y1, False, 200.0, 50.0, 10.0)
        mask = envelope_mask(b)
        n = int(mask.sum())
        roi = gray[y0:y1, x0:x1]
        if roi.shape != mask.shape:
            edge += 1
            continue  # numpy broadcasting decides, as before (unchanged path)
        want = float((roi.astype(np.int64) * mask).sum()) / n if n else 0.0
        assert mean_in_mask(gray, b) == want
        checked += 1
    assert checked > 150 and edge > 0


@pytest.mark.parametrize("f", [2, 4, 8])
def test_mask_blocks_without_resize_equal_the_nearest_neighbour_resize(f):
    """`_and_blocks` (each mask byte widened to an f x f block) gives what the INTER_NEAREST
    resize and AND give, for boxes cut short at the right and bottom (a frame edge)."""
    from receiver.vision.detect import _and_blocks
    rng = np.random.default_rng(f)
    for hs, ws in ((1, 1), (3, 7), (17, 23)):
        comp = np.where(rng.random((hs + 4, ws + 4)) < 0.6, 255, 0).astype(np.uint8)
        crop = comp[2:2 + hs, 1:1 + ws]  # a strided view, as `_masked_boxes` cuts it
        gray = rng.integers(0, 256, (hs * f + 5, ws * f + 9), dtype=np.uint8)
        for bh, bw in ((hs * f, ws * f), (hs * f - f + 1, ws * f - 1)):
            g = gray[3:3 + bh, 2:2 + bw]
            want = cv2.bitwise_and(g, cv2.resize(crop, (ws * f, hs * f), interpolation=cv2.INTER_NEAREST)[:bh, :bw])
            out = np.full((bh + 2, bw + 2), 7, np.uint8)
            _and_blocks(g, crop, f, out[1:1 + bh, 1:1 + bw])
            assert np.array_equal(out[1:1 + bh, 1:1 + bw], want)
            assert (out[0] == 7).all() and (out[-1] == 7).all() and (out[:, 0] == 7).all() and (out[:, -1] == 7).all()


def test_downsampled_search_gives_the_same_blobs_with_and_without_the_block_masks(monkeypatch):
    """A 4K frame (factor 4) and a 1080p one (factor 2) with big striped lights: the boxes
    masked by `_and_blocks` give the blobs the resize gives."""
    import receiver.vision.detect as detect_mod
    for w, h, r in ((3840, 2160, 160.0), (1920, 1080, 90.0)):
        img = blank(w, h, noise=2.0)
        for x, y in ((w * 0.25, h * 0.3), (w * 0.7, h * 0.6), (w * 0.5, h * 0.85)):
            draw_led(img, x, y, r, period_rows=24)
        g = u8(img)
        monkeypatch.setattr(detect_mod, "WIDE_MIN_PX", 0)
        fast = detect(g, stripe_gap_px=14)
        monkeypatch.setattr(detect_mod, "WIDE_MIN_PX", 10 ** 12)
        slow = detect(g, stripe_gap_px=14)
        assert len(fast) == 3 and len(slow) == 3
        assert all(same_blob(a, b) for a, b in zip(fast, slow))
