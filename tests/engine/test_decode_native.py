"""The compiled OOK kernels (receiver/decode/_ook.pyx), the decoder's one implementation of its
accumulator, alignment, packet decision and timing checks, and of the frame's chips once the
period is learned: the chips against the numpy chip grid and soft chips of an unlearned decoder
(bit for bit: the kernel repeats numpy's summation order), the rest against known packets and
numpy / OpenCV-free definitions (correlations to 1e-12 with the same decisions)."""

import numpy as np
import pytest

import receiver.decode.ook as ook
from receiver.core.native import require
from signals import ook_frames

K = require("receiver.decode._ook")

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


def _numpy_chips(prof, w, period, exp, min_row_frac, min_coherence):
    """The frame's chips at a learned period by the numpy functions an unlearned decoder runs
    (trim_rows, chip_grid without refinement, soft_chips): (soft, weights, start row)."""
    x = np.asarray(prof, dtype=np.float64)
    a, b = ook.trim_rows(w, x.size, min_row_frac)
    x = x[a:b]
    if x.size < 4 * period:
        return np.zeros(0), np.zeros(0), None
    ww = None if w is None else np.asarray(w, dtype=np.float64)[a:b]
    per, phase, coh = ook.chip_grid(x, period, segment_chips=0.0, phasor=ook._grid_phasor(period, 2 * x.size))
    if coh < min_coherence:
        return np.zeros(0), np.zeros(0), None
    soft, cw = ook.soft_chips(x, ww, per, phase, exposure_rows=exp, norm_chips=8)
    return soft, cw, a + phase


def test_frame_chips_bit_identical():
    rng = np.random.default_rng(5)
    nonempty = 0
    for prof, w, p0, err, exp in _profiles(rng, 1500):
        d = ook.OokDecoder(RATE, 1e6 / (RATE * p0), exp)
        d._learner.period = p0 * err  # learned: the kernel's case
        s1, c1 = d.frame_chips(prof, w)
        s0, c0, r0 = _numpy_chips(prof, w, p0 * err, d.exposure_rows, d.min_row_frac, d.min_coherence)
        assert s1.dtype == s0.dtype == np.float64
        assert np.array_equal(s1, s0) and np.array_equal(c1, c0)
        assert d.last_start_row == r0 or (s0.size == 0 and r0 is None)
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


def test_learned_decoding_decodes_the_packet():
    """A whole decoder (many frames, noise) decodes the ID and reports no other."""
    rng = np.random.default_rng(11)
    frames = ook_frames(0xBEEF, RATE, T_ROW, T_EXP, 90, 40, rng, noise=4.0)
    dec = ook.OokDecoder(RATE, T_ROW, T_EXP)
    ids = [dec.step(p, w).led_id for p, w in frames]
    assert ids[-1] == 0xBEEF and set(ids) <= {None, 0xBEEF}


def _softs(rng, n):
    """Soft-chip arrays like frame_chips gives (+-2 clipped, some near 0), of many lengths."""
    for _ in range(n):
        size = int(rng.integers(0, 140))
        yield np.clip(rng.choice([-1.0, 1.0], size) * rng.uniform(0.0, 2.5, size), -2.0, 2.0)


def test_find_sync_equals_numpy_and_line_predict_is_the_least_squares_line():
    """find_sync: the kernel (contiguous float64) gives the numpy path's answer (a strided view);
    line_predict: the least-squares line's value (np.polyfit) to 1e-9."""
    rng = np.random.default_rng(21)
    tpl = ook.packet_template(0xBEEF)
    cases = list(_softs(rng, 400))
    for _ in range(200):  # with real syncs, once or a packet apart (or not)
        x = np.tile(tpl, 3)[int(rng.integers(54)):][:int(rng.integers(6, 140))] * rng.uniform(0.2, 1.5)
        cases.append(x + rng.normal(0, 0.3, x.size))
    got = [ook.find_sync(x, sync_margin=0.3) for x in cases]
    assert got == [ook.find_sync(np.repeat(x, 2)[::2], sync_margin=0.3) for x in cases]
    assert sum(s is not None for s, _ in got) > 100
    for n in rng.integers(1, 20, 300):
        obs = [(int(k), float(v)) for k, v in zip(np.cumsum(rng.integers(1, 3, n)), rng.normal(0, 30, n))]
        pts = obs[-12:]
        k = obs[-1][0] + 1.5
        if len(pts) == 1 or pts[-1][0] - pts[0][0] < 2:
            want = pts[-1][1]
        else:
            want = float(np.polyval(np.polyfit([p[0] for p in pts], [p[1] for p in pts], 1), k))
        assert ook.line_predict(obs, k, 12) == pytest.approx(want, abs=1e-9, rel=1e-9)


def test_decode_acc_reads_known_packets():
    """decode_acc: a packet accumulated from a known ID's template decodes to it (confidence 1);
    a flipped data pair fails the CRC; an unknown data chip gives no decision."""
    rng = np.random.default_rng(22)
    table = ook.crc8_table()
    for led_id in rng.integers(0, 1 << 16, 200).tolist():
        w = rng.uniform(0.2, 3.0, 54)
        acc = ook.packet_template(led_id) * w
        assert K.decode_acc(acc, w, 0.25, table) == (led_id, 1.0)
        bit = int(rng.integers(24))
        bad = acc.copy()
        bad[[6 + 2 * bit, 7 + 2 * bit]] *= -1
        assert K.decode_acc(bad, w, 0.25, table)[0] is None
        w2 = w.copy()
        w2[int(rng.integers(6, 54))] = 0.0
        assert K.decode_acc(acc, w2, 0.25, table) is None


def test_align_finds_the_shift_of_a_cut_from_the_packet():
    """align: a frame cut from the accumulated packet at offset o (chip k = packet chip o + k),
    with noise, aligns at shift o, complete when every shift overlapped enough known chips; a
    frame of noise does not align."""
    rng = np.random.default_rng(23)
    aligned = noise_aligned = 0
    for _ in range(300):
        tpl = ook.packet_template(int(rng.integers(1 << 16)))
        w = rng.uniform(0.5, 2.0, 54)
        o, n = int(rng.integers(54)), int(rng.integers(20, 60))
        x = np.clip(tpl[(o + np.arange(n)) % 54] * rng.uniform(0.5, 1.5, n) + rng.normal(0, 0.2, n), -2, 2)
        shift, complete = K.align(tpl * w, w, x, True, 8, 2.0, 0.7, 0.25)
        assert shift in (None, o)
        aligned += shift == o
        assert complete
        noise_aligned += K.align(tpl * w, w, rng.normal(0, 1, n), True, 8, 2.0, 0.7, 0.25)[0] is not None
    assert aligned > 250 and noise_aligned < 15


def test_template_correlations_are_the_normalised_products():
    """best_two / corr_at: sum(t[(k + shift) % 54] clip(s_k)) / sum |clip(s_k)| at the best and
    second shift and at a given one, to 1e-12; None for an all-zero frame."""
    rng = np.random.default_rng(24)
    for soft in _softs(rng, 400):
        tpl = ook.packet_template(int(rng.integers(1 << 16)))
        shift = int(rng.integers(-60, 120))
        x = np.clip(soft, -1, 1)
        den = np.abs(x).sum()
        r = K.best_two(tpl, soft)
        if den > 0:
            corr = (tpl[ook._cyclic_index(x.size)] @ x) / den
            assert r[0] == int(corr.argmax()) or corr.max() - corr[r[0]] < 1e-12
            assert abs(r[1] - corr.max()) < 1e-12 and abs(r[2] - np.sort(corr)[-2]) < 1e-12
            assert abs(K.corr_at(tpl, soft, shift) - corr[shift % 54]) < 1e-12
        else:
            assert r is None and K.corr_at(tpl, soft, shift) is None


def test_small_blob_decoders_decode():
    """Short profiles (a few chips a frame: cyclic alignment, pending frames, rotation): the
    decoders report their own ID or nothing, and most decode."""
    rng = np.random.default_rng(12)
    decoded = 0
    for led_id, rows in ((0x002A, 70), (0x1234, 90), (0xFFFF, 80), (0xBEEF, 100)):
        frames = ook_frames(led_id, RATE, T_ROW, T_EXP, rows, 120, rng, noise=3.0)
        dec = ook.OokDecoder(RATE, T_ROW, T_EXP)
        ids = [dec.step(p, w).led_id for p, w in frames]
        assert set(ids) <= {None, led_id}
        decoded += ids[-1] == led_id
    assert decoded >= 2


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
