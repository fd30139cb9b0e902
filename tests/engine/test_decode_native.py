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
pytestmark = pytest.mark.skipif(K is None, reason="kernel not built / OCCLOC_PURE=1 (tests/engine/test_native.py checks the build)")

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


def _softs(rng, n):
    """Soft-chip arrays like frame_chips gives (+-2 clipped, some near 0), of many lengths."""
    for _ in range(n):
        size = int(rng.integers(0, 140))
        yield np.clip(rng.choice([-1.0, 1.0], size) * rng.uniform(0.0, 2.5, size), -2.0, 2.0)


def test_find_sync_and_line_predict_bit_identical(monkeypatch):
    rng = np.random.default_rng(21)
    tpl = ook.packet_template(0xBEEF)
    cases = list(_softs(rng, 400))
    for _ in range(200):  # with real syncs, once or a packet apart (or not)
        x = np.tile(tpl, 3)[int(rng.integers(54)):][:int(rng.integers(6, 140))] * rng.uniform(0.2, 1.5)
        cases.append(x + rng.normal(0, 0.3, x.size))
    obs = [[(int(k), float(v)) for k, v in zip(np.cumsum(rng.integers(1, 3, n)), rng.normal(0, 30, n))]
           for n in rng.integers(1, 20, 300)]
    got = {}
    for kernel in (K, None):
        monkeypatch.setattr(ook, "_k", kernel)
        got[kernel is None] = ([ook.find_sync(x, sync_margin=0.3) for x in cases],
                               [ook.line_predict(o, o[-1][0] + 1.5, 12) for o in obs])
    assert got[False] == got[True]
    assert sum(s is not None for s, _ in got[True][0]) > 100


def test_accumulator_kernels_equal_pure():
    """add4 / decode_acc exactly; the correlations (align, best_two, corr_at,
    overlap_corr) to 1e-12 with the same decisions."""
    rng = np.random.default_rng(22)
    dec0, dec1 = ook.OokDecoder(), ook.OokDecoder()
    table = ook.crc8_table()
    for trial, soft in enumerate(_softs(rng, 400)):
        cw = rng.uniform(0.2, 1.0, soft.size)
        shift = int(rng.integers(-60, 120))
        trusted, timed = bool(rng.integers(2)), bool(rng.integers(2))
        # pure _add / decay on dec0, kernel on dec1 (the same starting state)
        for d in (dec0, dec1):
            d.anchored = bool(rng.integers(2)) if d is dec0 else dec0.anchored
        pos = ook._cyclic_index(soft.size)[shift % 54]
        dec0.acc += np.bincount(pos, cw * soft, 54)
        w = np.bincount(pos, cw, 54)
        dec0.acc_w += w
        if trusted:
            dec0.trust_w += w
        elif timed:
            dec0.timed_w += w
        K.add4(dec1._acc4, 2 if trusted else 3 if timed else -1, soft, cw, shift)
        for a in ("acc", "acc_w", "trust_w", "timed_w"):
            assert getattr(dec0, a).tobytes() == getattr(dec1, a).tobytes()
        known = dec0.acc_w > 0
        ref = (ook.decode_packet(dec0._mean_packet(known), min_margin=0.25)
               if known[6:].all() else None)
        assert K.decode_acc(dec1.acc, dec1.acc_w, 0.25, table) == ref
        if soft.size >= 6:
            monkeypatch_k = ook._k
            try:
                ook._k = None
                ref_shift = dec0._align(soft)
                ref_complete = dec0._last_align_complete
            finally:
                ook._k = monkeypatch_k
            assert K.align(dec1.acc, dec1.acc_w, soft, dec1.anchored, 8, 2.0, 0.7, 0.25) == (ref_shift, ref_complete)
        tpl = ook.packet_template(int(rng.integers(1 << 16)))
        x = np.clip(soft, -1, 1)
        den = np.abs(x).sum()
        r = K.best_two(tpl, soft)
        if den > 0:
            corr = (tpl[ook._cyclic_index(x.size)] @ x) / den
            assert r[0] == int(corr.argmax()) or corr.max() - corr[r[0]] < 1e-12
            assert abs(r[1] - corr.max()) < 1e-12 and abs(r[2] - np.sort(corr)[-2]) < 1e-12
            c = K.corr_at(tpl, soft, shift)
            assert abs(c - corr[shift % 54]) < 1e-12
        else:
            assert r is None and K.corr_at(tpl, soft, shift) is None
        if trial % 50 == 49:
            K.decay4(dec1._acc4, 0.9)
            for a in ("acc", "acc_w", "trust_w", "timed_w"):
                setattr(dec0, a, getattr(dec0, a) * 0.9)
                assert getattr(dec0, a).tobytes() == getattr(dec1, a).tobytes()


def test_small_blob_decoders_identical(monkeypatch):
    """Short profiles (a few chips a frame: cyclic alignment, pending frames, rotation)."""
    rng = np.random.default_rng(12)
    decoded = 0
    for led_id, rows in ((0x002A, 70), (0x1234, 90), (0xFFFF, 80), (0xBEEF, 100)):
        frames = ook_frames(led_id, RATE, T_ROW, T_EXP, rows, 120, rng, noise=3.0)
        states = []
        for kernel in (K, None):
            monkeypatch.setattr(ook, "_k", kernel)
            dec = ook.OokDecoder(RATE, T_ROW, T_EXP)
            states.append([(dec.step(p, w), dec.acc.tobytes(), dec.anchored, len(dec.pending)) for p, w in frames])
        assert states[0] == states[1]
        assert {s[0].led_id for s in states[0]} <= {None, led_id}
        decoded += states[0][-1][0].led_id == led_id
    assert decoded >= 2


def _run_lines(spec, n):
    import json
    from receiver.cli.bench import load_case, whole_receiver
    from receiver.io.output import frame_line
    cam, led_map, frames, still = load_case(spec, n)
    rx = whole_receiver(cam, led_map, still=still)
    out = []
    for f in frames:
        d = json.loads(frame_line(rx.process(f)))
        d.pop("latency_ms")
        out.append(d)
    return out


@pytest.mark.parametrize("name", ["indoor-static", "indoor-sparse"])
def test_recording_output_identical(monkeypatch, name):
    """The whole receiver (frame clock, decoders, positioning) writes the same lines on a
    bundled recording with the kernels as with the pure paths."""
    import pathlib
    spec = str(pathlib.Path(__file__).resolve().parents[2] / "recordings" / name)
    fast = _run_lines(spec, 40)
    monkeypatch.setattr(ook, "_k", None)
    assert _run_lines(spec, 40) == fast
    assert sum(o["id"] is not None for d in fast for o in d["leds"]) > 20


def test_best_cyclic_match_other_template_length_takes_the_reference_path():
    """The kernel reads exactly 54 template chips; a template of another length must not let it
    read past the array (it returned a number from beyond it): both paths now agree."""
    import numpy as np
    import pytest
    from receiver.decode import ook
    with pytest.raises(IndexError):
        ook.best_cyclic_match(np.ones(40), np.ones(10))
    soft = np.random.default_rng(3).uniform(-1, 1, 40)
    tpl = ook.packet_template(0x2A)
    assert ook.best_cyclic_match(soft, tpl) == pytest.approx(
        float(max((np.roll(tpl, -k)[np.arange(40) % 54] @ soft) for k in range(54)) / np.abs(soft).sum()), abs=1e-12)


def test_fused_kernels_are_called_by_their_specialisations_and_any_nonzero_is_numpys():
    """The decoder calls frame_chips / trim by their dtype specialisation (no fused dispatch per
    call): every float32 / float64 combination is there and gives the dispatcher's numbers; the
    accumulator's emptiness test is numpy's any() (NaN counts as set)."""
    assert set(ook._FRAME_CHIPS) == {(x, w) for x in "fd" for w in "fd"} and set(ook._TRIM) == {"f", "d"}
    rng = np.random.default_rng(8)
    for prof, w, p0, err, exp in _profiles(rng, 200):
        if w is None:
            continue
        wc = w.dtype.char
        assert ook._TRIM[wc](w, 0.3) == K.trim(w, 0.3)
        a, b = K.trim(w, 0.3)
        if b - a < 4:
            continue
        phasor = ook._grid_phasor(p0, 2 * (b - a))
        r1 = ook._FRAME_CHIPS[prof.dtype.char, wc](prof, w, a, b, phasor, p0, exp, 8, 0.0)
        r0 = K.frame_chips(prof, w, a, b, phasor, p0, exp, 8, 0.0)
        assert r1[:2] == r0[:2] and np.array_equal(r1[2], r0[2]) and np.array_equal(r1[3], r0[3])
    for acc_w in (np.zeros(54), np.eye(1, 54, 53).ravel(), np.full(54, np.nan), np.full(54, -0.0),
                  rng.uniform(0, 1, 54) * (rng.random(54) < 0.1)):
        assert K.any_nonzero(acc_w) is bool(acc_w.any())
