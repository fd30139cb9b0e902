"""Tone decoder (receiver/decode_tone.py): synthetic stripes and the real Luxapose photos."""

import json

import cv2
import numpy as np
import pytest

from receiver.config import load_camera
from receiver.decode_tone import (ToneDecoder, default_spacing_hz, match_tone,
                                  stripe_frequency_hz)
from signals import tone_profile


def test_synthetic_accuracy():
    """Random frequencies 1-10 kHz, row times, exposures of 10-40 % of a period, blob sizes
    (>= 4 stripes, >= 40 rows) and noise: 95 % within 0.4 %, all within 1.5 % (the worst are
    stripes under 4 rows with short exposures: sharp edges whose aliased odd harmonics land
    near the fundamental and pull the peak)."""
    rng = np.random.default_rng(1)
    errs = []
    for _ in range(300):
        t_row = float(rng.uniform(10.0, 30.0))
        f = float(rng.uniform(1000.0, min(10000.0, 0.3e6 / t_row)))
        period_rows = 1e6 / (f * t_row)
        n_rows = int(max(40, rng.uniform(4.0, 12.0) * period_rows))
        exposure = float(rng.uniform(0.1, 0.4)) * 1e6 / f
        p, w = tone_profile(f, t_row, exposure, n_rows, rng, noise=float(rng.uniform(0, 20)))
        est, q = stripe_frequency_hz(p, t_row, w)
        errs.append(abs(est / f - 1))
        assert q > 5
    assert max(errs) < 0.015, max(errs)
    assert np.percentile(errs, 95) < 0.004


def test_no_stripes_gives_nan():
    rng = np.random.default_rng(2)
    f, q = stripe_frequency_hz(np.full(100, 200.0), 20.0)
    assert np.isnan(f) or q < 5
    f, q = stripe_frequency_hz(np.ones(5), 20.0)
    assert np.isnan(f)
    f, q = stripe_frequency_hz(rng.normal(100, 5, 120), 20.0)
    assert q < 30


def test_match_tone_half_spacing():
    table = {1: 2000.0, 2: 2500.0, 3: 3000.0}
    assert default_spacing_hz(table) == 500.0
    assert match_tone(2240.0, table) == 1
    assert match_tone(2260.0, table) == 2
    assert match_tone(1751.0, table) == 1
    assert match_tone(1749.0, table) is None  # beyond half a spacing below the lowest
    assert match_tone(3249.0, table) == 3 and match_tone(3251.0, table) is None
    assert match_tone(float("nan"), table) is None
    assert match_tone(2010.0, table, spacing_hz=10.0) is None
    assert default_spacing_hz({1: 1000.0, 2: 1020.0}) == 50.0  # floored at 50 Hz
    assert default_spacing_hz({1: 1000.0}) == 50.0


def test_tone_decoder_over_frames():
    rng = np.random.default_rng(3)
    table = {10: 2000.0, 11: 2100.0, 12: 2200.0}
    dec = ToneDecoder(table, 20.0)
    for _ in range(5):
        p, w = tone_profile(2100.0, 20.0, 40.0, 70, rng, noise=30.0)
        st = dec.step(p, w)
    assert st.led_id == 11 and st.frames == 5
    assert abs(st.freq_hz - 2100.0) < 20.0


def test_tone_step_benchmark(benchmark):
    rng = np.random.default_rng(4)
    p, w = tone_profile(3000.0, 20.0, 30.0, 100, rng, noise=5.0)
    f, _ = benchmark(stripe_frequency_hz, p, 20.0, w)
    assert abs(f / 3000.0 - 1) < 0.005


# --- real photos (Luxapose, Lumia 1020) -------------------------------------------------

def crude_blobs(gray, *, n=10, ds=8, rel_level=0.08, min_level=20, env_frac=0.01):
    """A test-only LED locator: threshold a downsampled frame, take the biggest blobs, and
    build each one's row profile over a generous envelope (rows where the heavily blurred
    light exceeds `env_frac` of its peak), so the dim striped rim is included."""
    small = cv2.resize(gray, (gray.shape[1] // ds, gray.shape[0] // ds),
                       interpolation=cv2.INTER_AREA)
    lit = (small > max(min_level, rel_level * float(small.max()))).astype(np.uint8)
    lit = cv2.dilate(lit, np.ones((5, 5), np.uint8))
    _, lab, st, cen = cv2.connectedComponentsWithStats(lit)
    out = []
    for i in (np.argsort(-st[1:, cv2.CC_STAT_AREA])[:n] + 1):
        cx, cy = cen[i] * ds
        half = max(st[i, cv2.CC_STAT_WIDTH], st[i, cv2.CC_STAT_HEIGHT]) * ds
        x0, y0 = int(max(0, cx - half)), int(max(0, cy - half))
        roi = gray[y0:int(cy + half), x0:int(cx + half)].astype(np.float32)
        blur = cv2.blur(roi, (41, 41))
        env = (blur > env_frac * blur.max()).astype(np.uint8)
        _, lab2, st2, _ = cv2.connectedComponentsWithStats(env)
        mask = lab2 == 1 + int(np.argmax(st2[1:, cv2.CC_STAT_AREA]))
        rows = np.flatnonzero(mask.any(axis=1))
        mask, roi = mask[rows[0]:rows[-1] + 1], roi[rows[0]:rows[-1] + 1]
        w = mask.sum(axis=1).astype(np.float32)
        out.append(((cx, cy), ((roi * mask).sum(axis=1) / np.maximum(w, 1)).astype(np.float32), w))
    return out


def load_sensor_gray(path, cam):
    """Gray photo in sensor orientation (rows = rolling-shutter rows): a portrait-stored file
    of a landscape sensor is turned back (which way does not change a frequency)."""
    g = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    if g.shape == (cam.width, cam.height) and cam.width != cam.height:
        g = cv2.rotate(g, cv2.ROTATE_90_CLOCKWISE)
    return g


# photo -> (map, {nominal Hz: allowed relative error}). 1 % is the target. Two
# documented exceptions: the "2000 Hz" LED of x_0_y_1.27 shows stripes 23.3 rows apart (rising
# edges at rows ~83.5, 106.5, 129.5, 153.5 of its profile), i.e. 2037 Hz at 21.035 us/row,
# while the same rig's 2000 Hz LED in small_blob reads 2000.7 Hz: that LED ran fast in this
# photo (the peer reads it as 2069 Hz). The chandelier LEDs are 11 m away at ISO 400, their
# images are small and dim, and their estimates move by ~1 % with the envelope mask.
PHOTOS = {
    "x_0_y_1.27.jpg": ("map_test_rig.json",
                       {2000: 0.025, 2500: 0.01, 3000: 0.01, 3500: 0.01, 4000: 0.01}),
    "small_blob.jpg": ("map_test_rig.json", {2000: 0.01, 2500: 0.01, 3500: 0.01, 4000: 0.01}),
    "chandelier0_2013-05-11--02-08-21-25.jpg": ("map_chandelier0.json",
                                                {2000: 0.02, 3000: 0.02, 4000: 0.01, 5000: 0.02}),
}


@pytest.mark.parametrize("photo", sorted(PHOTOS))
def test_luxapose_photos(photo, luxapose):
    cam = load_camera(str(luxapose / "camera_lumia1020.yaml"))
    map_name, expect = PHOTOS[photo]
    leds = json.loads((luxapose / map_name).read_text())["leds"]
    table = {led["id"]: float(led["freq_hz"]) for led in leds}
    gray = load_sensor_gray(luxapose / photo, cam)
    best = {}  # id -> (quality, freq)
    for _, profile, weights in crude_blobs(gray):
        f, q = stripe_frequency_hz(profile, cam.row_readout_us, weights,
                                   fmin_hz=0.5 * min(table.values()),
                                   fmax_hz=1.5 * max(table.values()))
        led = match_tone(f, table)
        if led is not None and q > best.get(led, (0.0, 0.0))[0]:
            best[led] = (q, f)
    for led, tol in expect.items():
        assert led in best, (photo, led, best)
        q, f = best[led]
        assert abs(f / table[led] - 1) <= tol, (photo, led, f)


def test_tone_decoder_ignores_noise_blobs():
    """No CRC in tone mode: an unstriped (noise-only) blob must not get an ID."""
    rng = np.random.default_rng(5)
    table = {1: 2000.0, 2: 2500.0, 3: 3000.0, 4: 3500.0, 5: 4000.0}
    for _ in range(30):
        dec = ToneDecoder(table, 21.0)
        n = int(rng.integers(30, 300))
        for _ in range(5):
            st = dec.step((120 + rng.normal(0, 8, n)).astype(np.float32), np.full(n, 40.0))
        assert st.led_id is None
