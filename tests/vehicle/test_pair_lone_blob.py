"""A decoded taillight pair whose one emitter is hidden does not carry its ID onto another car's
taillight: a lone blob smaller than its emitters, farther from where the pair predicts its
emitter than the shift estimate's error allows, does not move it (Pairer._lone_checked)."""

import numpy as np
import pytest

from receiver.core.records import Blob
from receiver.vision.pair_match import lone_gate_px
from receiver.vision.pairing import Pair, Pairer
from receiver.vision.track import Track


def _blob(cx, cy, w, h, peak=255.0):
    x0, y0 = int(round(cx - w / 2)), int(round(cy - h / 2))
    hull = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + h - 1], [x0, y0 + h - 1]], float)
    return Blob(cx=float(cx), cy=float(cy), area_px=float(w * h), hull=hull, x0=x0, y0=y0, x1=x0 + w, y1=y0 + h,
                border=False, peak=peak, level=10.0, background=2.0)


def _decoded_pair(pr, xb=560.0, y=440.0, peak=255.0, led_id=209):
    """A decoded car: taillights of 7 x 7 px at x 500 and `xb`, y `y` (60 px apart: a car ~40 m
    ahead)."""
    p = Pair(Track(3, _blob(500.0, y, 7, 7, peak), 0, 0), Track(4, _blob(xb, y, 7, 7, peak), 0, 0), ids=(10, 11))
    p.led_id, p.kind = led_id, "FV"
    pr.pairs = [p]
    pr._follow_all([], (720, 1280), 0.0, 0.0, {}, np.zeros((0, 2)))  # its first frame: the baseline
    return p


def _frame(pr, blobs):
    tracks = [Track(20 + i, b, 0, 0) for i, b in enumerate(blobs)]
    xy = np.array([(t.cx, t.cy) for t in tracks], float).reshape(-1, 2)
    return pr._follow_all(tracks, (720, 1280), 0.0, 0.0, {}, xy)


@pytest.mark.parametrize("offset_px", [7.0, 8.5])
def test_a_smaller_blob_beside_a_hidden_emitters_partner_does_not_take_the_pair(offset_px):
    pr = Pairer()
    p = _decoded_pair(pr)
    # A hidden; B dark this frame; the far car's taillight (5 x 4 px) lit beside B's place
    _frame(pr, [_blob(560.0 + offset_px, 437.0, 5, 4)])
    assert abs(p.b.cx - 560.0) < 1.0 and p.tracks == []
    # the next frame B is lit where the pair predicts it: the pair is still on its own car
    _frame(pr, [_blob(560.5, 440.0, 7, 7)])
    assert abs(p.b.cx - 560.5) <= 1.0 and [t.cx for t in p.tracks] == [560.5]


def test_its_own_emitters_blobs_still_move_it():
    pr = Pairer()
    p = _decoded_pair(pr)
    gate = lone_gate_px(pr, p)
    # a whole blob of its emitter a shake step beyond the gate: its own, it moves the pair
    _frame(pr, [_blob(560.0 + gate + 2.0, 440.0, 7, 7)])
    assert abs(p.b.cx - (560.0 + gate + 2.0)) <= 1.0
    # a clock edge's cut blob of its emitter within the gate moves it too
    other = Pairer()
    q = _decoded_pair(other)
    _frame(other, [_blob(560.0 + 0.5 * gate, 440.0, 5, 5)])
    assert [t.cx for t in q.tracks] == [560.0 + 0.5 * gate] and q.b.cx > 560.0


def test_an_undecoded_pair_is_not_held_back():
    """Before its ID, a pair has nothing to carry: a lone blob moves it within the usual gate."""
    pr = Pairer()
    p = _decoded_pair(pr)
    p.led_id = None
    _frame(pr, [_blob(568.0, 437.0, 5, 4)])
    assert [t.cx for t in p.tracks] == [568.0]
