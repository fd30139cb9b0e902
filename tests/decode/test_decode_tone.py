"""Tone decoder (receiver/decode_tone.py): synthetic stripes and the real Luxapose photos."""

import cv2
import numpy as np
import pytest

from receiver.io.camera import load_camera
from receiver.decode.tone import ToneDecoder, default_spacing_hz, match_tone, stripe_frequency_hz
from receiver.vision.tone_profile import tone_profile
from signals import tone_profile as synth_profile
from tests.decode.test_tone_real import PHOTOS


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
        p, w = synth_profile(f, t_row, exposure, n_rows, rng, noise=float(rng.uniform(0, 20)))
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
        p, w = synth_profile(2100.0, 20.0, 40.0, 70, rng, noise=30.0)
        st = dec.step(p, w)
    assert st.led_id == 11 and st.frames == 5
    assert abs(st.freq_hz - 2100.0) < 20.0


def test_tone_step_benchmark(benchmark):
    rng = np.random.default_rng(4)
    p, w = synth_profile(3000.0, 20.0, 30.0, 100, rng, noise=5.0)
    f, _ = benchmark(stripe_frequency_hz, p, 20.0, w)
    assert abs(f / 3000.0 - 1) < 0.005


# --- real photos (Luxapose, Lumia 1020) -------------------------------------------------

def load_sensor_gray(path, cam):
    """Gray photo in sensor orientation (rows = rolling-shutter rows), turned the way
    `occloc run` turns a portrait-stored file of a landscape sensor."""
    from receiver.io.camera import fit_camera
    g = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    _, rotate = fit_camera(cam, (g.shape[1], g.shape[0]))
    return cv2.rotate(g, cv2.ROTATE_90_COUNTERCLOCKWISE) if rotate else g


@pytest.mark.parametrize("photo", sorted(PHOTOS))
def test_luxapose_photos(photo, luxapose):
    """Detector blobs (the pipeline's still-photo settings) -> tone_profile -> spectral peak:
    every LED of the photo matched, within 1 % of its true frequency (see test_tone_real)."""
    from receiver.io.ledmap import load_map
    from receiver.vision.detect import detect
    from receiver.pipeline import Receiver
    cam = load_camera(str(luxapose / "camera_lumia1020.yaml"))
    map_name, truth = PHOTOS[photo]
    led_map = load_map(str(luxapose / map_name))
    gray = load_sensor_gray(luxapose / photo, cam)
    rx = Receiver(cam, led_map, still=True)
    dec = ToneDecoder({i: led.freq_hz for i, led in led_map.leds.items()}, cam.row_readout_us)
    found = {}
    for blob in detect(gray, settings=rx.settings.detect):
        prof, w, _ = tone_profile(gray, blob)
        f, q = stripe_frequency_hz(prof, cam.row_readout_us, w, fmin_hz=dec.fmin_hz, fmax_hz=dec.fmax_hz)
        led = match_tone(f, dec.table) if q >= dec.min_quality else None
        if led is not None:
            assert led not in found, (photo, led, f, found)
            found[led] = f
    assert sorted(found) == sorted(truth), found
    for led, (f_true, tol) in truth.items():
        assert abs(found[led] / f_true - 1) <= tol, (photo, led, found[led])


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


# --- tone profile (receiver/tone_profile.py) on a synthetic saturated LED ------------------

def _glowing_led_frame(freq_hz, t_row_us, exposure_us, rng, *, size=400, core_r=40.0,
                       glow_sigma=45.0, gain=900.0, noise=1.5):
    """Frame of one tone LED imaged like the Luxapose photos: a bright disc that saturates,
    inside a Gaussian glow that stays visible ~2 core radii out; every row shows the LED's
    state at its own instant (exact exposure integral of the drive waveform)."""
    from signals import exposure_mean, pin_waveform
    from firmware_tx.schedule import make_schedule
    sch = make_schedule("tone", 0, freq_hz)
    wave = pin_waveform(sch, 0)
    t = rng.uniform(0, 1 / freq_hz) + np.arange(size) * t_row_us * 1e-6
    state = exposure_mean(wave, sch.tick_hz, t, exposure_us * 1e-6)
    yy, xx = np.mgrid[0:size, 0:size] - size / 2.0
    rr = np.hypot(xx, yy)
    light = np.where(rr <= core_r, 1.0, 0.0) + 0.25 * np.exp(-0.5 * (rr / glow_sigma) ** 2)
    img = gain * light * state[:, None] + rng.normal(0, noise, (size, size))
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def test_tone_profile_covers_glow_and_is_accurate():
    """The half-maximum envelope of a saturated LED (only its core, ~3.4 stripe periods) gives a
    noisier frequency; the tone profile reaches into the striped glow: within 0.4 %, and half
    the mean error of the envelope's row profile on the same frames."""
    from receiver.core.records import Blob
    from receiver.vision.profile import row_profile
    rng = np.random.default_rng(6)
    t_row, f = 21.035, 2000.0
    err_tone, err_env = [], []
    for _ in range(5):
        gray = _glowing_led_frame(f, t_row, 60.0, rng)
        c = gray.shape[0] / 2.0
        lo, hi = int(c - 40), int(c + 41)
        hull = np.array([[lo, lo], [hi - 1, lo], [hi - 1, hi - 1], [lo, hi - 1]], np.float64)
        blob = Blob(c, c, 81.0 * 81.0, hull, lo, lo, hi, hi, False, 255.0, 7.6, 0.0)
        prof, w, y0 = tone_profile(gray, blob)
        assert y0 < lo - 20 and y0 + prof.size > hi + 20  # the glow rows are in
        assert np.all(w == w[0]) and w[0] >= 0.7 * (hi - lo)
        est, q = stripe_frequency_hz(prof, t_row, w, fmin_hz=1000.0, fmax_hz=6000.0)
        assert q > 30
        err_tone.append(abs(est / f - 1))
        env, w_env, _ = row_profile(gray, blob)
        err_env.append(abs(stripe_frequency_hz(env, t_row, w_env, fmin_hz=1000.0, fmax_hz=6000.0)[0] / f - 1))
    assert max(err_tone) < 0.004, err_tone
    assert np.mean(err_tone) < 0.6 * np.mean(err_env), (err_tone, err_env)
    # the blob on the frame's edge: the band is clipped, never an error
    blob = Blob(1.0, 1.0, 4.0, np.array([[0.0, 0.0], [2.0, 2.0]]), 0, 0, 3, 3, True, 255.0, 7.6, 0.0)
    prof, w, y0 = tone_profile(gray, blob)
    assert y0 == 0 and prof.size == w.size


def test_tone_profile_benchmark(benchmark):
    from receiver.core.records import Blob
    gray = _glowing_led_frame(3000.0, 21.035, 60.0, np.random.default_rng(7))
    hull = np.array([[160.0, 160.0], [240.0, 160.0], [240.0, 240.0], [160.0, 240.0]])
    blob = Blob(200.0, 200.0, 6561.0, hull, 160, 160, 241, 241, False, 255.0, 7.6, 0.0)
    prof, w, _ = benchmark(tone_profile, gray, blob)
    est, _ = stripe_frequency_hz(prof, 21.035, w, fmin_hz=1000.0, fmax_hz=6000.0)
    assert abs(est / 3000.0 - 1) < 0.005


def test_record_too_short_for_the_tone_is_no_estimate():
    """A blob spanning 1.38 periods of its 2000 Hz tone (46 rows of 15 us, a 10 cm panel on the
    bundled static scene): the searched band starts at 1.5 cycles per record (2174 Hz), above
    the line, so the spectrum's maximum is the band edge, a frequency set by the record length.
    It must not be reported: in this table it would be read as the 2150 Hz LED."""
    rng = np.random.default_rng(5)
    table = {1: 2000.0, 2: 2150.0, 3: 2300.0}
    for _ in range(20):
        p, w = synth_profile(2000.0, 15.0, 20.0, 46, rng, noise=2.0)
        f, _ = stripe_frequency_hz(p, 15.0, w, fmin_hz=1000.0, fmax_hz=3450.0)
        assert np.isnan(f) or match_tone(f, table) in (1, None), f
    dec = ToneDecoder(table, 15.0)
    for _ in range(10):
        p, w = synth_profile(2000.0, 15.0, 20.0, 46, rng, noise=2.0)
        assert dec.step(p, w).led_id in (1, None)


def test_decoder_match_is_match_tone():
    """ToneDecoder._match (table derived once, plain floats) answers as match_tone does."""
    import math
    from receiver.decode.tone import ToneDecoder, match_tone
    rng = np.random.default_rng(8)
    for _ in range(300):
        table = {int(i): float(f) for i, f in zip(rng.integers(0, 1000, 5), rng.uniform(500, 5000, 5))}
        dec = ToneDecoder(table, 15.0)
        for f in list(rng.uniform(400, 5100, 20)) + list(table.values()) + [math.nan, math.inf]:
            assert dec._match(float(f)) == match_tone(float(f), table)
    assert ToneDecoder({}, 15.0)._match(1000.0) is None


def test_nfft_is_the_log2_formula():
    from receiver.decode.tone import _nfft
    m = np.arange(1, 1 << 18)
    assert all(_nfft(int(v)) == 1 << int(np.ceil(np.log2(v))) for v in m)
