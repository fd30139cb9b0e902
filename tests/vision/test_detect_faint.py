"""Faint far S2-PSK emitters: the noise-following threshold (`noise_sigma`, `fine_noise`) finds a
1-3 px blob of a few tens of gray on a dark, clipped background, and no blob in pure noise; the
camera-shake shift (receiver.vision.motion) and the tracker's use of it; a short clip of the
vehicle-road scene."""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from receiver.pipeline import S2PSK_FAINT_DETECT
from receiver.vision.detect import auto_level, detect, noise_sigma
from receiver.vision.track import Tracker

H, W = 240, 320


def _noise(rng, sigma, bg=0.0):
    return np.clip(np.rint(bg + sigma * rng.standard_normal((H, W))), 0, 255)


def _spot(img, cx, cy, peak, sigma_px=0.7, width_px=1.0):
    yy, xx = np.mgrid[0:H, 0:W]
    # a panel width_px wide, under a pixel tall, blurred by the lens
    g = np.zeros((H, W))
    for x in np.linspace(cx - width_px / 2, cx + width_px / 2, 5):
        g += np.exp(-((xx - x) ** 2 + (yy - cy) ** 2) / (2 * sigma_px ** 2))
    img += peak * g / g.max()
    return img


@pytest.mark.parametrize("sigma", [0.4, 1.0, 3.0])
def test_noise_sigma_is_resolved_below_one_gray_level(sigma):
    rng = np.random.default_rng(7)
    img = _noise(rng, sigma, bg=0.0 if sigma < 1 else 20.0).astype(np.uint8)
    sample = img[::4, ::4]
    hist = cv2.calcHist([np.ascontiguousarray(sample)], [0], None, [256], [0, 256]).ravel()
    med = int(np.median(sample))
    mad = int(np.median(np.abs(sample.astype(int) - med)))
    assert noise_sigma(hist, med, mad) == pytest.approx(sigma, rel=0.3)


@pytest.mark.parametrize("seed", range(6))
def test_pure_noise_gives_no_blob(seed):
    rng = np.random.default_rng(seed)
    for sigma, bg in ((0.4, 0.0), (1.0, 0.0), (1.0, 10.0)):
        img = _noise(rng, sigma, bg).astype(np.uint8)
        assert detect(img, **S2PSK_FAINT_DETECT) == []


@pytest.mark.parametrize("seed", range(4))
def test_a_faint_one_to_three_px_emitter_is_found(seed):
    rng = np.random.default_rng(100 + seed)
    img = _noise(rng, 0.4)
    _spot(img, 150.3, 120.4, peak=22.0, width_px=2.0)   # ~2 px^2, 22 gray
    _spot(img, 158.6, 120.4, peak=30.0, width_px=1.0)   # its partner, 8 px to the right
    img = np.clip(img, 0, 255).astype(np.uint8)
    level, bg = auto_level(img, fine_noise=True, min_contrast=4.0)
    assert bg == 0.0 and level == 4.0  # 8 sigma is ~3 gray: the 4-gray floor holds
    blobs = detect(img, **S2PSK_FAINT_DETECT)
    assert len(blobs) == 2, blobs
    (a, b) = sorted(blobs, key=lambda b: b.cx)
    assert abs(a.cx - 150.3) < 0.6 and abs(b.cx - 158.6) < 0.6 and abs(a.cy - 120.4) < 0.6
    assert all(1.0 <= x.area_px <= 12.0 for x in blobs)
    # the fixed 24-gray floor and the 6 px^2 area floor lose the pair
    assert len(detect(img, min_area_px=6.0)) < 2


def test_a_one_row_panel_skips_the_shape_test():
    rng = np.random.default_rng(3)
    img = _noise(rng, 0.4)
    img[100, 60:68] += 40.0  # one row, 8 px wide: aspect 8, no contour area
    img = np.clip(img, 0, 255).astype(np.uint8)
    assert len(detect(img, **S2PSK_FAINT_DETECT)) == 1
    assert detect(img, **{**S2PSK_FAINT_DETECT, "shape_min_rows": 0}) == []


def test_tracker_follows_a_light_through_the_shake_with_the_shift():
    from receiver.core.records import Blob

    def blob(x, y):
        return Blob(x, y, 2.0, np.array([[x, y]]), int(x), int(y), int(x) + 1, int(y) + 1, False, 30.0, 4.0, 0.0)

    shakes = [(0, 0), (6, -5), (-7, 4), (5, 6), (-6, -6)]
    for use_shift, same in ((True, True), (False, False)):
        tr = Tracker(gate_px=3.0)
        tr.gate_size = 0.0  # a fixed gate (track.GATE_SIZE)
        pos = np.array([100.0, 100.0])
        ids = set()
        for k, s in enumerate(shakes):
            pos = pos + s
            tracks = tr.step(k, [blob(*pos)], shift=s if use_shift else None)
            ids.add(next(t.track_id for t in tracks if t.seen))
        assert (len(ids) == 1) is same


def test_vehicle_road_clip_far_emitters_found_without_false_blobs():
    """Three rendered frames of the vehicle-road scene (seed 1): of the lit emitters of 1-5 px^2
    (truth area; lit = a peak of 10+ gray at the truth centre), the faint-emitter settings find
    most, the default S2-PSK settings (24-gray floor, 6 px^2) few, and no blob is far from a light."""
    from tools.synth.render import FrameRenderer
    from tools.synth.scenes import make_scene

    scene = make_scene("vehicle-road", seed=1, n_frames=3)
    r = FrameRenderer(scene, 1)
    found = {"faint": 0, "default": 0}
    lit = 0
    for k in range(3):
        img, truth = r.render(k)
        ems = [e for d in truth["leds"] if d.get("emitters") for e in d["emitters"]]
        pts = np.array([(e["cx"], e["cy"]) for e in ems])
        small = [e for e in ems if e["visible"] and 1.0 <= e["area_px"] <= 5.0
                 and img[int(round(e["cy"])), int(round(e["cx"]))] >= 10]
        lit += len(small)
        for name, kw in (("faint", S2PSK_FAINT_DETECT), ("default", dict(min_area_px=6.0))):
            blobs = detect(img, **kw)
            for b in (b for b in blobs if not b.border):  # each at a light (an emitter, a merged head)
                assert np.min(np.hypot(pts[:, 0] - b.cx, pts[:, 1] - b.cy)) < 12.0, (name, b)
            # found: inside a blob's box (its own blob, or the merged blob of a lit head)
            found[name] += sum(any(b.x0 - 1 <= e["cx"] <= b.x1 and b.y0 - 1 <= e["cy"] <= b.y1 for b in blobs)
                               for e in small)
    assert lit >= 6
    # measured: faint 9, default 1 of 15
    assert found["faint"] >= 0.55 * lit and found["faint"] >= 3 * found["default"], (found, lit)


def test_vertical_shift_is_right_whichever_half_of_a_head_is_lit():
    from receiver.vision.motion import vertical_shift
    rng = np.random.default_rng(9)
    mids = rng.uniform((50, 50), (W - 50, H - 50), size=(12, 2))
    half = rng.uniform(3.0, 5.0, size=12)

    def lit(shift):  # each head shows A, B or its merged midpoint, at random
        side = rng.integers(-1, 2, size=12)
        return mids + np.stack((side * half, np.zeros(12)), axis=1) + shift

    prev, cur = lit((0.0, 0.0)), lit((5.5, -7.2))
    assert vertical_shift(prev, cur) == pytest.approx(-7.2, abs=0.01)
