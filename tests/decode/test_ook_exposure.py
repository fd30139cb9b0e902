"""The exposure model of the OOK decoder (receiver.decode.exposure) against known truth: profiles
integrated exactly over each row's exposure (tests/signals.py, the LED driver's own waveform),
through a phone-like tone curve and noise, decode to the ID sent; noise and corrupted streams
never yield a wrong ID."""

from __future__ import annotations

import numpy as np
import pytest

from receiver.decode.exposure import chip_kernel, mlse_chips
from receiver.decode.ook import OokDecoder, packet_template
from signals import ook_frames

RATE_HZ = 20000.0
ROW_US = 10.0


def _tone(prof: np.ndarray) -> np.ndarray:
    """A phone's tone curve: gamma 1/2.2 on 0..255 with a soft shoulder, clipped."""
    x = np.clip(prof / 255.0, 0.0, 1.0)
    return (255.0 * np.tanh(1.6 * x ** (1 / 2.2)) / np.tanh(1.6)).astype(np.float32)


def _decode(led_id, exposure_us, seed, *, frames=40, n_rows=130, noise=2.0, tone=True, **kw):
    rng = np.random.default_rng(seed)
    dec = OokDecoder(RATE_HZ, ROW_US, exposure_us, **kw)
    st = None
    for prof, w in ook_frames(led_id, RATE_HZ, ROW_US, exposure_us, n_rows, frames, rng,
                              gain=200.0, offset=15.0, noise=noise, width_px=120):
        st = dec.step(_tone(prof) if tone else prof, w)
    return st.led_id, dec


def test_kernel_is_a_normalised_box():
    """A row's chip weights sum to one (it reads the mean over its exposure) for any blur."""
    for e, blur in ((0.3, 0.0), (1.0, 0.1), (1.75, 0.3), (2.0, 0.0)):
        d, h = chip_kernel(e, blur)
        # sum over chips k of h(tau - k) at any tau: the kernel's integer-spaced samples
        for tau in (0.0, 0.37, 0.81):
            k = np.arange(-10, 11)
            assert np.interp(tau - k, d, h, left=0.0, right=0.0).sum() == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("exposure_us", [60.0, 75.0, 87.0])
@pytest.mark.parametrize("led_id", [0x1234, 0xBEEF])
def test_long_exposure_decodes_the_id_sent(exposure_us, led_id):
    """1.2 to 1.75 chips of exposure, tone curve, noise: the ID sent, from 40 frames."""
    got, dec = _decode(led_id, exposure_us, seed=led_id % 97 + int(exposure_us))
    assert dec.exposure_model
    assert got == led_id


def test_two_chip_exposure_mostly_decodes_never_wrong():
    """2 chips of exposure (a Manchester pair averages to its mean: the limit): most of 8
    LEDs decode, none wrongly."""
    got = [(_decode(0x4000 + 977 * s, 100.0, seed=s)[0], 0x4000 + 977 * s) for s in range(8)]
    assert all(g in (None, want) for g, want in got)
    assert sum(g == want for g, want in got) >= 4


def test_mlse_reads_noise_free_chips_exactly():
    """A noise-free, exactly integrated profile at 1.75 chips of exposure: every whole chip the
    sequence estimate returns is the chip sent (at its best cyclic position)."""
    led_id = 0x5A17
    rng = np.random.default_rng(3)
    (prof, w), = ook_frames(led_id, RATE_HZ, ROW_US, 87.5, 160, 1, rng, gain=1.0, offset=0.0,
                            falloff=0.0)
    r = mlse_chips(prof.astype(float), np.ones(prof.size), 5.0, 1.75, 0.0, 8)
    llr = r[0][4:-4]  # the partly seen chips at both ends aside
    t = packet_template(led_id) > 0
    hard = llr > 0
    best = max(np.mean(hard == t[(s + np.arange(hard.size)) % 54]) for s in range(54))
    assert best == 1.0


def test_noise_never_yields_an_id():
    """Profiles of pure noise (with the blob's shape) at long exposure: no ID in 300 decoders
    of 12 frames each."""
    rng = np.random.default_rng(11)
    for _ in range(300):
        dec = OokDecoder(RATE_HZ, ROW_US, 87.0)
        for _ in range(12):
            n = int(rng.integers(60, 200))
            base = 120.0 * (1.0 - 0.3 * np.linspace(-1, 1, n) ** 2)
            prof = base + rng.normal(0.0, rng.uniform(1.0, 40.0), n)
            if rng.uniform() < 0.5:  # smooth noise: stripes of random widths
                prof = np.convolve(prof, np.ones(int(rng.integers(2, 9))) / 4.0, mode="same")
            st = dec.step(prof.astype(np.float32), np.full(n, 80.0, np.float32))
        assert st.led_id is None


@pytest.mark.parametrize("exposure_us", [10.0, 87.0])
def test_every_persistent_single_chip_error_never_a_wrong_id(exposure_us):
    """A stream with any one of its 54 chips sent inverted in every packet is not a packet of
    any ID at distance zero: the decoder reports nothing or the ID sent, never another
    (short exposure: the plain sampler; long: the exposure model)."""
    led_id = 0x3C5A
    for chip in range(54):
        rng = np.random.default_rng(chip)
        dec = OokDecoder(RATE_HZ, ROW_US, exposure_us)
        st = None
        for prof, w in ook_frames(led_id, RATE_HZ, ROW_US, exposure_us, 130, 8, rng,
                                  flip_chips=(chip,), noise=2.0, width_px=120):
            st = dec.step(prof, w)
        assert st.led_id in (None, led_id), chip


@pytest.mark.parametrize("exposure_us", [20.0, 50.0, 87.0])
def test_exposure_learned_from_the_stripes_when_unknown(exposure_us):
    """exposure_us 0 (not in the camera file): the decoders' shared learner measures it from
    the stripes' edge ramps within a row plus the blur, and the ID is decoded."""
    from receiver.decode.exposure import ExposureLearner

    learner = ExposureLearner()
    rng = np.random.default_rng(int(exposure_us))
    dec = OokDecoder(RATE_HZ, ROW_US, 0.0, exposure_learner=learner)
    for prof, w in ook_frames(0x2468, RATE_HZ, ROW_US, exposure_us, 130, 40, rng,
                              gain=200.0, offset=15.0, noise=2.0, width_px=120):
        st = dec.step(prof, w)
    assert learner.exposure_rows * ROW_US == pytest.approx(exposure_us, abs=ROW_US + 2.0)
    assert st.led_id == 0x2468


def test_verdict_names_what_would_work():
    from receiver.decode.exposure import exposure_verdict

    ok, text = exposure_verdict(100.0, 20000.0)
    assert not ok and "2.00 chips" in text and "<= 90 us" in text and "<= 18.0 kHz" in text
    assert exposure_verdict(87.0, 20000.0)[0] and exposure_verdict(20.0, 20000.0)[0]
    assert not exposure_verdict(400.0, 5000.0)[0]


def _accumulate(frames):
    """(sums, weights, squares) per packet position of (soft chips, positions, weights) frames."""
    S, W, Q = np.zeros(54), np.zeros(54), np.zeros(54)
    for x, pos, w in frames:
        np.add.at(S, pos, w * x)
        np.add.at(W, pos, w)
        np.add.at(Q, pos, w * x * x)
    return S, W, Q


def test_soft_decision_margin_on_noise_and_misassembly():
    """Seeded Monte Carlo (the calibration of OokSettings.soft_min_z, smaller): accumulations
    of pure noise, and of a true packet with half of its frames misplaced by even shifts (a
    wrong assembly), never reach the acceptance margin with a wrong ID; a true packet seen at
    40 of 54 positions through noise is accepted."""
    from receiver.decode.ook import soft_decide
    from receiver.decode.settings import OOK_TUNING, OokSettings

    z_min, snr_min = OokSettings.soft_min_z, OOK_TUNING.soft_min_snr
    rng = np.random.default_rng(7)
    for trial in range(120):
        tid = int(rng.integers(0, 1 << 16))
        t = packet_template(tid)
        frames = []
        for _ in range(int(rng.integers(2, 8))):
            n, s = int(rng.integers(10, 30)), int(rng.integers(0, 54))
            pos = (s + np.arange(n)) % 54
            if trial % 2:
                x = rng.normal(0.0, 1.0, n)
            else:
                off = 0 if rng.uniform() < 0.5 else int(rng.choice([-10, -6, -4, -2, 2, 4, 6, 10]))
                x = t[(pos + off) % 54] + rng.normal(0.0, rng.uniform(0.2, 1.2), n)
            frames.append((np.clip(x, -2, 2), pos, rng.uniform(0.3, 1.0, n)))
        S, W, Q = _accumulate(frames)
        led_id, z, snr = soft_decide(S, W, Q)
        assert led_id == tid or z < z_min or snr < snr_min
        assert trial % 2 == 0 or z < z_min
    led_id = 0x7E57
    t = packet_template(led_id)
    seen = np.sort(rng.choice(54, 40, replace=False))
    frames = [(np.clip(t[seen] + rng.normal(0.0, 0.4, seen.size), -2, 2), seen, np.ones(seen.size))
              for _ in range(3)]
    got, z, snr = soft_decide(*_accumulate(frames))
    assert got == led_id and z >= z_min and snr >= snr_min
