"""The pair stage's cheaper forms of numpy / dataclasses calls give the same values:
`moved` (a record built as `frozen_record` builds it instead of dataclasses.replace),
`pair_observation` (likewise, instead of the constructor), `Pairer.flux_on` (a sorted list's
middle instead of np.median), the levels cached between adds."""

import dataclasses

import numpy as np
import pytest

from receiver.core.records import Blob, PairObservation
from receiver.pipeline import pair_observation
from receiver.vision import pair_read
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


# -- the per-frame loops over pairs, as one array computation -----------------------------------

def _ref_shift_votes(pr, xy, radius_px):
    """Pairer.shift_votes as a loop over the pairs (the reference)."""
    out = []
    if len(xy) == 0:
        return np.zeros((0, 2))
    for p in pr.pairs:
        if p.base0 is None:
            continue
        mx, my, hx, hy, _ = pr._predict(p)
        d = xy - (mx, my)
        d = d[(np.abs(d[:, 0]) <= radius_px + abs(hx)) & (np.abs(d[:, 1]) <= radius_px + abs(hy))]
        if len(d):
            out += [d, d + (hx, hy), d - (hx, hy)]
    return np.concatenate(out) if out else np.zeros((0, 2))


def _ref_emitters(pr):
    """Pairer.emitters with a loop per emitter for the overlap checks (the reference; which
    emitters may be reported at all is `pair_read.decoded_emitters`, shared)."""
    live = pair_read.live_pairs(pr, pr.pairs)
    dec = pair_read.decoded_emitters(pr, live)
    xy = np.array([(b.cx, b.cy) for _, b, _, _ in dec], float).reshape(-1, 2)
    owner = np.array([id(p) for _, _, p, _ in dec])
    size = np.array([max(p.a.blob.area_px, p.b.blob.area_px) for _, _, p, _ in dec], float)
    out = []
    for k, (i, b, p, own) in enumerate(dec):
        other = owner != id(p)
        d = np.hypot(*(xy - (b.cx, b.cy)).T)[other]
        area = np.maximum(size[k], size[other])
        if own or not d.size or (d > np.maximum(pr.match_min_px, pr.match_size * np.sqrt(np.maximum(area, 1.0)))).all():
            out.append((i, b, p))
    for p in live:
        if p.led_id is None:
            for i, e in zip(p.ids, (p.a, p.b)):
                if not len(xy) or np.hypot(*(xy - (e.blob.cx, e.blob.cy)).T).min() > pr.match_min_px:
                    out.append((i, e.blob, p))
    return out


def _random_pairs(rng, pr, n):
    pr.pairs = []
    for k in range(n):
        mx, my, hx = rng.uniform(20, 200), rng.uniform(20, 120), rng.uniform(2, 12)
        a = Track(k, _blob(mx - hx, my), 0, 0)
        b = Track(k if rng.random() < 0.4 else 100 + k, _blob(mx + hx, my + rng.normal(0, 1)), 0, 0)
        p = Pair(a, b, ids=(2 * k, 2 * k + 1))
        if rng.random() < 0.8:
            p.base0, p.area0, p.mx, p.my = (2 * hx, 0.0), 15.0, mx, my
            p.vx, p.vy = rng.normal(0, 1), rng.normal(0, 1)
        p.led_id = int(rng.integers(0, 256)) if rng.random() < 0.6 else None
        p.misses = int(rng.integers(0, 5))
        p.frames = int(rng.integers(1, 30))
        p.seen_a, p.seen_b = p.frames - int(rng.integers(0, 8)), p.frames - int(rng.integers(0, 8))
        p.anchored, p.beside = bool(rng.random() < 0.8), bool(rng.random() < 0.1)
        pr.pairs.append(p)


@pytest.mark.parametrize("kernel", [True, False])
def test_shift_votes_and_emitters_equal_their_loops(kernel, monkeypatch):
    from receiver.vision import pairing
    if not kernel:
        monkeypatch.setattr(pairing, "_k", None)  # the numpy path
    rng = np.random.default_rng(8)
    kept = 0
    for trial in range(60):
        pr = Pairer()
        _random_pairs(rng, pr, int(rng.integers(0, 12)))
        xy = rng.uniform(0, 220, size=(int(rng.integers(0, 30)), 2))
        got, want = pr.shift_votes(xy, 14.0), _ref_shift_votes(pr, xy, 14.0)
        assert got.shape == want.shape and np.array_equal(got, want)
        e1, e0 = pr.emitters(), _ref_emitters(pr)
        assert [(i, b, id(p)) for i, b, p in e1] == [(i, b, id(p)) for i, b, p in e0]
        kept += len(e0) < sum(2 for p in pr.pairs if p.misses <= pr.report_coast_frames)
    assert kept > 0  # some emitters were left out by the gates


def _ref_pair_dx(offsets, *, radius_px=14.0, sigma_px=1.5, step_px=0.25, zero_rel=0.15, min_score=1.0):
    if not offsets:
        return None
    grid = np.arange(-radius_px, radius_px + 0.5 * step_px, step_px)
    score = np.zeros(len(grid))
    for c in offsets:
        score += np.exp(-0.5 * ((grid[:, None] - np.asarray(c, float)[None, :]) / sigma_px) ** 2).max(axis=1)
    i = int(np.argmax(score))
    if score[i] < min_score:
        return None
    if float(np.interp(0.0, grid, score)) >= (1.0 - zero_rel) * score[i]:
        return 0.0
    return float(grid[i])


def test_pair_dx_equals_its_loop():
    from receiver.vision.motion import pair_dx
    rng = np.random.default_rng(9)
    for _ in range(300):
        shift = rng.uniform(-8, 8)
        offsets = [np.array([shift + rng.normal(0, 1)]) if rng.random() < 0.4 else
                   np.array([shift + rng.normal(0, 1), shift + rng.uniform(4, 12) * rng.choice([-1, 1])])
                   for _ in range(int(rng.integers(0, 25)))]
        assert pair_dx(offsets) == _ref_pair_dx(offsets)


def test_predictions_memo_until_a_pair_moves():
    """`Pairer._predictions` (read by shift_votes, dx_offsets and _first_pass of one frame) equals
    `_predict` of every formed pair, is computed once, and is recomputed after a pair follows,
    after a step and for another pairs list."""
    rng = np.random.default_rng(21)
    pr = Pairer()
    _random_pairs(rng, pr, 9)
    first = pr._predictions()
    assert [(id(p), q) for p, q in first] == [(id(p), pr._predict(p)) for p in pr.pairs if p.base0 is not None]
    assert pr._predictions() is first  # reused within the frame
    p = first[0][0]
    pr._follow(p, [], np.zeros((0, 2)), None)  # the pair moves (coasts one frame)
    again = pr._predictions()
    assert again is not first and again[0][1] == pr._predict(p) != first[0][1]
    pr.pairs = list(pr.pairs)  # another list
    assert pr._predictions() is not again
    pr.step(None, [], lambda g, t: 0.0)
    assert pr._preds is None


def test_pair_observation_is_the_constructor():
    a, b = _blob(100.0, 50.0), _blob(130.0, 52.0)
    for obs_a, led_id in ((None, None), ((a, 3), 5)):
        p = Pair(Track(1, a, 0, 0), Track(2, b, 0, 0), led_id=led_id, kind="SL" if led_id else None,
                 obs_a=obs_a, obs_b=(b, 4), frames=7, both_seen=bool(led_id))
        got = pair_observation(p, white_gray=200.0)
        want = PairObservation(key=p.key, led_id=p.reported_id, kind=p.kind, a_px=(a.cx, a.cy), b_px=(b.cx, b.cy),
                               area_a_px=a.area_px, area_b_px=b.area_px, separation_px=float(np.hypot(30.0, 2.0)),
                               both_visible=p.both_seen, a_seen=None if obs_a is None else ((a.cx, a.cy), a.area_px, 4),
                               b_seen=((b.cx, b.cy), b.area_px, 3), founding=(1, 2), a_saturated=True,
                               b_saturated=True)
        assert got == want and list(got.__dict__) == list(want.__dict__)
