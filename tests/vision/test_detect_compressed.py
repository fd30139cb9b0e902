"""A compressed camera (JPEG frames, as MJPEG stores them): its flat background carries far less
noise than its sensor had, while the blocks that hold a light ring around it. The faint-emitter
threshold measures the noise next to the lights too (`near_light_sigma`), so the ringing gives
no specks and does not break a light up, and a sensor whose background is not flattened keeps
its threshold."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from receiver.pipeline import S2PSK_FAINT_DETECT
from receiver.vision.detect import auto_level, detect, near_light_sigma

H, W = 240, 320
# (cx, cy, peak gray above the background, width px): far heads of a few px, near ones of tens
LIGHTS = ((40.3, 40.4, 60.0, 1.0), (100.6, 60.2, 40.0, 2.0), (170.2, 90.7, 180.0, 4.0),
          (250.8, 120.3, 120.0, 3.0), (60.4, 180.6, 30.0, 1.0), (220.5, 200.2, 150.0, 6.0))


def _frame(seed: int, sigma: float = 1.4, bg: float = 8.0) -> np.ndarray:
    """A sensor frame (float): background `bg`, Gaussian noise `sigma`, the LIGHTS blurred."""
    rng = np.random.default_rng(seed)
    img = bg + sigma * rng.standard_normal((H, W))
    yy, xx = np.mgrid[0:H, 0:W]
    for cx, cy, peak, width in LIGHTS:
        g = np.zeros((H, W))
        for x in np.linspace(cx - width / 2, cx + width / 2, 7):
            g += np.exp(-((xx - x) ** 2 + (yy - cy) ** 2) / (2 * 0.8 ** 2))
        img += peak * g / g.max()
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _jpeg(img: np.ndarray, quality: int) -> np.ndarray:
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)


def _flatten(img: np.ndarray, bg: int = 8) -> np.ndarray:
    """The background's noise removed (what a compressing camera does to an empty block), the
    lights' blocks kept: the frame a camera stores before its JPEG step rings them."""
    out = img.copy()
    lit = cv2.dilate((img > bg + 12).astype(np.uint8), np.ones((17, 17), np.uint8)).astype(bool)
    out[~lit] = bg
    return out


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("quality", [50, 75])
def test_compressed_frame_gives_one_blob_per_light_and_no_specks(seed, quality):
    img = _jpeg(_flatten(_frame(seed)), quality)
    flat = img[::4, ::4]
    assert np.mean(flat == 8) > 0.9  # the background is flattened: far below the sensor's 1.4 gray
    # the threshold alone (the shape test off): each light is one blob, and nothing else is
    blobs = detect(img, **{**S2PSK_FAINT_DETECT, "max_aspect": 0})
    pts = np.array([(b.cx, b.cy) for b in blobs])
    assert len(blobs) == len(LIGHTS), pts
    for cx, cy, _, _ in LIGHTS:
        assert np.min(np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)) < 1.5, (cx, cy, pts)
    # the receiver's settings: no speck either (the shape test may drop a 2 x 3 px far light
    # whose blur tail joins it diagonally, on an uncompressed frame too)
    blobs = detect(img, **S2PSK_FAINT_DETECT)
    assert len(blobs) >= len(LIGHTS) - 2
    for b in blobs:
        assert min(np.hypot(b.cx - cx, b.cy - cy) for cx, cy, _, _ in LIGHTS) < 1.5, b


def test_the_flat_background_alone_would_cut_the_ringing_into_specks(monkeypatch):
    """What the near-light noise prevents: the threshold from the flat background's sigma
    finds more blobs than lights (the JPEG ringing around them)."""
    from receiver.vision import detect as detect_mod
    img = _jpeg(_flatten(_frame(0)), 50)
    level, bg = auto_level(img, k_mad=S2PSK_FAINT_DETECT["k_mad"], min_contrast=S2PSK_FAINT_DETECT["min_contrast"],
                           fine_noise=True)
    assert near_light_sigma(img, bg + S2PSK_FAINT_DETECT["min_contrast"], bg) > 0.8
    monkeypatch.setattr(detect_mod, "auto_level", lambda *a, **k: (bg + S2PSK_FAINT_DETECT["min_contrast"], bg))
    low = detect(img, **S2PSK_FAINT_DETECT)
    assert len(low) > len(LIGHTS)
    assert level > bg + S2PSK_FAINT_DETECT["min_contrast"] + 4


@pytest.mark.parametrize("sigma", [0.6, 1.4, 3.0])
def test_near_light_sigma_of_an_unflattened_sensor_is_its_noise(sigma):
    img = _frame(5, sigma=sigma, bg=20.0)
    assert near_light_sigma(img, 20.0 + 12 * sigma, 20.0) == pytest.approx(sigma, rel=0.25)


def test_a_background_clipped_at_black_or_no_light_leaves_the_level_alone():
    rng = np.random.default_rng(1)
    dark = np.clip(np.rint(0.4 * rng.standard_normal((H, W))), 0, 255).astype(np.uint8)
    assert near_light_sigma(dark, 4.0, 0.0) == 0.0  # no lit pixel: no neighbourhood
    lit = dark.copy()
    lit[100:104, 100:110] = 90
    assert near_light_sigma(lit, 4.0, 0.0) == 0.0  # nothing below a black background
    got = auto_level(lit, k_mad=12.0, min_contrast=4.0, fine_noise=True)
    assert got == pytest.approx(auto_level(dark, k_mad=12.0, min_contrast=4.0, fine_noise=True), abs=0.05)


@pytest.mark.parametrize("bg", [0.0, 2.0, 8.0, 40.0])
def test_near_light_noise_is_at_most_the_background(bg):
    """The noise next to the lights is measured from the deviations below the background, so it
    never exceeds the background (auto_level skips it where k_mad times that could not raise
    the level): on raw and compressed frames with a wide noise, and the level is the same with
    and without the skip."""
    import receiver.vision.detect as detect_mod
    for seed in range(4):
        for img in (_frame(seed, sigma=6.0, bg=bg), _jpeg(_frame(seed, sigma=6.0, bg=bg), 50)):
            med = float(np.median(img))
            for level in (med + 3.0, med + 20.0, 100.0):
                assert near_light_sigma(img, level, med) <= med + 1e-9
            got = auto_level(img, fine_noise=True, min_contrast=4.0, k_mad=12.0)
            want = _level_always_measured(img, detect_mod)
            assert got == want


def _level_always_measured(img, detect_mod):
    """auto_level's level with the noise next to the lights always measured (no skip)."""
    hist = np.empty(256, np.float32)
    sample = np.ascontiguousarray(img[::4, ::4])
    hist = cv2.calcHist([sample], [0], None, [256], [0, 256]).ravel()
    cdf = np.cumsum(hist)
    med = int(np.searchsorted(cdf, cdf[-1] / 2.0))
    dev = np.bincount(np.abs(np.arange(256) - med), weights=hist, minlength=256)
    mad = int(np.searchsorted(np.cumsum(dev), cdf[-1] / 2.0))
    level = max(med + 12.0 * detect_mod.noise_sigma(hist, med, mad), med + 4.0)
    near = near_light_sigma(img, min(level, 254.0), med)
    return float(min(max(level, med + 12.0 * near), 254.0)), float(med)


def test_near_light_sigma_is_the_rms_below_the_background_next_to_the_lights():
    """near_light_sigma against its definition with OpenCV on the whole frame: the pixels above
    the level (cv2.threshold), those within NEAR_LIGHT_PX of one (cv2.dilate) and not lit, at or
    below the background: the RMS of their deviations below it (0 under NEAR_LIGHT_MIN_SAMPLES)."""
    import receiver.vision.detect as detect_mod
    imgs = [_jpeg(_frame(s, sigma=3.0, bg=b), 60) for s, b in ((1, 8.0), (2, 20.0))]
    imgs.append(np.zeros((H, W), np.uint8))
    got = []
    for img in imgs:
        bg = float(np.median(img))
        for lv in (12.5, 30.0, 254.0):
            v = near_light_sigma(img, lv, bg)
            _, lit = cv2.threshold(img, lv, 255, cv2.THRESH_BINARY)
            r = detect_mod.NEAR_LIGHT_PX
            near = (cv2.dilate(lit, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0) & (lit == 0)
            below = near & (img <= np.floor(bg))
            dev = bg - img[below].astype(np.float64)
            want = float(np.sqrt(np.mean(dev * dev))) if dev.size >= detect_mod.NEAR_LIGHT_MIN_SAMPLES else 0.0
            assert v == pytest.approx(want, rel=1e-9, abs=1e-12)
            got.append(v)
    assert any(v > 0 for v in got)
