"""Packets assembled from short pieces placed by the frame times (receiver.decode.pieces):
exactly integrated profiles of a small light at 10 kHz (8-11 chips a frame) with frame-start
jitter decode to the ID sent among the map's IDs; a light whose ID is not among them, and
noise, never yield an ID."""

from __future__ import annotations

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
    OokSettings): pieces of 5-13 chips with 100 us rms jitter from lights in and out of the
    candidates; a wrong best ID never passes the acceptance gap."""
    from receiver.decode.settings import OokSettings

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
                            min_frames=6, min_corr=OokSettings.pieces_min_corr, min_gap=OokSettings.pieces_min_gap,
                            shift_penalty=OokSettings.pieces_shift_penalty)
        phi, sd = rng.uniform(0, 54), rng.uniform(0.1, 0.8)
        for f in range(30):
            n = int(rng.integers(5, 14))
            q = rate * f / FPS + rng.uniform(0, 40)
            s = int(np.floor(q + phi + rng.normal(0, 100e-6) * rate + 0.5)) % 54
            pa.add(t[(s + np.arange(n)) % 54] + rng.normal(0, sd, n), np.ones(n), q)
            got = pa.decide()
            assert got is None or got == tid


def _windowed_reference(a: PieceAssembler, x: np.ndarray) -> np.ndarray:
    """A piece's (K, 54) windowed correlations written plainly: for each packet position s,
    sum_k x_k T[:, (s + k) % 54] / sum |x| in float32, added in chip order, then the best of
    the positions within the jitter window less shift_penalty per chip away."""
    corr = np.zeros((a.ids.size, 54), np.float32)
    for k in range(x.size):
        corr += x[k] * a._wrapped[:, k:k + 54]
    corr /= float(np.abs(x).sum())
    best = corr.copy()
    for d in range(1, a.jitter + 1):
        np.maximum(best, np.roll(corr, -d, axis=1) - a.shift_penalty * d, out=best)
        np.maximum(best, np.roll(corr, d, axis=1) - a.shift_penalty * d, out=best)
    return best


def test_piece_correlations_equal_the_plain_sums():
    """The vectorised correlations of a piece with every candidate at every place are the
    plain loop's numbers exactly (same float32 additions in the same order), for 1-300
    candidates, jitter windows of 0-5 chips and pieces of 2-16 chips."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        k, jitter, n = int(rng.integers(1, 300)), int(rng.integers(0, 6)), int(rng.integers(2, 17))
        ids = rng.choice(1 << 16, k, replace=False)
        a = PieceAssembler(ids, np.array([packet_template(int(i)) for i in ids]), jitter_chips=jitter,
                           history=30, min_frames=1, min_corr=0.85, min_gap=0.3)
        x = (np.clip(rng.normal(0.0, 1.0, n), -1.0, 1.0) * rng.uniform(0.1, 1.0, n)).astype(np.float32)
        a.add(x, np.ones(n), float(rng.uniform(0.0, 54.0)))
        got = a.pieces[-1][0]
        assert got.dtype == np.float32
        assert np.array_equal(got, _windowed_reference(a, x))
