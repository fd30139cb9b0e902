"""Packets assembled from short pieces placed by the frame times (receiver.decode.pieces):
exactly integrated profiles of a small light at 10 kHz (8-11 chips a frame) with frame-start
jitter decode to the ID sent among the map's IDs; a light whose ID is not among them, and
noise, never yield an ID."""

from __future__ import annotations

import types

import numpy as np

from firmware_tx.schedule import make_schedule
from receiver.decode.ook import OokDecoder, candidate_tables
from receiver.decode.pieces import Candidates, PieceAssembler
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
    dec = OokDecoder(RATE_HZ, ROW_US, 10.0,
                     candidates=candidates if isinstance(candidates, Candidates) else np.asarray(candidates))
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


def test_shared_candidate_tables_decide_as_the_ids_do():
    """Decoders sharing one `Candidates` (as DecodePolicy gives every light) decide frame by
    frame as decoders given the ID array each, and leave the shared tables unchanged."""
    rng = np.random.default_rng(5)
    cands = [int(v) for v in rng.choice(1 << 16, 60, replace=False)]
    shared = candidate_tables(np.asarray(cands, np.int64))
    wrapped = shared.wrapped.copy()
    decided = 0
    for seed in range(4):
        led_id = cands[seed * 7]
        found_ids, dec_ids = _run(led_id, cands, seed, frames=90)
        found_shared, dec_shared = _run(led_id, shared, seed, frames=90)
        assert dec_shared.pieces._wrapped is shared.wrapped
        assert found_shared == found_ids and dec_shared.frames == dec_ids.frames
        assert dec_shared.pieces.score == dec_ids.pieces.score and dec_shared.pieces.added == dec_ids.pieces.added
        decided += found_ids is not None
    assert decided >= 1
    assert np.array_equal(shared.wrapped, wrapped)


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
                            min_frames=6, min_corr=OOK_TUNING.pieces_min_corr, min_agree=OOK_TUNING.pieces_min_agree,
                            min_z=OOK_TUNING.pieces_min_z,
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


def test_lights_given_ids_by_the_pose_are_never_given_a_wrong_one():
    """Each light also given one map ID as the pose's (tests/decode/pieces_mc.py `near`): lights
    outside the map given a map ID, and mapped lights given another one's, get no ID; mapped
    lights given their own decode, none wrongly."""
    from pieces_mc import BY_NAME, monte_carlo

    r = monte_carlo(BY_NAME["5k-120rows-unmapped"], trials=2, seed=6, frames=60, near=1, near_wrong=1.0)
    assert r["mapped"] == 0 and r["wrong"] == []
    r = monte_carlo(BY_NAME["5k-120rows"], trials=3, seed=4, frames=60, near=1, near_wrong=0.5)
    assert r["wrong"] == [] and r["right"] >= 0.6 * r["mapped"]


def test_the_chip_verdict_names_the_frames_an_id_needs():
    from receiver.decode.pieces import chips_verdict

    ok, text = chips_verdict(6.0, 5000.0, max_chips=16, min_frames=6, mapped=True)
    assert ok and "6 chips a frame" in text and "no single frame holds a packet" in text
    assert "at least 8 frames" in text and "> 13 kHz" in text  # 48 data chips, 6 a frame
    ok, text = chips_verdict(11.0, 10000.0, max_chips=16, min_frames=6, mapped=False)
    assert not ok and "no ID can be read" in text
    ok, text = chips_verdict(30.0, 20000.0, max_chips=16, min_frames=6, mapped=True)
    assert ok and "at least 2 frames" in text
    ok, text = chips_verdict(90.0, 20000.0, max_chips=16, min_frames=6, mapped=True)
    assert ok and "one frame holds a whole packet" in text


def _fft_best(x, templates, half, penalty):
    """numpy's FFT oracle: a piece's circular cross-correlation with each packet over its
    weight, and its best within +-half positions less penalty per position away."""
    xp = np.zeros(54)
    xp[:x.size] = x
    corr = np.real(np.fft.ifft(np.conj(np.fft.fft(xp))[None, :] * np.fft.fft(templates, axis=1), axis=1))
    corr /= np.abs(x).sum()
    return corr, np.max([np.roll(corr, -d, axis=1) - penalty * abs(d) for d in range(-half, half + 1)], axis=0)


def test_piece_correlations_are_the_circular_cross_correlations():
    """A piece's correlation with every candidate at every packet position is the circular
    cross-correlation of the piece with each packet (numpy's FFT as the oracle), and its
    windowed best (wide: +-jitter_chips, shift_penalty; narrow: +-1, timed_penalty) is the
    best of the shifted correlations less the penalty per chip away."""
    rng = np.random.default_rng(7)
    for _ in range(60):
        k, n = int(rng.integers(1, 40)), int(rng.integers(2, 17))
        templates = rng.choice([-1.0, 1.0], size=(k, 54)).astype(np.float32)
        a = PieceAssembler(np.arange(k), templates, jitter_chips=int(rng.integers(0, 4)), history=8,
                           min_frames=2, min_corr=0.5, min_agree=0.5, min_z=1.0, shift_penalty=float(rng.uniform(0, 0.5)),
                           timed_penalty=float(rng.uniform(0, 2)))
        x = rng.uniform(-1, 1, n).astype(np.float32)
        slot = int(rng.integers(0, 8))  # (history 8: slots 0-7)
        a._correlate(types.SimpleNamespace(x=x, n=n, den=float(np.abs(x).sum()), slot=slot))
        want, wide = _fft_best(x, templates, a.jitter_chips, a.shift_penalty)
        _, narrow = _fft_best(x, templates, min(1, a.jitter_chips), a.timed_penalty)
        assert np.allclose(a._corr[slot], want, atol=1e-5)
        for w, best in ((0, wide), (1, narrow)):
            rep = a._rep[w, slot]  # each position's best repeated for its 4 phases, twice round
            assert np.allclose(rep[:, :216:4], best, atol=1e-5)
            assert np.array_equal(rep, np.tile(np.repeat(rep[:, :216:4], 4, axis=1), 2))
    import pytest

    with pytest.raises(IndexError):  # a slot outside the tables is refused, never written
        a._correlate(types.SimpleNamespace(x=x, n=n, den=float(np.abs(x).sum()), slot=8))


def test_the_likelihood_table_is_the_sum_of_the_pieces_terms():
    """After pieces come and go (history 5) and their frames' jitter is measured, moved and
    restated, the table holds exactly the live pieces' terms: for every candidate and phase phi,
    the sum over pieces of weight times its best correlation (FFT oracle) at position
    floor(qq + phi + 1/2) % 54, qq its packet time plus the jitter when measured (narrow window)
    or its timestamp's place (wide); and the decision is the table's argmax."""
    from receiver.decode.pieces import FrameJitter

    rng = np.random.default_rng(11)
    for trial in range(12):
        k = int(rng.integers(2, 9))
        templates = rng.choice([-1.0, 1.0], size=(k, 54)).astype(np.float32)
        fj = FrameJitter(frames=8)
        a = PieceAssembler(np.arange(k) + 100, templates, jitter_chips=int(rng.integers(1, 4)), history=5,
                           min_frames=2, min_corr=0.99, min_agree=0.9, min_z=9.0, jitter=fj, timed_penalty=0.7)
        kept = []
        for f in range(14):
            n = int(rng.integers(3, 15))
            soft, cw, q = rng.uniform(-1.5, 1.5, n), rng.uniform(0.1, 1, n), float(rng.uniform(-100, 100))
            a.add(soft, cw, q, float(f))
            kept = (kept + [(f, q % 54, (np.clip(soft, -1, 1) * cw).astype(np.float32))])[-5:]
            for g in rng.choice(f + 1, 3):  # other lights measure (and restate) frames' jitter
                fj.post(float(g), -1, float(rng.uniform(-1.5, 1.5)))
            if a.decide() is None and len(kept) < 2:
                continue
            phis = np.arange(216) / 4
            ll = np.zeros((k, 216))
            for g, qf, x in kept:
                j = fj.estimate(float(g), a.key)
                qq = qf if j is None else qf + j
                best = _fft_best(x, templates, a.jitter_chips if j is None else 1, 0.2 if j is None else 0.7)[1]
                ll += np.abs(x).sum() * best[:, np.floor(qq + phis + 0.5).astype(int) % 54]
            total = sum(float(np.abs(x).sum()) for _, _, x in kept)
            assert np.isclose(a.total, total)
            assert np.allclose(a.ll, ll, atol=1e-4)
            c = int(np.argmax(a.ll.max(axis=1)))  # (near ties: the table's own argmax)
            assert a.best_id == 100 + c and a.score == a.ll.max() / a.total


def test_a_sure_light_posts_its_frames_jitter_about_its_mean_phase():
    """A light whose pieces are its packet's chips, each frame started j_f chips off its
    timestamp (integers within the window), measures j_f minus their mean (its phase absorbs
    the mean) for each frame it is sure of."""
    from receiver.decode.pieces import FrameJitter

    rng = np.random.default_rng(3)
    for trial in range(10):
        templates = rng.choice([-1.0, 1.0], size=(6, 54)).astype(np.float32)
        fj = FrameJitter()
        a = PieceAssembler(np.arange(6), templates, jitter_chips=3, history=12, min_frames=4, min_corr=0.5,
                           min_agree=0.5, min_z=1.0, jitter=fj)
        tid, phi = int(rng.integers(6)), int(rng.integers(54))
        js = rng.integers(-2, 3, 12)
        for f in range(12):
            q = float(rng.integers(0, 5000))
            s = (int(q) + phi + int(js[f])) % 54
            a.add(templates[tid][(s + np.arange(16)) % 54], np.ones(16), q, float(f))
        a.decide(fixed=tid)
        posted = {t: d[a.key] for t, d in fj.by_frame.items()}
        assert len(posted) >= 6
        for t, m in posted.items():
            assert abs(m - (js[int(t)] - js.mean())) < 1e-9


def test_the_consensus_is_the_median_of_the_largest_agreeing_group():
    """Three or more lights: the median of the largest group within agree_chips of one of
    them (odd and even counts); two largest groups of the same measurements are no tie, two of
    different ones are."""
    from receiver.decode.pieces import FrameJitter

    cases = (([0.0, 0.5, 0.3], 0.3), ([0.0, 0.7, 1.4], 0.7), ([0.0, 0.2, 0.4, 0.6], 0.3),
             ([0.0, 0.7, 0.2, 5.0], 0.2), ([0.0, 0.7, 5.0, 5.5], None), ([26.9, -26.9, -26.5, 10.0], -26.5),
             ([1.0, 1.0, 9.0], 1.0))
    for vals, want in cases:
        fj = FrameJitter()
        for key, v in enumerate(vals):
            fj.post(0.0, key, v)
        got = fj.estimate(0.0, 99)
        assert (got is None) if want is None else abs(got - want) < 1e-12, (vals, got)


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
                       min_frames=2, min_corr=0.5, min_agree=0.5, min_z=1.0)
    assert a.jitter_chips == 26


def test_any_two_packets_differ_in_at_least_the_crc_distance():
    """The 24 bits of a packet (16 ID + CRC-8, firmware_tx) form a linear code whose least
    nonzero weight, enumerated over all 65,536 IDs, is `CRC_MIN_DISTANCE_BITS`: the bound that
    lets a piece decision leave `MAX_UNSEEN_BITS` unseen."""
    from firmware_tx.crc import crc8
    from receiver.decode.pieces import CRC_MIN_DISTANCE_BITS, MAX_UNSEEN_BITS

    ids = np.arange(1 << 16)
    words = (ids << 8) | np.array([crc8(int(i), 16) for i in ids])
    rng = np.random.default_rng(3)
    a, b = rng.integers(1 << 16, size=(2, 500))
    assert np.array_equal(words[a ^ b], words[a] ^ words[b])  # linear: distance = weight of the xor
    weight = np.array([bin(int(w)).count("1") for w in words[1:]])
    assert weight.min() == CRC_MIN_DISTANCE_BITS
    assert CRC_MIN_DISTANCE_BITS - MAX_UNSEEN_BITS >= 3


def test_a_bit_is_seen_by_either_chip_of_its_manchester_pair():
    """Chips 0-5 are the sync (never needed); bit i is chips 6 + 2i and 7 + 2i: either shows it;
    all bits but one must be shown."""
    from receiver.decode.pieces import bits_seen

    seen = np.ones(54, bool)
    seen[:6] = False
    assert bits_seen(seen)
    seen[6::2] = False  # every pair's first chip unseen: its second shows the bit
    assert bits_seen(seen)
    seen[7] = False  # bit 0 unseen
    assert bits_seen(seen)
    seen[53] = False  # and bit 23: two bits
    assert not bits_seen(seen)


def _fixed_pieces(led_id, cands, starts, n, near=None, history=30, min_z=3.5):
    """The ML decision over `cands` after noiseless n-chip pieces of `led_id`'s packet at
    packet positions `starts`, each at its exact packet time (no jitter window). near: the map
    IDs given as the pose's at every decision; then the first ID decided is kept."""
    t = packet_template(led_id)
    pa = PieceAssembler(np.asarray(cands), np.stack([packet_template(int(i)) for i in cands]),
                        jitter_chips=0, history=history, min_frames=6, min_corr=0.85, min_agree=0.75, min_z=min_z)
    got = None
    for s in starts:
        pa.add(t[(s + np.arange(n)) % 54], np.ones(n), float(s))
        if near is None:
            got = pa.decide()
            continue
        got = pa.decide(near=near)
        if got is not None:
            break
    return got, pa


def test_pieces_that_miss_one_chip_of_some_pairs_decode():
    """4-chip pieces that never show chips 14 and 28 (each the partner of a shown chip, as
    pieces stepping 4.67 chips a frame, 5 kHz chips at 30 frames/s, do on a rendered grid):
    the right ID is decided. Pieces that also leave bits 7 and 8 (chips 20-23) unseen decide none,
    though the winner is the right ID and passes the correlation and gap checks."""
    rng = np.random.default_rng(12)
    cands = [int(v) for v in rng.choice(1 << 16, 20, replace=False)]
    for starts, unseen in (([0, 4, 8, 10, 15, 19, 23, 24, 29, 33, 37, 41, 45, 49, 50] * 2, [14, 28]),
                           ([0, 4, 8, 10, 15, 24, 29, 33, 37, 41, 45, 49, 50] * 2, [14, 19, 20, 21, 22, 23, 28])):
        seen = np.zeros(54, bool)
        for s in starts:
            seen[(s + np.arange(4)) % 54] = True
        assert np.flatnonzero(~seen).tolist() == unseen
        for led_id in cands[:5]:
            got, pa = _fixed_pieces(led_id, cands, starts, 4)
            assert pa.best_id == led_id and pa.score >= 0.85 and pa.gap >= 0.3
            assert got == (led_id if len(unseen) == 2 else None)


def test_the_winner_against_each_rival_on_the_chips_where_their_packets_differ():
    """For the table's best hypothesis (c, phase) and every other candidate k at its own best
    phase: each piece fitted under each (the first best of its correlation less the window's
    penalty, FFT oracle), `differ` is the weight of the chips whose two fitted packets' chips
    differ and `evidence` half the table's gap, which is the sum of x times c's chip over those
    chips less half the pieces' difference of window penalties."""
    from receiver.decode import pieces as pmod
    from receiver.decode.pieces import FrameJitter

    rng = np.random.default_rng(23)
    for trial in range(12):
        k = int(rng.integers(2, 9))
        templates = rng.choice([-1.0, 1.0], size=(k, 54)).astype(np.float32)
        fj = FrameJitter(frames=10)
        pw, pn = float(rng.uniform(0, 0.5)), float(rng.uniform(0.3, 1.5))
        a = PieceAssembler(np.arange(k), templates, jitter_chips=int(rng.integers(0, 4)), history=6,
                           min_frames=2, min_corr=0.99, min_agree=0.9, min_z=9.0, jitter=fj, shift_penalty=pw, timed_penalty=pn)
        for f in range(9):
            n = int(rng.integers(3, 15))
            a.add(rng.uniform(-1.5, 1.5, n), rng.uniform(0.1, 1, n), float(rng.uniform(-100, 100)), float(f))
            if rng.uniform() < 0.5:
                fj.post(float(f), -1, float(rng.uniform(-1.5, 1.5)))
        a.decide()
        P = len(a.pieces)
        flat = int(np.argmax(a.ll))
        c, ph = divmod(flat, 216)
        ev, df, df2 = np.empty(k), np.empty(k), np.empty(k)
        pmod._k.rivals(a.ll, a._corr, a._wrapped, [p.x for p in a.pieces], a._qq, a._narrow, a.added, c, ph,
                       a.jitter_chips, pw, pn, ev, df, df2)
        fits = []  # per piece: (x, window half, penalty, corr (k, 54))
        for i, p in enumerate(a.pieces):
            narrow = bool(a._narrow[i])
            half = min(1, a.jitter_chips) if narrow else a.jitter_chips
            fits.append((p.x, half, pn if narrow else pw, _fft_best(p.x, templates, half, 0.0)[0], a._qq[i]))

        def fit(corr, kk, start, half, pen):
            ds = np.arange(-half, half + 1)
            return (start + ds[np.argmax(corr[kk, (start + ds) % 54].astype(np.float32) -
                                         (pen * np.abs(ds)).astype(np.float32))]) % 54, half

        for kk in range(k):
            if kk == c:
                assert ev[kk] == 0 and df[kk] == 0 and df2[kk] == 0
                continue
            phk = int(np.argmax(a.ll[kk]))
            d = d2 = e = 0.0
            for x, half, pen, corr, qq in fits:
                sc = int(np.floor(qq + ph / 4 + 0.5)) % 54
                sk = int(np.floor(qq + phk / 4 + 0.5)) % 54
                fc, fk = fit(corr, c, sc, half, pen)[0], fit(corr, kk, sk, half, pen)[0]
                j = np.arange(x.size)
                tc, tk = templates[c][(fc + j) % 54], templates[kk][(fk + j) % 54]
                diff = tc != tk
                d += np.abs(x[diff]).sum()
                d2 += (x[diff].astype(float) ** 2).sum()
                pc = pen * abs(_wrap_chips(fc - sc))
                pk = pen * abs(_wrap_chips(fk - sk))
                e += (x[diff] * tc[diff]).sum() - 0.5 * np.abs(x).sum() * (pc - pk)
            assert np.isclose(df[kk], d, atol=1e-4) and np.isclose(df2[kk], d2, atol=1e-4)
            assert np.isclose(ev[kk], (a.ll[c, ph] - a.ll[kk, phk]) / 2, atol=1e-9)
            assert np.isclose(ev[kk], e, atol=1e-3)
    import pytest

    with pytest.raises(IndexError):
        pmod._k.rivals(a.ll, a._corr, a._wrapped, [p.x for p in a.pieces], a._qq, a._narrow, a.added, k, 0,
                       a.jitter_chips, pw, pn, ev, df, df2)


def _wrap_chips(d):
    return (d + 27) % 54 - 27


def test_a_light_is_told_from_its_twin_at_the_least_distance():
    """Two map IDs whose packets differ in the code's least 4 bits (8 of 54 chips) correlate
    1 - 16/54 = 0.70, so with pieces covering the packet evenly the winner's gap of mean
    correlations is 0.296: below the flat 0.3 once required, yet all 8 differing chips agree
    with the winner three times over. Each of the twins is decided as itself; a twin missing from the
    map is never given the other's ID."""
    from firmware_tx.crc import crc8

    d = next(i for i in range(1, 1 << 16) if bin((i << 8) | crc8(i, 16)).count("1") == 4)
    rng = np.random.default_rng(31)
    starts = list(range(0, 54, 6)) * 3  # 6-chip pieces: every chip seen three times
    for a in rng.choice(1 << 16, 4, replace=False).tolist():
        b = a ^ d
        assert int((packet_template(a) != packet_template(b)).sum()) == 8
        others = [int(v) for v in rng.choice(1 << 16, 18, replace=False) if v not in (a, b)]
        for sent, twin in ((a, b), (b, a)):
            got, pa = _fixed_pieces(sent, [twin, sent] + others, starts, 6)
            assert pa.best_id == sent and abs(pa.gap - 16 / 54) < 1e-6 and got == sent
            assert pa.agree == 1.0 and abs(pa.z - 24 ** 0.5) < 1e-9
            got, pa = _fixed_pieces(sent, [twin] + others, starts, 6)
            assert got is None


def _near_pieces(led_id, cands, starts, n, near):
    """`_fixed_pieces` with the map IDs `near` given as the pose's at every decision."""
    return _fixed_pieces(led_id, cands, starts, n, near=near, history=60, min_z=3.0)


def test_fewer_bits_may_stay_unseen_among_fewer_ids_at_the_same_bound():
    """Among k of K IDs the bound K x phases x 2^-(24 - MAX_UNSEEN_BITS) of the choice among all
    holds with floor(log2(K / k)) more unseen bits, and never with more."""
    from receiver.decode.pieces import MAX_UNSEEN_BITS, unseen_bits_allowed

    for K in (1, 2, 3, 60, 225, 360, 4096):
        for k in (1, 2, 3, 5, 400):
            u = unseen_bits_allowed(K, k)
            assert u >= MAX_UNSEEN_BITS
            if k < K:  # k x 2^-(24 - u) <= K x 2^-(24 - MAX): k 2^u <= K 2^MAX, and one more bit breaks it
                assert k * 2.0 ** u <= K * 2.0 ** MAX_UNSEEN_BITS < k * 2.0 ** (u + 1)
            else:
                assert u == MAX_UNSEEN_BITS


def test_the_pose_s_id_is_confirmed_by_its_chips_with_fewer_bits_seen():
    """Noiseless 6-chip pieces, each chip seen twice, that leave 6 of the 24 bits unseen: the
    choice among all 225 IDs decides none; given the light's own ID as the pose's, it is
    decided (225 / 1: 7 more bits may stay unseen, and every other packet differs from it in
    a seen bit); given another ID (the pose wrong), or 225 IDs, none."""
    from receiver.decode.pieces import SYNC_LEN

    rng = np.random.default_rng(41)
    cands = [int(v) for v in rng.choice(1 << 16, 225, replace=False)]
    starts = list(range(0, 42, 6))  # packet chips 0-41 seen: bits 18-23 (chips 42-53) unseen
    seen = np.zeros(54, bool)
    for s in starts:
        seen[s:s + 6] = True
    assert int((~seen[SYNC_LEN:][0::2]).sum()) == 6
    for sent in cands[:4]:
        assert _near_pieces(sent, cands, starts * 2, 6, ())[0] is None
        assert _near_pieces(sent, cands, starts * 2, 6, (sent,))[0] == sent
        other = next(v for v in cands if v != sent)
        assert _near_pieces(sent, cands, starts * 2, 6, (other,))[0] is None
        assert _near_pieces(sent, cands, starts * 2, 6, tuple(cands))[0] is None


def test_the_pose_s_id_is_never_given_to_a_light_whose_packet_differs_only_in_unseen_bits():
    """Pieces that show every bit of the light's packet but the 4 in which a twin's (a packet
    at the code's least distance) differs: given the twin's ID as the pose's, none, whether
    the twin is in the map or not; given the light's own, none either (the chips cannot tell
    the two apart), while with those bits seen it is decided."""
    from firmware_tx.crc import crc8

    d = next(i for i in range(1, 1 << 16) if bin((i << 8) | crc8(i, 16)).count("1") == 4)
    rng = np.random.default_rng(43)
    cands = [int(v) for v in rng.choice(1 << 16, 225, replace=False)]
    for sent in cands[:3]:
        twin = sent ^ d
        differ = np.flatnonzero(packet_template(sent) != packet_template(twin))
        pairs = [s for s in range(0, 54, 2) if s not in differ]  # the sync's and every other bit's chips
        assert len(differ) == 8 and len(pairs) == 27 - 4
        others = [v for v in cands if v != twin]
        for near in ((twin,), (sent,)):
            assert _near_pieces(sent, [twin] + others, pairs * 3, 2, near)[0] is None
            assert _near_pieces(sent, others, pairs * 3, 2, near)[0] is None
        assert _near_pieces(sent, others, list(range(0, 54, 2)) * 3, 2, (sent,))[0] == sent


def test_the_bits_seen_tell_every_packet_apart_exactly_when_no_code_word_hides_in_the_rest():
    """`shows_every_difference` against all 65,536 packets (firmware_tx's CRC): for random sets
    of seen bits it holds exactly when no two packets agree on every seen bit."""
    from firmware_tx.crc import crc8
    from receiver.decode.pieces import shows_every_difference

    ids = np.arange(1, 1 << 16)
    words = (ids << 8) | np.array([crc8(int(i), 16) for i in ids])  # = the differences from ID 0
    rng = np.random.default_rng(9)
    seen_all = np.ones(24, bool)
    assert shows_every_difference(seen_all)
    verdicts = set()
    for n_unseen in (1, 2, 4, 6, 8, 9):
        for _ in range(6):
            seen = np.ones(24, bool)
            seen[rng.choice(24, n_unseen, replace=False)] = False
            mask = int((seen.astype(np.int64) << np.arange(23, -1, -1)).sum())
            want = bool(((words & mask) != 0).all())
            assert shows_every_difference(seen) == want
            verdicts.add(want)
    assert verdicts == {True, False}


def test_the_pose_s_id_is_never_given_to_a_light_whose_packet_is_it_shifted_by_a_bit():
    """0xfff3's packet a Manchester pair later is 0x7ff9's but for 4 chips (two of the sync's,
    one of bit 0's, one of bit 23's). Pieces that show those 4 chips once and the others but
    0x7ff9's bits 18-23 three times fit 0x7ff9 at the shifted phase best of 225 IDs, with a
    mean correlation above `min_corr` and every seen bit but bit 0 agreeing with it at those
    placements; too few bits for the choice among all IDs. Given 0x7ff9 as the pose's, a light
    sending 0xfff3 (not in the map) gets no ID: its chips tell 0xfff3 a pair later from 0x7ff9
    and agree with it there. A light sending 0x7ff9 with the same pieces gets its ID."""
    sent, shifted = 0xFFF3, 0x7FF9
    t, c = packet_template(sent), packet_template(shifted)
    differ = np.flatnonzero(np.roll(c, -2) != t)
    assert differ.tolist() == [1, 2, 5, 52]
    once = sorted({int(i) // 2 * 2 for i in differ})
    pairs = once + [s for s in range(0, 54, 2) if s not in once and not 40 <= s <= 50] * 3
    rng = np.random.default_rng(47)
    others = [int(v) for v in rng.choice(1 << 16, 224, replace=False) if v not in (sent, shifted)]
    assert _near_pieces(sent, [shifted] + others, pairs, 2, ())[0] is None
    got, pa = _near_pieces(sent, [shifted] + others, pairs, 2, (shifted,))
    assert pa.best_id == shifted and pa.score >= pa.min_corr and got is None
    assert _near_pieces(shifted, [shifted] + others, pairs, 2, (shifted,))[0] == shifted


def test_every_packet_at_every_other_phase_is_tried():
    """`beats_every_shifted_packet` against all 65,536 packets (ook.packet_template) moved by
    each of 1-53 chips, on the chips where they differ from the winner: its verdict is whether
    every such packet but the winner's own ID's differs in a seen chip with a sum >= 0."""
    from receiver.decode.pieces import beats_every_shifted_packet

    rng = np.random.default_rng(53)
    packets = (np.stack([packet_template(i) for i in range(1 << 16)]) > 0).astype(np.int8)
    verdicts = set()
    for c_id, n_bad, n_unseen in ((0xFFF3, 4, 12), (0x7FF9, 3, 12), (int(rng.integers(1 << 16)), 3, 12),
                                  (0x5555, 2, 12), (0x0F0F, 1, 12), (0xFFF3, 0, 12), (0x7FF9, 0, 36)):
        c = packets[c_id]
        a = rng.uniform(0.2, 1.0, 54)
        a[rng.choice(54, n_unseen, replace=False)] = 0.0  # unseen chips
        a[rng.choice(54, n_bad, replace=False)] = -2.0  # chips that disagree
        seen = a != 0
        want = True
        for s in range(1, 54):
            differ = np.roll(packets, s, axis=1) ^ c
            ok = (differ @ a >= 0) & (differ @ seen.astype(np.int64) > 0)
            ok[c_id] = True
            want &= bool(ok.all())
        assert beats_every_shifted_packet(c > 0, a, seen, c_id) == want
        verdicts.add(want)
    assert verdicts == {True, False}
