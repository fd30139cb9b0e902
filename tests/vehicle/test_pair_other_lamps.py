"""A decoded taillight pair keeps its ID on its own car when a nearer car's lamps cross it:
- a saturated lamp well above the pair's own blobs, seen beside them while the pair is placed, is
  another light's for as long as its track lives (pair_match.other_lamps, `Pair.others`), also
  when it later sits on a hidden emitter cut by a clock edge to the pair's size;
- an emitter with no blob of its own for `jumper_unseen_frames` is not reported (hidden);
- a coasting pair is not re-placed on two blobs too small for their spacing to be one car's
  lamps (pair_match.reanchor, the pairing's `max_baseline` diameters)."""

import numpy as np

from receiver.vision.pairing import Pair, Pairer
from receiver.vision.track import Track
from tests.vehicle.test_pair_lone_blob import _blob

WHITE = 255.0
SHAPE = (720, 1280)


def _decoded_pair(pr, xa=500.0, xb=558.0, y=470.0, side=7, led_id=204):
    """A decoded car with saturated taillights of `side` x `side` px at `xa` and `xb`, row `y`."""
    a, b = _blob(xa, y, side, side), _blob(xb, y, side, side)
    p = Pair(Track(3, a, 0, 0), Track(4, b, 0, 0), ids=(10, 11))
    p.led_id, p.kind = led_id, "FV"
    pr.pairs = [p]
    _frame(pr, [(3, a), (4, b)])  # its first frame: the baseline, both emitters seen
    return p


def _frame(pr, tracks):
    """One frame of `tracks` ((track id, blob), ...): the tracker keeps a light's id."""
    ts = [Track(tid, b, 0, 0) for tid, b in tracks]
    xy = np.array([(t.cx, t.cy) for t in ts], float).reshape(-1, 2)
    return pr._follow_all(ts, SHAPE, 0.0, 0.0, {}, xy)


def test_a_nearer_lamp_seen_beside_the_pair_never_becomes_its_hidden_emitter():
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr)
    # A lit on its place; a nearer car's saturated lamp (11 x 10 px, over twice the pair's
    # 7 x 7) 16 px right of B's place, outside B's gate: not explained
    _frame(pr, [(30, _blob(500.5, 470.0, 7, 7)), (31, _blob(574.0, 473.0, 11, 10))])
    assert [t.track_id for t in p.tracks] == [30]
    # the next frame that lamp has moved onto B's place (B hidden behind it) and a clock edge
    # cuts it to 8 x 7 px: as large as the pair's own bloomed lamps, within every area gate
    _frame(pr, [(31, _blob(559.0, 472.0, 8, 7))])
    assert p.tracks == []
    assert abs(p.b.cx - 558.5) <= 1.0 and abs((p.b.cx - p.a.cx) - 58.0) <= 0.5
    # ... nor is it taken while it stays there, with A lit again
    _frame(pr, [(30, _blob(500.5, 470.0, 7, 7)), (31, _blob(559.5, 473.0, 11, 10))])
    assert [t.track_id for t in p.tracks] == [30]


def test_its_own_lamps_still_move_it():
    """Its own emitters' blobs, and a lamp beside it no larger than its own, are not marked."""
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr)
    _frame(pr, [(30, _blob(500.5, 470.0, 7, 7)), (31, _blob(574.0, 473.0, 7, 7))])
    assert p.others == set()
    _frame(pr, [(31, _blob(559.0, 470.0, 7, 7))])
    assert [t.track_id for t in p.tracks] == [31]


def test_an_emitter_without_a_blob_of_its_own_for_long_is_not_reported():
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr)
    reported = []
    for k in range(pr.jumper_unseen_frames + 3):
        _frame(pr, [(30, _blob(500.5, 470.0, 7, 7))])  # A lit every frame; B hidden
        reported.append(sorted(i for i, _, _ in pr.emitters()))
    assert reported[0] == [10, 11]  # dark for a frame or two: still where the pair puts it
    assert reported[-1] == [10]
    assert p.frames - p.seen_b > pr.jumper_unseen_frames


def test_a_coasting_car_is_not_re_placed_on_two_far_lights_pixels():
    """A near car (10 x 10 px lamps 90 px apart) coasts; two one-pixel blobs of far street
    lights 90 px apart, 10 px above it, are 90 diameters apart: not its taillights."""
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr, xa=600.0, xb=690.0, side=10, led_id=182)
    _frame(pr, [])
    _frame(pr, [(40, _blob(600.0, 460.0, 1, 1, peak=31.0)), (41, _blob(690.0, 460.0, 1, 1, peak=30.0))])
    assert p.tracks == [] and abs(p.a.cy - 470.0) <= 1.0
    # its own lamps one baseline apart 10 px above (the camera pitched) move it
    _frame(pr, [(42, _blob(603.0, 460.0, 10, 10)), (43, _blob(693.0, 460.0, 10, 10))])
    assert sorted(t.track_id for t in p.tracks) == [42, 43] and abs(p.a.cy - 460.0) <= 1.0


def test_a_car_half_behind_a_nearer_car_reports_its_other_lamp_only_when_seen():
    """Car 185's left taillight is hidden between the taillights of nearer car 216; its right
    one, at 216's edge, may go behind 216 any frame: reported in the frames it is seen, not
    where the pair predicts it while it is dark."""
    pr = Pairer(white_gray=WHITE)
    near = _decoded_pair(pr, xa=790.0, xb=878.0, y=455.0, side=10, led_id=216)
    a, b = _blob(840.0, 447.0, 7, 7), _blob(893.0, 447.0, 7, 7)
    far = Pair(Track(5, a, 0, 0), Track(6, b, 0, 0), ids=(12, 13))
    far.led_id, far.kind, near.kind = 185, "FV", "FV"
    pr.pairs = [near, far]
    lamps_216 = [(3, _blob(790.0, 455.0, 10, 10)), (4, _blob(878.0, 455.0, 10, 10))]
    _frame(pr, lamps_216 + [(5, a), (6, b)])
    reported = []
    for k in range(pr.jumper_unseen_frames + 3):
        lit_b = k % 2 == 0  # 185's right taillight lit every other frame; its left one hidden
        _frame(pr, lamps_216 + ([(6, _blob(893.0, 447.0, 7, 7))] if lit_b else []))
        reported.append((lit_b, sorted(i for i, _, p in pr.emitters() if p is far)))
    assert reported[0] == (True, [12, 13])
    assert reported[-1] == (True, [13]) and reported[-2] == (False, [])
    # a car not behind another reports its seen taillight when dark too (S2-PSK's dark half)
    other = Pairer(white_gray=WHITE)
    p = _decoded_pair(other)
    for k in range(other.jumper_unseen_frames + 4):
        _frame(other, [(30, _blob(500.5, 470.0, 7, 7))] if k % 2 == 0 else [])
    assert p.tracks == [] and sorted(i for i, _, _ in other.emitters()) == [10]
