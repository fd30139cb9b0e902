"""Width-based size test and baseline re-measurement of S2-PSK pairs: a far street-light half is
one or two rows tall, so its area doubles between frames while its width holds, and a merged
both-lit blob is one baseline wider."""

import math

import numpy as np
import pytest

from receiver.core.records import Blob
from receiver.vision.pairing import Pair, Pairer
from receiver.vision.track import Track


def _blob(cx, cy, w, h):
    """A w x h px bar centred on (cx, cy) (half-open box)."""
    x0, y0 = int(round(cx - w / 2)), int(round(cy - h / 2))
    hull = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + h - 1], [x0, y0 + h - 1]], float)
    return Blob(cx=float(cx), cy=float(cy), area_px=float(w * h), hull=hull, x0=x0, y0=y0, x1=x0 + w, y1=y0 + h,
                border=False, peak=60.0, level=10.0, background=2.0)


def _jumper(hx=6.0, w=10, h=1):
    """A pair founded on one jumping track (a far head) with halves of w x h px, 2 * hx apart."""
    t = Track(7, _blob(100.0, 50.0, w, h), 0, 0)
    a, b = Track(7, _blob(100.0 - hx, 50.0, w, h), 0, 0), Track(7, _blob(100.0 + hx, 50.0, w, h), 0, 0)
    p = Pair(a, b, fresh=False, tracks=[t], nearby=[t], ids=(1, 2))
    p.base0, p.area0, p.mx, p.my = (2 * hx, 0.0), float(w * h), 100.0, 50.0
    return p


def test_width_classes_single_and_merged_short_blobs_only():
    pr = Pairer()
    p = _jumper(hx=6.0, w=10)
    assert pr._width_class(p, _blob(100, 50, 10, 2), 6.0) == "single"  # twice the area, same width
    assert pr._width_class(p, _blob(100, 50, 22, 1), 6.0) == "merged"  # one baseline (12 px) wider
    assert pr._width_class(p, _blob(100, 50, 16, 1), 6.0) is None      # neither
    assert pr._width_class(p, _blob(100, 50, 22, 5), 6.0) is None      # tall: its area tells
    # a short cut row of a tall (5-row) head is not judged by width
    assert pr._width_class(_jumper(hx=6.0, w=10, h=5), _blob(100, 50, 22, 2), 6.0) is None


def test_merged_width_remeasures_a_short_baseline():
    pr = Pairer()
    p = _jumper(hx=4.5, w=10)  # founded 9 px apart; the head's halves are 12 px apart
    mx, my, hx, hy, single = pr._predict(p)
    assert hx == pytest.approx(4.5)
    pr._measure_baseline(p, hx, hy, None, None, _blob(100, 50, 22, 1))
    assert p.base == pytest.approx((12.0, 0.0))
    assert pr._predict(p)[2] == pytest.approx(6.0)
    # a blob of another shape (here 2.5 x the predicted baseline wider) is not a measurement
    p.frames += 1
    pr._measure_baseline(p, 6.0, 0.0, None, None, _blob(100, 50, 40, 1))
    assert p.base == pytest.approx((12.0, 0.0))
    # later measurements are blended in (baseline_gain 0.5)
    pr._measure_baseline(p, 6.0, 0.0, None, None, _blob(100, 50, 24, 1))
    assert p.base[0] == pytest.approx(13.0)
    assert math.isfinite(p.growth) and 0.0 <= p.growth <= pr.max_growth


def _explain(pr, p, blob):
    t = Track(9, blob, 0, 0)
    mx, my, hx, hy, single = pr._predict(p)
    return pr._explain(p, [t], np.array([[t.cx, t.cy]]), mx, my, hx, hy, single)


def test_width_takes_a_taller_half_but_not_a_cut_one():
    pr = Pairer()
    # one-row envelopes: the same half seen over two rows (twice the area) is its emitter A
    p = _jumper(hx=6.0, w=10, h=1)
    expl, _, shifts, obs_a, obs_b, merged = _explain(pr, p, _blob(94.0, 50.0, 10, 2))
    assert len(expl) == 1 and obs_a is not None and obs_b is None and merged is None
    # a 3-row head: one row of A cut by a clock edge is as wide; it moves the pair (area 1/3,
    # `max_cut`) but never becomes A's envelope; a fifth of it is not A's at all
    q = _jumper(hx=6.0, w=10, h=3)
    expl, _, _, obs_a, _, _ = _explain(pr, q, _blob(94.0, 50.0, 10, 1))
    assert len(expl) == 1 and obs_a is None
    q = _jumper(hx=6.0, w=10, h=5)
    expl, _, _, obs_a, _, _ = _explain(pr, q, _blob(94.0, 50.0, 10, 1))
    assert expl == [] and obs_a is None
    # a merged blob one baseline wider, nearest emitter B (a short predicted baseline) is merged
    r = _jumper(hx=3.0, w=10, h=1)
    expl, _, shifts, obs_a, obs_b, merged = _explain(pr, r, _blob(102.5, 50.0, 16, 1))
    assert merged is not None and obs_a is None and obs_b is None
    assert shifts[0][0] == pytest.approx(2.5)  # moves the midpoint, not emitter B


def test_a_decoded_far_head_that_coasted_is_reported_again_once_a_merged_blob_places_it():
    pr = Pairer()
    p = _jumper(hx=3.0, w=6, h=1)
    p.led_id, p.kind, p.seen_a, p.seen_b = 42, "SL", 0, 0
    pr.pairs = [p]
    assert len(pr.emitters()) == 2
    empty = np.zeros((0, 2))
    for _ in range(pr.anchor_coast_frames):
        assert pr._follow(p, [], empty, None)  # no blob: it coasts
    assert not p.anchored and pr.emitters() == []  # may sit a baseline aside now
    one = Track(9, _blob(p.mx + p.vx + 3.0, 50.0, 6, 1), 0, 0)  # a single half: which one?
    pr._follow(p, [one], np.array([[one.cx, one.cy]]), None)
    assert not p.anchored and pr.emitters() == []
    both = Track(9, _blob(p.mx + p.vx, 50.0, 12, 1), 0, 0)  # both lit, one blob: the midpoint
    pr._follow(p, [both], np.array([[both.cx, both.cy]]), None)
    assert p.anchored and len(pr.emitters()) == 2
    # pairs of two tracks (taillights, near heads) are not held back
    q = _jumper(hx=3.0, w=6, h=1)
    q.b = Track(8, q.b.blob, 0, 0)
    q.led_id, q.anchored, q.seen_a, q.seen_b = 43, False, 0, 0
    pr.pairs = [q]
    assert len(pr.emitters()) == 2


def test_a_decoded_far_head_beside_a_blob_it_did_not_take_is_not_reported():
    """vehicle-road seed 3 frame 125: head 17's pair (3 px baseline, 2 px right of its head)
    missed its own half's blob 2.5 px left of emitter A; its emitter B, reported, was matched to
    the neighbouring head 62."""
    def follow(pr, p, x, w=3):
        t = Track(9, _blob(x, 50.0, w, 1), 0, 0)
        pr.pairs = [p]
        pr.step(np.zeros((100, 200), np.uint8), [t], lambda g, e: 0.0, shift=(0.0, 0.0))
        return p

    def decoded(w=3):
        p = _jumper(hx=1.5, w=w, h=1)
        p.led_id, p.kind, p.seen_a, p.seen_b = 17, "SL", 0, 0
        return p

    pr = Pairer()
    p = follow(pr, decoded(), 95.5)  # outside the pair, 3 px left of A: not taken
    assert p.misses == 1 and p.beside and pr.emitters() == []
    p = follow(pr, p, 98.5)  # its own half at A: taken, reported again
    assert p.misses == 0 and not p.beside and len(pr.emitters()) == 2
    # not held: a blob between its emitters, a speck a third of an emitter's size, an undecoded
    # pair
    assert not follow(Pairer(), decoded(), 100.0, w=9).beside
    assert not follow(Pairer(), decoded(w=6), 95.5, w=1).beside
    assert follow(Pairer(), decoded(w=6), 95.5, w=2).beside
    q = decoded()
    q.led_id = None
    assert not follow(Pairer(), q, 95.5).beside


def _two_track_pair(pr, a0, b0):
    ta, tb = Track(3, a0, 0, 0), Track(4, b0, 0, 0)
    p = Pair(Track(3, a0, 0, 0), Track(4, b0, 0, 0), fresh=False, tracks=[ta, tb], nearby=[ta, tb], ids=(1, 2))
    pr.pairs = [p]
    return p


def _step(pr, *blobs, frame=1):
    pr.step(None, [Track(3 + k, b, frame, frame) for k, b in enumerate(blobs)], lambda g, t: 0.0,
            shift=(0.0, 0.0))


def test_a_two_track_pair_measures_its_baseline_and_never_scales_it_by_the_area():
    """A pair of two tracks (taillights, a head's separate halves) takes its baseline from its
    two emitters' own blobs seen in one frame; the emitters' area (a saturated blob blooms to
    2-3x the emitter's) does not change it; the next such measurement is blended in and gives
    the baseline's growth per frame (an approaching light's separation grows as 1 / range)."""
    pr = Pairer()
    p = _two_track_pair(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
    _step(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
    assert p in pr.pairs and p.base == pytest.approx((40.0, 0.0))
    p.a.blob = p.b.blob = _blob(180.0, 80.0, 12, 8)  # four times the area
    assert pr._predict(p)[2] == pytest.approx(20.0)  # half the baseline, unchanged
    p.a.blob, p.b.blob = _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4)
    _step(pr, _blob(176.0, 80.0, 6, 4), _blob(224.0, 80.0, 6, 4), frame=2)
    assert p in pr.pairs and p.base[0] == pytest.approx(44.0)  # half of the 8 px more, blended in
    assert p.growth > 0.0
    # only A's own blob: no measurement, the baseline is predicted at its growth
    base = p.base
    _step(pr, _blob(175.0, 80.0, 6, 4), frame=3)
    assert p in pr.pairs and p.base == base
    assert pr._predict(p)[2] > 0.5 * base[0]


def test_a_saturated_blob_is_its_emitter_whatever_its_area():
    """A blob that peaks at the sensor's white level (`white_gray`) blooms: three times the
    emitter's area beside the pair's A is still A's own blob; the same blob unsaturated is
    another light's (a far bigger emitter)."""
    for peak, explained in ((255.0, True), (200.0, False)):
        pr = Pairer(white_gray=250.0)
        p = _two_track_pair(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
        _step(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
        big = _blob(180.0, 80.0, 12, 6)
        big = Blob(big.cx, big.cy, big.area_px, big.hull, big.x0, big.y0, big.x1, big.y1, big.border, peak,
                   big.level, big.background)
        _step(pr, big, frame=2)
        assert p in pr.pairs
        assert (p.misses == 0) is explained
        assert (p.seen_a == p.frames) is explained


def test_a_coasting_two_track_pair_is_replaced_on_both_its_emitters_blobs():
    """A pair of two tracks whose light moved past its gate while it coasted (12 px: a shake step
    the frame's shift missed) is placed again on two seen blobs one baseline apart, both emitters at
    once; not in its first frame without a blob (both emitters dark in a quarter of the frames,
    any two blobs one baseline apart would do), nor on two blobs of another separation."""
    def run(misses, sep):
        pr = Pairer()
        p = _two_track_pair(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
        _step(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
        for k in range(misses):
            _step(pr, frame=2 + k)  # nothing seen: it coasts
        _step(pr, _blob(192.0, 81.0, 6, 4), _blob(192.0 + sep, 81.0, 6, 4), frame=2 + misses)
        return p
    p = run(1, 40.0)
    assert p.misses == 0 and p.anchored
    assert (p.a.cx, p.b.cx) == pytest.approx((192.0, 232.0))
    assert run(0, 40.0).misses == 1       # first frame without a blob: not re-placed
    assert run(1, 52.0).misses == 2       # another separation: another light


def _tracks_step(pr, tracks, frame):
    pr.step(None, [Track(tid, b, frame, frame) for tid, b in tracks], lambda g, t: 0.0, shift=(0.0, 0.0))


def test_a_pair_on_another_pairs_light_holds_back_its_id():
    """Two cars' taillight pairs side by side, 20 px apart. A decoded pair that explains the
    founding track of another decoded pair, which explains no blob in that frame and predicts
    an emitter within its reach of it (its light may be that one), may be on another light: its
    ID is kept but not reported (`reported_id`) until its own samples confirm it again
    (receiver.pipeline). A pair that explains its own tracks' blobs reports its ID; so does one
    that explains the other's founding track while the other still explains a blob of its own,
    or while the other is predicted far away (the tracker gave the id to another light)."""
    def two_pairs(x_other=240.0):
        pr = Pairer()
        pa = _two_track_pair(pr, _blob(180.0, 80.0, 6, 4), _blob(220.0, 80.0, 6, 4))
        tc, td = Track(5, _blob(x_other, 80.0, 6, 4), 0, 0), Track(6, _blob(x_other + 40.0, 80.0, 6, 4), 0, 0)
        pb = Pair(Track(5, tc.blob, 0, 0), Track(6, td.blob, 0, 0), fresh=False, tracks=[tc, td],
                  nearby=[tc, td], ids=(7, 8))
        pr.pairs = [pa, pb]
        pa.led_id, pb.led_id = 133, 201
        _tracks_step(pr, [(3, _blob(180.0, 80.0, 6, 4)), (4, _blob(220.0, 80.0, 6, 4)),
                          (5, _blob(x_other, 80.0, 6, 4)), (6, _blob(x_other + 40.0, 80.0, 6, 4))], 1)
        return pr, pa, pb
    pr, pa, pb = two_pairs()
    assert pa.confirmed and pb.confirmed and (pa.reported_id, pb.reported_id) == (133, 201)
    # B's founding track 5 now lies on A's right emitter, and B explains no blob: A may be on B's light
    _tracks_step(pr, [(5, _blob(221.0, 80.0, 6, 4))], 2)
    assert [t.track_id for t in pa.tracks] == [5]
    assert not pa.confirmed and pa.led_id == 133 and pa.reported_id is None
    assert pb.reported_id == 201
    # its own blobs only: confirmed
    pr, pa, pb = two_pairs()
    _tracks_step(pr, [(3, _blob(181.0, 80.0, 6, 4)), (6, _blob(280.0, 80.0, 6, 4))], 2)
    assert pa.confirmed and pa.reported_id == 133 and pb.reported_id == 201
    # the same track 5 on A's right emitter while B explains its own left blob (a new track 9)
    pr, pa, pb = two_pairs()
    _tracks_step(pr, [(5, _blob(221.0, 80.0, 6, 4)), (9, _blob(240.0, 80.0, 6, 4))], 2)
    assert [t.track_id for t in pa.tracks] == [5]
    assert pa.confirmed and pa.reported_id == 133
    # B far away (200 px): track 5 on A's right emitter is not B's light
    pr, pa, pb = two_pairs(x_other=420.0)
    _tracks_step(pr, [(5, _blob(221.0, 80.0, 6, 4))], 2)
    assert [t.track_id for t in pa.tracks] == [5]
    assert pa.confirmed and pa.reported_id == 133
