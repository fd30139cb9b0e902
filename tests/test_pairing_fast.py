"""The pair stage's cheaper forms of numpy / dataclasses calls give the same values:
`moved` (the Blob constructor instead of dataclasses.replace), `Pairer.flux_on` (a sorted
list's middle instead of np.median), the levels cached between adds."""

import dataclasses

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pairing import EmitterLevels, Pair, Pairer, moved
from receiver.vision.track import Track


def _blob(cx, cy):
    hull = np.array([[cx - 2, cy - 1], [cx + 2, cy - 1], [cx + 2, cy + 1], [cx - 2, cy + 1]], float)
    return Blob(cx=cx, cy=cy, area_px=15.0, hull=hull, x0=int(cx) - 2, y0=int(cy) - 1, x1=int(cx) + 3,
                y1=int(cy) + 2, border=True, peak=201.0, level=40.0, background=3.5)


def test_moved_is_dataclasses_replace():
    rng = np.random.default_rng(2)
    for _ in range(200):
        b = _blob(float(rng.uniform(10, 500)), float(rng.uniform(10, 300)))
        cx, cy = b.cx + rng.normal(0, 4), b.cy + rng.normal(0, 4)
        got = moved(b, cx, cy)
        dx, dy = int(round(cx - b.cx)), int(round(cy - b.cy))
        if dx == 0 and dy == 0:
            assert got is b
            continue
        want = dataclasses.replace(b, cx=b.cx + dx, cy=b.cy + dy, hull=b.hull + (dx, dy), x0=b.x0 + dx,
                                   x1=b.x1 + dx, y0=b.y0 + dy, y1=b.y1 + dy)
        for f in dataclasses.fields(Blob):
            g, w = getattr(got, f.name), getattr(want, f.name)
            assert np.array_equal(g, w) if f.name == "hull" else (g == w and type(g) is type(w)), f.name


def test_flux_on_is_twice_numpy_median():
    rng = np.random.default_rng(4)
    pr = Pairer()
    t = Track(1, _blob(100.0, 50.0), 0, 0)
    for _ in range(300):
        p = Pair(t, t)
        for _ in range(int(rng.integers(0, 60))):
            p.flux.append(float(rng.choice([0.0, rng.uniform(0, 2 * pr.flux_min), rng.normal(900, 300)])))
        lit = [v for v in p.flux if v > pr.flux_min][-pr.flux_recent:]
        want = 2.0 * float(np.median(lit)) if lit else 0.0
        assert pr.flux_on(p) == want


def test_levels_cached_until_the_next_value():
    lv = EmitterLevels(history=5)
    assert (lv.on, lv.off) == (0.0, 0.0)
    for v in (10.0, 200.0, 30.0, 180.0, 20.0, 250.0, 5.0):
        lv.add(v)
        on, off = lv.on, lv.off
        assert (on, off) == tuple(float(x) for x in np.percentile(list(lv.values), (90.0, 10.0)))
        assert (lv.on, lv.off) == (on, off)
