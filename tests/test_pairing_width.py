"""Width-based size test and baseline re-measurement of S2-PSK pairs (PairSettings.width_size,
measure_baseline; opt-in): a far street-light half is one or two rows tall, so its area doubles
between frames while its width holds, and a merged both-lit blob is one baseline wider."""

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
    pr = Pairer(width_size=True)
    p = _jumper(hx=6.0, w=10)
    assert pr._width_class(p, _blob(100, 50, 10, 2), 6.0) == "single"  # twice the area, same width
    assert pr._width_class(p, _blob(100, 50, 22, 1), 6.0) == "merged"  # one baseline (12 px) wider
    assert pr._width_class(p, _blob(100, 50, 16, 1), 6.0) is None      # neither
    assert pr._width_class(p, _blob(100, 50, 22, 5), 6.0) is None      # tall: its area tells
    assert Pairer()._width_class(p, _blob(100, 50, 10, 2), 6.0) is None  # off by default


def test_merged_width_remeasures_a_short_baseline():
    pr = Pairer(width_size=True, measure_baseline=True)
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


def test_off_by_default_keeps_the_area_scaled_baseline():
    pr = Pairer()
    p = _jumper(hx=4.5, w=10)
    pr._measure_baseline(p, 4.5, 0.0, None, None, _blob(100, 50, 22, 1))  # called directly: measures
    q = _jumper(hx=4.5, w=10)
    assert pr._predict(q)[2] == pytest.approx(4.5)
    assert not pr.measure_baseline and not pr.width_size


def _explain(pr, p, blob):
    t = Track(9, blob, 0, 0)
    mx, my, hx, hy, single = pr._predict(p)
    return pr._explain(p, [t], np.array([[t.cx, t.cy]]), mx, my, hx, hy, single)


def test_width_takes_a_taller_half_but_not_a_cut_one():
    pr = Pairer(width_size=True)
    # one-row envelopes: the same half seen over two rows (twice the area) is its emitter A
    p = _jumper(hx=6.0, w=10, h=1)
    expl, _, shifts, obs_a, obs_b, merged = _explain(pr, p, _blob(94.0, 50.0, 10, 2))
    assert len(expl) == 1 and obs_a is not None and obs_b is None and merged is None
    assert Pairer()._explain(p, [Track(9, _blob(94.0, 50.0, 10, 2), 0, 0)], np.array([[94.0, 50.0]]),
                             *Pairer()._predict(p))[0] == []  # by area: "another light's"
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
