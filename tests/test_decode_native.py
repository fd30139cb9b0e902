"""The compiled OOK kernels (receiver/decode/_ook.pyx) equal the pure numpy reference paths of
receiver.decode.ook / frameclock (which the rest of the suite also runs under OCCLOC_PURE=1):
bit for bit where the kernel repeats numpy's own summation order, to a stated tolerance where a
BLAS product's order differs (only the best shift and threshold decisions are taken there)."""

import numpy as np
import pytest

import receiver.decode.ook as ook
from receiver.core.native import load
from signals import ook_frames

K = load("receiver.decode._ook")
pytestmark = pytest.mark.skipif(K is None, reason="kernel not built / OCCLOC_PURE=1 (test_native.py checks the build)")

RATE, T_ROW, T_EXP = 20000.0, 15.0, 20.0


def _profiles(rng, n):
    """Random row profiles: striped (chips of a random period), pure noise and flat ones, float32
    and float64, with weights (float32 / float64, some rows empty) or without."""
    for _ in range(n):
        rows = int(rng.integers(5, 700))
        p0 = float(rng.uniform(1.5, 8.0))
        dt = (np.float32, np.float64)[int(rng.integers(2))]
        kind = rng.random()
        if kind < 0.7:
            chips = rng.integers(0, 2, rows + 2)
            prof = 100 + 120 * chips[(np.arange(rows) / p0).astype(int)] + rng.normal(0, 5, rows)
        elif kind < 0.9:
            prof = rng.uniform(0, 255, rows)
        else:
            prof = np.full(rows, 77.0)
        w = None
        if rng.random() < 0.8:
            w = np.maximum(rng.normal(50, 20, rows), 0).astype((np.float32, np.float64)[int(rng.integers(2))])
        yield prof.astype(dt), w, p0, float(rng.uniform(0.97, 1.03)), float(rng.uniform(0, 20))


def _frame_chips(monkeypatch, kernel, prof, w, p0, err, exp):
    monkeypatch.setattr(ook, "_k", kernel)
    d = ook.OokDecoder(RATE, 1e6 / (RATE * p0), exp)
    d._learner.period = p0 * err  # learned: the kernel's case
    soft, cw = d.frame_chips(prof, w)
    return soft, cw, d.last_start_row


def test_frame_chips_bit_identical(monkeypatch):
    rng = np.random.default_rng(5)
    nonempty = 0
    for prof, w, p0, err, exp in _profiles(rng, 1500):
        s1, c1, r1 = _frame_chips(monkeypatch, K, prof, w, p0, err, exp)
        s0, c0, r0 = _frame_chips(monkeypatch, None, prof, w, p0, err, exp)
        assert s1.dtype == s0.dtype == np.float64
        assert np.array_equal(s1, s0) and np.array_equal(c1, c0) and r1 == r0
        nonempty += s0.size > 0
    assert nonempty > 300  # the comparison covered real chips, not only rejected profiles


def test_trim_and_coherence_equal_pure():
    rng = np.random.default_rng(6)
    for prof, w, p0, err, exp in _profiles(rng, 500):
        if w is None:
            continue
        a, b = ook.trim_rows(w, w.size, 0.25)
        assert K.trim(w, 0.25) == (a, b)
        if b - a < 4:
            continue
        x = prof.astype(np.float64)[a:b]
        phasor = ook._grid_phasor(p0, 2 * x.size)
        _, phase, coh = ook.chip_grid(x, p0, segment_chips=0.0, phasor=phasor)
        kphase, kcoh, _, _ = K.frame_chips(prof, w, a, b, phasor, p0, exp, 8, 2.0)
        assert (kphase, kcoh) == (phase, coh)


def test_learned_decoding_identical(monkeypatch):
    """Whole decoders (shared period learner, many frames, noise) step to the same states."""
    rng = np.random.default_rng(11)
    frames = ook_frames(0xBEEF, RATE, T_ROW, T_EXP, 90, 40, rng, noise=4.0)
    states = []
    for kernel in (K, None):
        monkeypatch.setattr(ook, "_k", kernel)
        dec = ook.OokDecoder(RATE, T_ROW, T_EXP)
        states.append([(dec.step(p, w), dec.last_start_row, dec.acc.tobytes()) for p, w in frames])
    assert states[0] == states[1]
    assert states[0][-1][0].led_id == 0xBEEF
