"""Tracker (gated assignment, coasting) and S2-PSK pairing geometry / blinking checks."""

from __future__ import annotations

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pairing import EmitterLevels, Pairer, pair_score
from receiver.vision.track import Track, Tracker


def blob(cx, cy, r=10.0):
    a = np.pi * r * r
    hull = np.array([[cx - r, cy - r], [cx + r, cy - r], [cx + r, cy + r], [cx - r, cy + r]])
    return Blob(cx, cy, a, hull, int(cx - r), int(cy - r), int(cx + r) + 1, int(cy + r) + 1,
                False, 200.0, 50.0, 10.0)


def test_moving_blobs_keep_their_tracks_and_order_does_not_matter():
    tr = Tracker()
    rng = np.random.default_rng(1)
    starts = [(100.0, 100.0), (140.0, 100.0), (300.0, 200.0)]
    vel = [(6.0, 0.0), (-5.0, 2.0), (0.0, 8.0)]
    ids = None
    for k in range(12):
        blobs = [blob(x + vx * k, y + vy * k) for (x, y), (vx, vy) in zip(starts, vel)]
        order = rng.permutation(3)
        tracks = tr.step(k, [blobs[i] for i in order])
        by_start = {}
        for t in tracks:
            j = int(np.argmin([abs(t.cx - (x + vx * k)) + abs(t.cy - (y + vy * k))
                               for (x, y), (vx, vy) in zip(starts, vel)]))
            by_start[j] = t.track_id
        if ids is None:
            ids = by_start
        assert by_start == ids and len(tracks) == 3


def test_track_coasts_through_dark_frames_then_ends():
    tr = Tracker(max_missed=3)
    tr.step(0, [blob(100, 100)])
    (t0,) = tr.tracks
    for k in (1, 2, 3):
        tracks = tr.step(k, [])
        assert tracks == [t0] and not t0.seen and t0.misses == k
    tracks = tr.step(4, [blob(101, 100)])  # back after 3 dark frames: same track
    assert tracks == [t0] and t0.seen and t0.misses == 0
    for k in range(5, 9):
        tr.step(k, [])
    assert tr.tracks == [] and tr.ended == [t0]


def test_gate_and_area_change_start_new_tracks():
    tr = Tracker(gate_px=10.0)
    tr.gate_size = 0.5  # blob diameters added to the gate (track.GATE_SIZE)
    tr.step(0, [blob(100, 100)])
    tracks = tr.step(1, [blob(200, 100)])  # far outside the gate
    assert len(tracks) == 2 and {t.track_id for t in tracks if t.seen} == {1}
    tr2 = Tracker()
    tr2.step(0, [blob(100, 100, r=5)])
    tracks = tr2.step(1, [blob(101, 100, r=20)])  # 16x the area: another light
    assert {t.track_id for t in tracks if t.seen} == {1}


def test_decoded_id_stays_with_the_track():
    tr = Tracker()
    tr.step(0, [blob(100, 100)])
    tr.tracks[0].led_id = 42
    for k in range(1, 5):
        (t,) = tr.step(k, [blob(100 + 3 * k, 100)])
        assert t.led_id == 42


def _track(tid, cx, cy, r=5.0):
    return Track(tid, blob(cx, cy, r), 0, 0)


def test_pair_geometry():
    a = _track(0, 100, 100)
    assert pair_score(a, _track(1, 180, 102)) is not None  # same row, 8 diameters apart
    assert pair_score(a, _track(2, 180, 130)) is None  # other row band
    assert pair_score(a, _track(3, 180, 100, r=15)) is None  # size differs 9x
    assert pair_score(a, _track(4, 105, 100)) is None  # overlapping
    assert pair_score(a, _track(5, 900, 100)) is None  # too far for a pair


def test_pairer_pairs_blinking_neighbours_only():
    a, b = _track(0, 100, 100), _track(1, 180, 101)
    steady, c = _track(2, 100, 300), _track(3, 180, 300)  # a lamp pair that never blinks
    rng = np.random.default_rng(2)
    on = {0: rng.random(12) < 0.5, 1: rng.random(12) < 0.5, 2: np.ones(12, bool), 3: np.ones(12, bool)}
    pr = Pairer()
    assert pr.min_frames == 4
    for k in range(12):
        lum = {tid: (200.0 if on[tid][k] else 15.0) for tid in on}
        pairs = pr.step(None, [a, b, steady, c], lambda g, t: lum[t.track_id])
        for p in pairs:  # as the pipeline does: every frame's intensities of a pair
            ia, ib = pr.sample(p, None, lambda g, t: lum[t.track_id])
            assert (ia, ib) == (lum[p.a.track_id], lum[p.b.track_id])
    assert len(pairs) == 1 and pairs[0].key == (0, 1)
    p = pairs[0]
    assert p.levels_a.on > 150 and p.levels_a.off < 50


def test_emitter_levels():
    lv = EmitterLevels(history=10)
    for v in [10, 200, 12, 198, 11, 202]:
        lv.add(v)
    assert lv.off < 20 and lv.on > 190 and lv.blinks(50)
    assert not EmitterLevels().blinks(1)


def test_coasting_pair_moves_its_emitter_masks_with_it():
    """A far head drifting 0.4 px per frame with both emitters dark: the masks its intensities
    are read in must follow the pair's own position (whole-pixel steps, never more than half a
    pixel behind), not stay where the last blob was."""
    from receiver.vision.pairing import Pair, _emitter
    a, b = Track(1, blob(100.0, 50.0, 2.0), 0, 0), Track(2, blob(110.0, 50.0, 2.0), 0, 0)
    p = Pair(_emitter(a), _emitter(b), tracks=[a, b], nearby=[a, b])
    pr = Pairer(max_missed=100)
    assert pr._follow(p, [], np.zeros((0, 2)), None)  # forms the geometry
    p.vx = 0.4
    for _ in range(20):
        assert pr._follow(p, [], np.zeros((0, 2)), None)
    for e, sign in ((p.a, -1.0), (p.b, 1.0)):
        mask_x = e.blob.hull[:, 0].mean()   # the square mask's centre
        assert abs(mask_x - (p.mx + sign * 5.0)) <= 0.5 + 1e-9, (mask_x, p.mx)
    assert abs(p.mx - 113.0) < 1e-9   # 105 + 20 x 0.4


def _formed_pair(pr, x, y, track_ids):
    from receiver.vision.pairing import Pair, _emitter
    a = Track(track_ids[0], blob(x, y, 2.0), 0, 0)
    b = Track(track_ids[1], blob(x + 10.0, y, 2.0), 0, 0)
    p = Pair(_emitter(a), _emitter(b), tracks=[a, b], nearby=[a, b])
    assert pr._follow(p, [], np.zeros((0, 2)), None)   # forms the geometry, no blob
    return p


def test_pitch_shake_moves_dark_pairs_with_the_lit_ones():
    """Three heads show an emitter 3 px lower than predicted (the camera pitched); a fourth is
    dark this frame. The common shift (median) moves the dark one too, so its emitter masks stay
    on its lights; x offsets (which emitter lit) do not count."""
    pr = Pairer(max_missed=100)
    pairs = [_formed_pair(pr, 100.0 + 60 * i, 50.0, (2 * i, 2 * i + 1)) for i in range(4)]
    pr.pairs = list(pairs)
    lit = [Track(100 + i, blob(p.mx - 5.0 + (0.4 if i == 1 else 0.0), p.my + 3.0, 2.0), 1, 1)
           for i, p in enumerate(pairs[:3])]
    xy = np.array([[t.cx, t.cy] for t in lit])
    assert abs(pr.pitch_shift(lit, xy) - 3.0) < 1e-9
    assert pr.pitch_shift(lit[:2], xy[:2]) == 0.0   # fewer than 3 pairs explain a blob: none
    pr.step(np.zeros((120, 400), np.uint8), lit, lambda g, t: 0.0)
    dark = pairs[3]
    assert abs(dark.my - 53.0) < 1e-9 and abs(dark.a.blob.cy - 53.0) <= 0.5


def test_jumping_track_pairs_despite_the_heads_vertical_motion():
    """A far head whose halves are never two blobs of one frame: one track jumps between A and
    B (7 px apart) while the camera's pitch moves the head 1.5 px per frame. Consecutive
    left-to-right jumps then differ by 3 px vertically (twice the motion); the pair still
    forms, with the baseline free of the motion (mean of the two jumps)."""
    pr = Pairer()
    xs = [100.0, 107.0, 100.0, 107.0]  # B <- A -> B ...
    pairs = []
    for k, x in enumerate(xs):
        t = Track(5, blob(x + 0.1 * k, 50.0 - 1.5 * k, 2.0), 0, k)
        pairs = pr.step(None, [t], lambda g, tr: 100.0)
        if pairs:
            break
    assert len(pairs) == 1, "no pair from the jumping track"
    p = pairs[0]
    assert abs((p.b.blob.cx - p.a.blob.cx) - 7.0) <= 1.0
    assert abs(p.b.blob.cy - p.a.blob.cy) <= 0.5  # a level head: no vertical baseline
    # without the vertical allowance the same motion forms no pair
    pr = Pairer()
    pr.jump_agree_y_px = 0.0
    for k, x in enumerate(xs):
        assert not pr.step(None, [Track(5, blob(x + 0.1 * k, 50.0 - 1.5 * k, 2.0), 0, k)],
                           lambda g, tr: 100.0)


def test_an_emitter_with_a_stale_small_envelope_still_explains_its_grown_blob():
    """An approaching head: B's envelope followed the growing light, A's (seen in few frames)
    is still the size it was. A blob on A three times A's envelope but the size of B's is A's
    own single blob: it moves the pair and becomes A's envelope."""
    from receiver.vision.pairing import Pair, _emitter
    pr = Pairer(max_missed=100)
    a, b = Track(1, blob(100.0, 50.0, 2.0), 0, 0), Track(2, blob(110.0, 50.0, 2.0), 0, 0)
    p = Pair(_emitter(a), _emitter(b), tracks=[a, b], nearby=[a, b])
    assert pr._follow(p, [], np.zeros((0, 2)), None)  # forms the geometry
    p.b.blob = blob(110.0, 50.0, 3.5)  # B grew with the light (3x the area)
    seen = Track(7, blob(100.5, 50.0, 3.4), 1, 1)
    assert pr._follow(p, [seen], np.array([[seen.cx, seen.cy]]), None)
    assert p.tracks == [seen] and p.misses == 0
    assert abs(p.a.blob.area_px - seen.blob.area_px) < 1e-9


def test_a_decoded_street_lights_pair_follows_its_size_through_merged_blobs():
    """An approaching street light (decoded) shows both halves lit as one merged blob for a
    few frames; its envelopes stay the size they were. Its next merged blob, grown to 3.5x an
    envelope (over `max_merged` 3x), is still its own: the merged blob before it (2.6x, half
    of it one emitter) set the pair's size. A pair not known to be a street light (a car's
    taillights never merge) keeps its envelopes' size and misses it."""
    from receiver.vision.pairing import Pair, _emitter

    def run(follow):
        pr = Pairer(max_missed=100)
        a, b = Track(1, blob(100.0, 50.0, 4.0), 0, 0), Track(2, blob(120.0, 50.0, 4.0), 0, 0)
        p = Pair(_emitter(a), _emitter(b), tracks=[a, b], nearby=[a, b], led_id=110, kind="SL" if follow else None)
        assert pr._follow(p, [], np.zeros((0, 2)), None)  # forms the geometry
        env = p.a.blob.area_px
        misses = []
        for k, grown in enumerate((2.6, 3.5)):
            m = Track(7 + k, blob(p.mx, 50.0, 4.0 * np.sqrt(grown)), 1 + k, 1 + k)
            assert pr._follow(p, [m], np.array([[m.cx, m.cy]]), None)
            misses.append(p.misses)
        assert abs(p.a.blob.area_px - env) < 1e-9  # a merged blob never becomes an envelope
        return misses

    assert run(True) == [0, 0]
    assert run(False) == [0, 1]


def test_a_near_jumper_pairs_first_sample_reads_against_its_tracks_levels():
    """A near head whose halves merge (one track jumping between them, 28 px^2 blobs): its new
    pair's emitters start with the track's learned on / off levels, so its first sample (A lit,
    B dark) reads anti-phase. Without the seeding (`jumper_levels_min_area_px` inf, or a far
    head under it) each emitter holds one value and the sample reads 0."""
    from receiver.decode.s2psk import pair_xor

    def first_xor(min_area):
        pr = Pairer()
        pr.jumper_levels_min_area_px = min_area
        xs = [100.0, 112.0, 100.0, 112.0, 100.0]
        lum = [200.0, 10.0, 200.0, 10.0, 200.0]
        pairs = []
        for k, x in enumerate(xs):
            t = Track(5, blob(x, 50.0, 3.0), 0, k)
            pairs = pr.step(None, [t], lambda g, tr, k=k: lum[k])
            if pairs:
                break
        assert len(pairs) == 1, "no pair from the jumping track"
        p = pairs[0]
        ia, ib = pr.sample(p, None, lambda g, tr: 200.0 if tr is p.a else 10.0)
        la, lb = p.levels_a, p.levels_b
        return pair_xor(ia, ib, la.on, lb.on, la.off, lb.off)

    assert first_xor(16.0) > 0.9
    assert first_xor(float("inf")) == 0.0
    assert first_xor(30.0) == 0.0  # 28 px^2: a far head's, not seeded


def test_emitter_levels_equal_numpy_percentiles():
    """The levels come from a sorted copy kept per value; they must be np.percentile's."""
    rng = np.random.default_rng(3)
    for _ in range(40):
        lv = EmitterLevels(history=int(rng.integers(2, 60)))
        for _ in range(int(rng.integers(1, 120))):
            lv.add(float(rng.choice([rng.normal(100, 40), round(rng.normal(50, 30)), 12.0])))
            off, on = np.percentile(np.fromiter(lv.values, float), (10.0, 90.0))
            assert (lv.off, lv.on) == (float(off), float(on))


def test_jumping_track_pairs_when_the_measured_shake_spans_a_dark_frame():
    """Yaw shake of up to 6 px per frame, measured (`shift`): the head's track is dark every
    other frame, so each jump spans two frames' shake. Taking out only the latest frame's
    shift leaves the other frame's in the jump (13 px, then 2 px: no pair); the shift added up
    since the track's previous blob leaves the 7 px baseline twice."""
    xs = [100.0, None, 107.0, None, 100.0]  # A, dark, B, dark, A
    shifts = [(0.0, 0.0), (6.0, 0.0), (-2.0, 0.0), (5.0, 0.0), (-3.0, 0.0)]
    pr = Pairer()
    pairs, offset, last = [], 0.0, 100.0
    for k, (x, s) in enumerate(zip(xs, shifts)):
        offset += s[0]
        seen = x is not None
        last = x if seen else last
        t = Track(5, blob(last + (offset if seen else 0.0), 50.0, 2.0), 0, k, seen=seen)
        pairs = pr.step(None, [t], lambda g, tr: 100.0, shift=s)
        if pairs:
            break
    assert len(pairs) == 1, "no pair from the jumping track"
    assert abs((pairs[0].b.blob.cx - pairs[0].a.blob.cx) - 7.0) <= 1.0


def test_gated_assignment_shortcut_equals_the_solver():
    from receiver.vision.track import _solver_assignment, gated_assignment
    rng = np.random.default_rng(3)
    shortcut = 0
    for _ in range(400):
        t, b = rng.integers(1, 7, size=2)
        d = rng.uniform(0, 50, size=(t, b))
        ok = d <= rng.uniform(5, 40)
        if np.count_nonzero(ok, axis=0).max(initial=0) <= 1 and np.count_nonzero(ok, axis=1).max(initial=0) <= 1:
            shortcut += 1
        assert gated_assignment(d, ok) == _solver_assignment(d, ok)
    assert 50 < shortcut < 390  # both paths were taken
