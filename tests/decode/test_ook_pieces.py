"""Packets assembled from short pieces placed by the frame times (receiver.decode.pieces):
exactly integrated profiles of a small light at 10 kHz (8-11 chips a frame) with frame-start
jitter decode to the ID sent among the map's IDs; a light whose ID is not among them, and
noise, never yield an ID."""

from __future__ import annotations

import types

import numpy as np

from firmware_tx.schedule import make_schedule
from receiver.decode.ook import OokDecoder
from receiver.decode.pieces import PieceAssembler
from receiver.decode.ook import packet_template
from signals import pin_waveform, row_profile

RATE_HZ = 10000.0
ROW_US = 10.0
FPS = 30.0


def _run(led_id, candidates, seed, *, frames=45, n_rows=100, jitter_us=100.0, noise=2.0):
    rng = np.random.default_rng(seed)
    sch = make_schedule("ook", led_id, int(RATE_HZ))
    wave = pin_waveform(sch, 0)
    phase = rng.uniform(0.0, len(wave) / sch.tick_hz)
    dec = OokDecoder(RATE_HZ, ROW_US, 10.0, candidates=np.asarray(candidates))
    st = None
    for k in range(frames):
        y0 = 300 + int(10 * np.sin(k / 7.0))  # the image moves a little
        t_true = k / FPS + rng.normal(0.0, jitter_us * 1e-6)
        prof, w = row_profile(wave, sch.tick_hz, ROW_US, 10.0, n_rows, phase + t_true + y0 * ROW_US * 1e-6,
                              gain=180.0, offset=15.0, noise=noise, rng=rng, width_px=90)
        st = dec.step(prof, w, k / FPS, y0=y0)
        if st.led_id is not None:
            break
    return st.led_id, dec


def test_short_pieces_decode_among_the_map_ids():
    """Six small lights (8-11 chips a frame, 100 us rms frame jitter), 60 candidates: none
    decodes wrongly, and some decode within 90 frames (the acceptance is strict)."""
    rng = np.random.default_rng(5)
    got = []
    for seed in range(6):
        cands = [int(v) for v in rng.choice(1 << 16, 60, replace=False)]
        led_id = cands[seed * 7]
        found, dec = _run(led_id, cands, seed, frames=90)
        assert dec.pieces is not None and dec.pieces.pieces
        assert found in (None, led_id)
        got.append(found == led_id)
    assert sum(got) >= 2


def test_a_light_not_in_the_map_is_never_reported():
    rng = np.random.default_rng(9)
    for seed in range(4):
        cands = [int(v) for v in rng.choice(1 << 16, 60, replace=False)]
        led_id = int(rng.integers(1 << 16))
        while led_id in cands:
            led_id = int(rng.integers(1 << 16))
        found, _ = _run(led_id, cands, 100 + seed, frames=90)
        assert found is None


def test_pieces_margin_monte_carlo():
    """Seeded Monte Carlo of the ML choice itself (a small version of the calibration in
    docs/ook-exposure.md): pieces of 5-13 chips with 100 us rms jitter from lights in and out of the
    candidates; a wrong best ID never passes the acceptance gap."""
    from receiver.decode.settings import OOK_TUNING, OokSettings

    rng = np.random.default_rng(2)
    for trial in range(16):
        K = int(rng.choice([20, 100]))
        cands = rng.choice(1 << 16, K, replace=False)
        outside = trial % 2 == 0
        tid = int(rng.integers(1 << 16)) if outside else int(cands[rng.integers(K)])
        t = packet_template(tid)
        rate = float(rng.choice([5000.0, 10000.0]))
        pa = PieceAssembler(cands, np.stack([packet_template(int(i)) for i in cands]),
                            jitter_chips=int(np.ceil(OokSettings.pieces_jitter_us * rate * 1e-6)), history=30,
                            min_frames=6, min_corr=OOK_TUNING.pieces_min_corr, min_gap=OOK_TUNING.pieces_min_gap,
                            shift_penalty=OOK_TUNING.pieces_shift_penalty)
        phi, sd = rng.uniform(0, 54), rng.uniform(0.1, 0.8)
        for f in range(30):
            n = int(rng.integers(5, 14))
            q = rate * f / FPS + rng.uniform(0, 40)
            s = int(np.floor(q + phi + rng.normal(0, 100e-6) * rate + 0.5)) % 54
            pa.add(t[(s + np.arange(n)) % 54] + rng.normal(0, sd, n), np.ones(n), q)
            got = pa.decide()
            assert got is None or got == tid


def test_frame_jitter_is_the_other_lights_consensus():
    """A light's pieces are placed by the jitter the *other* lights measured in that frame: the
    median of the largest agreeing group; a tie between two disagreeing lights gives none."""
    from receiver.decode.pieces import FrameJitter

    fj = FrameJitter(frames=3)
    assert fj.estimate(0.0, 1) is None
    fj.post(0.0, 1, 0.4)
    assert fj.estimate(0.0, 1) is None          # its own measurement never places its pieces
    assert abs(fj.estimate(0.0, 2) - 0.4) < 1e-9
    fj.post(0.0, 2, 1.9)
    assert fj.estimate(0.0, 3) is None          # 0.4 against 1.9: no majority
    fj.post(0.0, 3, 0.6)
    fj.post(0.0, 4, 53.8)                       # -0.2 chips, across the packet's wrap
    assert abs(fj.estimate(0.0, 5) - 0.4) < 1e-9
    assert abs(fj.estimate(0.0, 2) - 0.4) < 1e-9
    for t in (1.0, 2.0, 3.0):                   # only the last `frames` frames are kept
        fj.post(t, 1, 0.0)
    assert fj.estimate(0.0, 5) is None and abs(fj.estimate(3.0, 5)) < 1e-9


def test_lights_of_one_frame_measure_its_jitter_for_one_another():
    """Five small lights at once (10 chips a frame, 100 us rms frame jitter, crystals +-50 ppm,
    two of five on average outside the map): the pieces they share the frame times of decode
    most mapped lights, and no light is ever given a wrong ID (tests/decode/pieces_mc.py)."""
    from pieces_mc import BY_NAME, monte_carlo

    r = monte_carlo(BY_NAME["10k-100rows"], trials=3, seed=4, frames=45)
    assert r["wrong"] == []
    assert r["mapped"] >= 5 and r["right"] >= 0.6 * r["mapped"]


def test_unmapped_lights_sharing_frames_are_never_reported():
    """Lights none of which is in the map measure one another's jitter (their best hypotheses
    are wrong, yet strong enough to post): still no ID."""
    from pieces_mc import BY_NAME, monte_carlo

    r = monte_carlo(BY_NAME["5k-120rows-unmapped"], trials=2, seed=6, frames=60)
    assert r["mapped"] == 0 and r["wrong"] == []


def test_the_chip_verdict_names_the_frames_an_id_needs():
    from receiver.decode.pieces import chips_verdict

    ok, text = chips_verdict(6.0, 5000.0, max_chips=16, min_frames=6, mapped=True)
    assert ok and "6 chips a frame" in text and "no single frame holds a packet" in text
    assert "at least 9 frames" in text and "> 13 kHz" in text
    ok, text = chips_verdict(11.0, 10000.0, max_chips=16, min_frames=6, mapped=False)
    assert not ok and "no ID can be read" in text
    ok, text = chips_verdict(30.0, 20000.0, max_chips=16, min_frames=6, mapped=True)
    assert ok and "at least 2 frames" in text
    ok, text = chips_verdict(90.0, 20000.0, max_chips=16, min_frames=6, mapped=True)
    assert ok and "one frame holds a whole packet" in text


def test_piece_correlations_are_the_circular_cross_correlations():
    """A piece's correlation with every candidate at every packet position is the circular
    cross-correlation of the piece with each packet (numpy's FFT as the oracle), and its
    windowed best is the best of the shifted correlations less the penalty per chip away."""
    from receiver.decode.pieces import _windowed

    rng = np.random.default_rng(7)
    for _ in range(60):
        k, n = int(rng.integers(1, 40)), int(rng.integers(2, 17))
        templates = rng.choice([-1.0, 1.0], size=(k, 54)).astype(np.float32)
        a = PieceAssembler(np.arange(k), templates, jitter_chips=int(rng.integers(0, 4)), history=8,
                           min_frames=2, min_corr=0.5, min_gap=0.1)
        x = rng.uniform(-1, 1, n).astype(np.float32)
        p = types.SimpleNamespace(x=x, n=n, den=float(np.abs(x).sum()), slot=0)
        a._correlate(p)
        xp = np.zeros(54)
        xp[:n] = x
        want = np.real(np.fft.ifft(np.conj(np.fft.fft(xp))[None, :] * np.fft.fft(templates, axis=1), axis=1)) / p.den
        assert np.allclose(p.corr, want, atol=1e-5)
        for half, pen in ((a.jitter_chips, a.shift_penalty), (2, 0.3)):
            best = np.max([np.roll(want, -d, axis=1) - pen * abs(d) for d in range(-half, half + 1)], axis=0)
            assert np.allclose(_windowed(p.corr, half, pen), best, atol=1e-5)


def test_frame_jitter_is_wanted_only_while_a_light_without_id_shows_pieces():
    """Lights whose ID is known measure the frames' jitter only while some light without its ID
    asked within the last `want_frames` frames measured; the frames kept are the newest stamps,
    whatever order they are posted in."""
    from receiver.decode.pieces import FrameJitter

    fj = FrameJitter(frames=4, want_frames=2)
    assert not fj.wanted()
    fj.want()
    assert fj.wanted()
    for t in (1.0, 2.0):
        fj.post(t, 1, 0.0)
    assert fj.wanted()
    fj.post(3.0, 1, 0.0)
    assert not fj.wanted()
    fj.post(3.0, 2, 0.0)        # a frame already measured does not count again
    assert not fj.wanted()
    for t in (4.0, 5.0, 0.5):   # a late post of an old frame does not push out a newer one
        fj.post(t, 1, 0.0)
    assert sorted(fj.by_frame) == [2.0, 3.0, 4.0, 5.0]


def test_pieces_settings_that_mean_nothing_are_refused():
    import pytest

    from receiver.core.errors import InputError
    from receiver.core.settings import settings_from_json
    from receiver.decode.settings import OokSettings

    for name, value in (("pieces_jitter_us", -1.0), ("pieces_jitter_us", 1e6)):
        with pytest.raises(InputError):
            settings_from_json(OokSettings, {name: value})
    a = PieceAssembler(np.arange(2), np.ones((2, 54), np.float32), jitter_chips=500, history=4,
                       min_frames=2, min_corr=0.5, min_gap=0.1)
    assert a.jitter_chips == 26
