"""A decoded taillight pair whose emitter is hidden by a nearer car does not carry its ID onto
that car's taillight: once the pair's own blobs saturate, a saturated blob well above them
(more than `merged_ratio` x its envelope) is another light's (pair_match.bloom_checked)."""

from receiver.vision.pairing import Pairer
from tests.vehicle.test_pair_lone_blob import _blob, _frame
from tests.vehicle.test_pair_lone_blob import _decoded_pair as _pair_at

WHITE = 255.0


def _decoded_pair(pr, peak=WHITE):
    """A decoded car ~37 m ahead: taillights of 7 x 7 px at x 500 and 558, y 470."""
    return _pair_at(pr, xb=558.0, y=470.0, peak=peak, led_id=216)


def _hidden_a_frame(pr):
    """A hidden; B lit where the pair predicts it; a nearer car's saturated taillight (11 x 10 px,
    over twice the pair's area) lit 3 px left of A's place."""
    near, own_b = _blob(497.0, 471.0, 11, 10), _blob(558.5, 470.0, 7, 7)
    _frame(pr, [near, own_b])
    return near, own_b


def test_a_nearer_lamp_beside_a_hidden_emitter_does_not_take_the_pair():
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr)
    _hidden_a_frame(pr)
    # only B's own blob is explained: A stays where the pair puts it, the baseline is unchanged
    assert [t.cx for t in p.tracks] == [558.5]
    assert abs(p.a.cx - 500.5) <= 0.5 and p.a.blob.area_px == 49.0
    assert abs((p.b.cx - p.a.cx) - 58.0) <= 0.5


def test_a_saturated_blob_is_not_held_to_an_unsaturated_envelope():
    """Before its own blobs saturate, a pair's bloom is unknown: the larger blob is its lamp
    starting to bloom and is taken as before."""
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr, peak=200.0)
    near, _ = _hidden_a_frame(pr)
    assert near.cx in [t.cx for t in p.tracks]


def test_its_own_bloomed_blobs_still_move_it():
    """Its own lamps' saturated blobs within `merged_ratio` of the envelope are its own."""
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr)
    _frame(pr, [_blob(501.0, 470.0, 8, 8), _blob(559.0, 470.0, 8, 8)])
    assert sorted(t.cx for t in p.tracks) == [501.0, 559.0] and abs(p.a.cx - 501.0) <= 0.5


def test_a_lamp_at_the_midpoint_of_a_wide_pair_is_not_both_its_emitters_lit():
    """Both emitters lit as one blob span the baseline: a 13 x 13 px lamp between taillights
    58 px apart is another car's."""
    pr = Pairer(white_gray=WHITE)
    p = _decoded_pair(pr)
    _frame(pr, [_blob(533.0, 474.0, 13, 13)])
    assert p.tracks == [] and abs(p.a.cx - 500.5) <= 0.5 and abs(p.b.cx - 558.5) <= 0.5
