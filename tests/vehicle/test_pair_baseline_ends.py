"""A street-light head whose two halves are separate blobs, approaching: the pair's baseline
follows the head's separation (1 / range) from frames in which both halves are seen, whatever
their blobs' areas (pair_model.both_ends). A far half covers one or two rows, so its area
doubles between frames; an envelope taken from a two-row blob made every later one-row blob a
"cut" one, and the baseline was never measured again."""

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pairing import Pair, Pairer
from receiver.vision.track import Track

FOCAL_PX = 1400.0
HALVES_M = 0.6  # centre to centre, across the road
MID_X, Y = 600.0, 300.0


def _blob(cx, cy, w, h, peak=60.0):
    x0, y0 = int(round(cx - w / 2)), int(round(cy - h / 2))
    hull = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + h - 1], [x0, y0 + h - 1]], float)
    return Blob(cx=float(cx), cy=float(cy), area_px=float(w * h), hull=hull, x0=x0, y0=y0, x1=x0 + w, y1=y0 + h,
                border=False, peak=peak, level=10.0, background=8.0)


def _sep_px(k):
    """The head's separation in frame k (px): 100 m away at first, approaching at 15 m/s."""
    return FOCAL_PX * HALVES_M / (100.0 - 0.5 * k)


def _run(frames):
    pr = Pairer()
    s0 = _sep_px(0)
    p = Pair(Track(3, _blob(MID_X - s0 / 2, Y, 3, 2), 0, 0), Track(4, _blob(MID_X + s0 / 2, Y, 3, 2), 0, 0),
             ids=(10, 11))
    p.led_id, p.kind = 7, "SL"
    pr.pairs = [p]
    pr._follow_all([], (720, 1280), 0.0, 0.0, {}, np.zeros((0, 2)))  # its first frame: the baseline
    for k in range(1, frames + 1):
        s = _sep_px(k)
        ax, bx = MID_X - s / 2, MID_X + s / 2
        # S2-PSK: both halves lit, A only, B only, both dark; a lone lit half shows two rows,
        # the two lit together one row each (a clock edge, the blur)
        blobs = [[_blob(ax, Y, 3, 1), _blob(bx, Y, 3, 1)], [_blob(ax, Y, 3, 2)], [_blob(bx, Y, 3, 2)], []][k % 4]
        tracks = [Track(20 + i, b, 0, 0) for i, b in enumerate(blobs)]
        xy = np.array([(t.cx, t.cy) for t in tracks], float).reshape(-1, 2)
        pr.pairs = pr._follow_all(tracks, (720, 1280), 0.0, 0.0, {}, xy)
    return p, pr, _sep_px(frames)


def test_an_approaching_heads_baseline_follows_its_separation():
    p, pr, sep = _run(120)
    assert p in pr.pairs
    assert sep > 1.8 * _sep_px(0)  # the head came twice as near
    assert abs(p.b.cx - p.a.cx - sep) <= 0.1 * sep
    assert abs(p.a.cx - (MID_X - sep / 2)) <= 1.5 and abs(p.b.cx - (MID_X + sep / 2)) <= 1.5


def test_the_vertical_part_is_not_taken_from_cut_blobs():
    """A blob cut by a clock edge loses rows: only the horizontal part is measured from it."""
    p, _, _ = _run(40)
    assert p.base is not None and abs(p.base[1]) < 0.5
