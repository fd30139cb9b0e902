"""The compiled kernels of the S2-PSK pair stage (receiver/vision/_pairing.pyx) against their
Python references: the same decisions and the same numbers, bit for bit."""

import math
from pathlib import Path

import numpy as np
import pytest

from receiver.core.records import Blob
from receiver.vision import pairing
from receiver.vision.pairing import Pair, Pairer
from receiver.vision.track import Track

_k = pairing._k
needs_kernel = pytest.mark.skipif(_k is None, reason="compiled kernels not built (tests/engine/test_native.py fails then)")


def _blob(cx, cy, w, h, area=None):
    x0, y0 = int(math.floor(cx - w / 2)), int(math.floor(cy - h / 2))
    hull = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + h - 1], [x0, y0 + h - 1]], float)
    return Blob(cx=float(cx), cy=float(cy), area_px=float(w * h if area is None else area), hull=hull,
                x0=x0, y0=y0, x1=x0 + w, y1=y0 + h, border=False, peak=60.0, level=10.0, background=2.0)


@needs_kernel
def test_hypot_is_pythons_to_the_last_bit():
    rng = np.random.default_rng(7)
    x = rng.normal(size=20000) * 10.0 ** rng.uniform(-3, 3, 20000)
    y = rng.normal(size=20000) * 10.0 ** rng.uniform(-3, 3, 20000)
    special = [(0.0, 0.0), (-0.0, 3.0), (3.0, 4.0), (1e-310, 2e-310), (5e-324, 0.0), (1e300, 1e300),
               (-2.5, 0.0), (0.1, 0.2)]
    for a, b in list(zip(x.tolist(), y.tolist())) + special:
        assert _k.hypot_py(a, b) == math.hypot(a, b), (a, b)
    # libm's hypot (np.hypot) differs from math.hypot in the last bit for some of them: the
    # kernel must take math.hypot's where the reference does
    assert any(float(np.hypot(a, b)) != math.hypot(a, b) for a, b in zip(x.tolist(), y.tolist()))


def _scene(rng, n_pairs, n_tracks):
    """Random pairs and blobs scattered around them (most near a pair's A, B or midpoint, of
    one emitter's size, a merged blob's or another light's), some dark, some excluded."""
    pairs, items, tracks = [], [], []
    for k in range(n_pairs):
        w, h = int(rng.integers(2, 9)), int(rng.integers(1, 5))
        mx, my, hx = rng.uniform(50, 600), rng.uniform(50, 400), rng.uniform(2, 20)
        hy = rng.uniform(-1, 1) * (rng.random() < 0.5)
        a = Track(k, _blob(mx - hx, my - hy, w, h), 0, 0)
        b = Track(1000 + k, _blob(mx + hx, my + hy, w + int(rng.integers(0, 2)), h), 0, 0)
        p = Pair(a, b, ids=(2 * k, 2 * k + 1))
        p.misses = int(rng.integers(0, 4))
        p.size = float(rng.choice([0.0, w * h * rng.uniform(0.5, 2)]))
        p.led_id = None if rng.random() < 0.4 else int(rng.integers(0, 256))
        single = max(0.5 * (a.blob.area_px + b.blob.area_px), p.size, 1.0)
        pairs.append(p)
        items.append([p, (mx + rng.normal(0, 1), my + rng.normal(0, 1), hx, hy, single), ()])
        for _ in range(n_tracks):
            where = rng.choice([-1.0, 0.0, 1.0])
            kind = rng.choice(["single", "merged", "tiny", "big"])
            cw = {"single": w, "merged": w + int(round(2 * hx)), "tiny": 1, "big": 3 * w}[kind]
            ch = {"single": h, "merged": h, "tiny": 1, "big": 3 * h}[kind]
            scale = 1.0 if kind in ("single", "merged") else 0.1
            area = cw * ch * rng.uniform(0.5, 2.0) * scale if rng.random() < 0.5 else None
            x = mx + where * hx + rng.normal(0, 3 + 3 * rng.random())
            y = my + where * hy + rng.normal(0, 2)
            t = Track(len(tracks) + 5000, _blob(x, y, cw, ch, area), 0, 0)
            t.seen = bool(rng.random() < 0.85)
            tracks.append(t)
    order = rng.permutation(len(tracks))
    tracks = [tracks[i] for i in order]
    for it in items:
        if rng.random() < 0.3:
            it[2] = {t.track_id for t in tracks if rng.random() < 0.2}
    return pairs, [tuple(it) for it in items], tracks


def _reference(pr, items, tracks, claims):
    """Pairer._explain per item, and `_first_pass`'s claims, as the Python reference does."""
    xy = np.array([[t.cx, t.cy] for t in tracks], float).reshape(-1, 2)
    out = []
    for p, (mx, my, hx, hy, single), exclude in items:
        expl, near, shifts, oa, ob, mg = pr._explain(p, tracks, xy, mx, my, hx, hy, single, exclude)
        mean = tuple(float(v) for v in np.mean(shifts, axis=0)) if shifts else (0.0, 0.0)
        dy = float(np.mean([d[1] for d in shifts])) if shifts else 0.0
        claimed = []
        if claims and p.led_id is not None and len(xy):
            tol = max(pr.match_min_px, pr.match_size * math.sqrt(single))
            d = np.minimum(np.hypot(xy[:, 0] - (mx - hx), xy[:, 1] - (my - hy)),
                           np.hypot(xy[:, 0] - (mx + hx), xy[:, 1] - (my + hy)))
            claimed = [tracks[i] for i in np.flatnonzero(d <= tol) if tracks[i].seen]
        out.append((expl, near, len(shifts), mean[0], mean[1], dy, oa, ob, mg, claimed))
    return out


@needs_kernel
@pytest.mark.parametrize("seed", range(12))
def test_explain_batch_equals_explain(seed):
    rng = np.random.default_rng(seed)
    pr = Pairer()
    pr.vertical_known = bool(seed % 2)
    pairs, items, tracks = _scene(rng, int(rng.integers(1, 8)), int(rng.integers(1, 9)))
    got = pr._explain_batch(items, tracks, claims=seed % 4 != 0)
    want = _reference(pr, items, tracks, claims=seed % 4 != 0)
    assert len(got) == len(want)
    n_expl = n_near = n_claim = 0
    for g, w in zip(got, want):
        assert [id(t) for t in g[0]] == [id(t) for t in w[0]]
        assert [id(t) for t in g[1]] == [id(t) for t in w[1]]
        assert g[2] == w[2]
        if g[2]:
            assert (g[3], g[4], g[5]) == (w[3], w[4], w[5])  # exact, numpy's summation orders
        assert all(x is y for x, y in zip(g[6:9], w[6:9]))
        assert [id(t) for t in g[9]] == [id(t) for t in w[9]]
        n_expl, n_near, n_claim = n_expl + len(w[0]), n_near + len(w[1]), n_claim + len(w[9])
    assert n_near > 0  # the scenes do reach the decisions


@needs_kernel
def test_explain_batch_covers_every_branch():
    """Over many random scenes the reference takes every kind of decision the kernel must
    repeat: merged and single blobs, A's and B's own blobs, claims, excluded tracks."""
    seen = dict(merged=0, obs_a=0, obs_b=0, claims=0, many=0)
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        pr = Pairer()
        pr.vertical_known = bool(seed % 3)
        _, items, tracks = _scene(rng, 6, 8)
        got = pr._explain_batch(items, tracks, claims=True)
        want = _reference(pr, items, tracks, claims=True)
        for g, w in zip(got, want):
            assert [id(t) for t in g[0]] == [id(t) for t in w[0]] and g[2:6] == w[2:6]
            assert all(x is y for x, y in zip(g[6:9], w[6:9]))
            seen["merged"] += w[8] is not None
            seen["obs_a"] += w[6] is not None
            seen["obs_b"] += w[7] is not None
            seen["claims"] += len(w[9])
            seen["many"] += w[2] >= 8  # numpy's pairwise sum of the dys
    assert all(v > 0 for v in seen.values()), seen


_RUN = """
import json, sys
from receiver.vision import pairing
if sys.argv[2] == "pure":
    pairing._k = None
from receiver.cli.bench import load_case, whole_receiver
from receiver.io.output import frame_line
cam, m, frames, still = load_case(sys.argv[1], int(sys.argv[3]))
rx = whole_receiver(cam, m, still=still)
for f in frames:
    d = json.loads(frame_line(rx.process(f)))
    d.pop("latency_ms", None)
    d.pop("stage_ms", None)
    print(json.dumps(d, sort_keys=True))
"""


def _run(path, n, mode):
    """The JSON Lines (latency removed) of the first `n` frames of a recording, in a fresh
    process (the pairs' uids, which stagger their re-decodes, count from 0 as in `occloc run`)."""
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", _RUN, str(path), mode, str(n)], cwd=root, check=True,
                         capture_output=True, text=True).stdout
    return out.splitlines()


@needs_kernel
def test_vehicle_recording_same_with_and_without_kernel():
    rec = Path(__file__).resolve().parents[2] / "recordings" / "vehicle"
    a, b = _run(rec, 90, "kernel"), _run(rec, 90, "pure")
    assert len(a) == 90 and a == b
    assert sum('"s2psk"' in x for x in a) > 0  # pairs decoded within these frames


def _envelope(rng, cx, cy):
    """A convex envelope polygon through pixel centres around (cx, cy), with its box."""
    r = rng.uniform(0.5, 6.0, 2)
    ang = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 9))))
    pts = np.unique(np.rint(np.stack((cx + r[0] * np.cos(ang), cy + r[1] * np.sin(ang)), axis=1)), axis=0)
    import cv2
    hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(float)
    x0, y0 = int(hull[:, 0].min()), int(hull[:, 1].min())
    x1, y1 = int(hull[:, 0].max()) + 1, int(hull[:, 1].max()) + 1
    return Blob(cx=float(cx), cy=float(cy), area_px=float((x1 - x0) * (y1 - y0)), hull=hull, x0=x0, y0=y0,
                x1=x1, y1=y1, border=False, peak=200.0, level=20.0, background=3.0)


@needs_kernel
def test_mean_in_masks_equals_mean_in_mask():
    from receiver.vision.pairing import moved
    from receiver.vision.profile import mean_in_mask, mean_in_masks
    rng = np.random.default_rng(11)
    gray = rng.integers(0, 256, size=(90, 160), dtype=np.uint8)
    blobs = [_envelope(rng, rng.uniform(-3, 163), rng.uniform(-3, 93)) for _ in range(300)]
    blobs += [moved(b, b.cx + rng.normal(0, 20), b.cy + rng.normal(0, 20)) for b in blobs]  # past the edges too
    want = [mean_in_mask(gray, b) for b in blobs]
    assert mean_in_masks(gray, blobs) == want
    assert any(w == 0.0 for w in want) and any(w > 0.0 for w in want)
    assert mean_in_masks(gray, []) == []
    view = np.ascontiguousarray(np.repeat(gray, 2, axis=1))[:, ::2]  # rows not contiguous
    assert mean_in_masks(view, blobs[:50]) == [mean_in_mask(view, b) for b in blobs[:50]]


@needs_kernel
def test_peak_in_masks_equals_peak_in_mask():
    """The emitters' S2-PSK intensity (their envelope's highest gray) read in one kernel call
    equals the reference per envelope, also for envelopes past the frame's edges."""
    from receiver.vision.pairing import moved
    from receiver.vision.profile import peak_in_mask, peak_in_masks
    rng = np.random.default_rng(12)
    gray = rng.integers(0, 256, size=(90, 160), dtype=np.uint8)
    blobs = [_envelope(rng, rng.uniform(-3, 163), rng.uniform(-3, 93)) for _ in range(300)]
    blobs += [moved(b, b.cx + rng.normal(0, 20), b.cy + rng.normal(0, 20)) for b in blobs]
    want = [peak_in_mask(gray, b) for b in blobs]
    assert peak_in_masks(gray, blobs) == want
    assert any(w == 0.0 for w in want) and any(w > 0.0 for w in want)
    b = blobs[0]
    x0, y0 = max(b.x0, 0), max(b.y0, 0)
    inside = gray[y0:max(b.y1, 0), x0:max(b.x1, 0)]
    assert not inside.size or want[0] <= float(inside.max())
    assert peak_in_masks(gray, []) == []


def test_sample_all_equals_sample():
    from receiver.vision.profile import mean_in_mask, mean_in_masks
    rng = np.random.default_rng(12)
    gray = rng.integers(0, 256, size=(90, 160), dtype=np.uint8)
    made = []
    for _ in range(2):
        pairs = []
        for k in range(12):
            a = Track(k, _envelope(np.random.default_rng(k), 20 + 10 * k, 30), 0, 0)
            b = Track(100 + k, _envelope(np.random.default_rng(50 + k), 25 + 10 * k, 40), 0, 0)
            p = Pair(a, b, fresh=k % 3 == 0)
            for v in (5.0, 200.0):
                p.levels_a.add(v)
                p.levels_b.add(v + 1)
            pairs.append(p)
        made.append(pairs)
    one = [Pairer.sample(p, gray, lambda g, t: mean_in_mask(g, t.blob)) for p in made[0]]
    many = Pairer.sample_all(made[1], gray, lambda g, ts: mean_in_masks(g, [t.blob for t in ts]))
    assert one == many
    assert [list(p.levels_a.values) for p in made[0]] == [list(p.levels_a.values) for p in made[1]]
    assert not any(p.fresh for p in made[1])


def _ref_dx_offsets(pr, blobs, xy, dy, radius_px):
    """Pairer.dx_offsets as the Python loop computes it (the reference, with `_k` None)."""
    saved, pairing._k = pairing._k, None
    try:
        return pr.dx_offsets(blobs, xy, dy, radius_px)
    finally:
        pairing._k = saved


@needs_kernel
@pytest.mark.parametrize("seed", range(8))
def test_dx_offsets_kernel_equals_loop(seed):
    from receiver.vision.motion import pair_dx
    rng = np.random.default_rng(40 + seed)
    pr = Pairer()
    pairs, items, tracks = _scene(rng, int(rng.integers(1, 7)), int(rng.integers(1, 8)))
    for p, (mx, my, hx, hy, single), _ in items:
        p.base0, p.area0, p.mx, p.my = (2 * hx, 2 * hy), single, mx, my
    pr.pairs = pairs
    blobs = [t.blob for t in tracks]
    xy = np.array([(b.cx, b.cy) for b in blobs], float)
    dy = float(rng.normal(0, 1))
    want = _ref_dx_offsets(pr, blobs, xy, dy, 14.0)
    got = pr.dx_offsets(blobs, xy, dy, 14.0)
    pad = np.full((len(want), 2), np.inf)
    for k, c in enumerate(want):
        pad[k, :len(c)] = c
    assert got.shape == pad.shape and np.array_equal(got, pad)
    assert len(want) > 0
    assert pair_dx(got) == pair_dx(want)


@needs_kernel
def test_sample_fluxes_equal_head_flux():
    """The kernel's float32 sums in numpy's pairwise order: the same values to the bit, for
    boxes of a few to thousands of pixels, partly outside the frame."""
    rng = np.random.default_rng(13)
    gray = rng.integers(0, 256, size=(120, 200), dtype=np.uint8)
    gray[rng.random(gray.shape) < 0.7] = 3  # mostly background, as around a far head
    for margins in ((4.0, 3.0), (0.0, 0.0)):
        pr = Pairer()
        pr.flux_floor = float(rng.uniform(0, 5))
        pr.flux_margin_px, pr.flux_margin_y_px = margins
        _check_fluxes(rng, gray, pr)


def _check_fluxes(rng, gray, pr):
    pairs = []
    for k in range(200):
        cx, cy, hx = rng.uniform(-10, 210), rng.uniform(-5, 125), rng.uniform(0.5, 40)
        if k < 3:
            cx, hx = -100.0, 1.0  # wholly left of the frame: an empty box
        a = Track(k, _blob(cx - hx, cy, int(rng.integers(1, 6)), int(rng.integers(1, 30))), 0, 0)
        b = Track(k, _blob(cx + hx, cy, 3, int(rng.integers(1, 4))), 0, 0)
        a.blob = Blob(**{**a.blob.__dict__, "background": float(rng.uniform(0, 20))})
        p = Pair(a, b)
        p.mx, p.my = cx, cy
        pairs.append(p)
    want = [pr.head_flux(p, gray) for p in pairs]
    got = pr.sample_fluxes(pairs, gray)
    assert got == want
    assert [p.flux[-1] for p in pairs] == want
    sizes = [(x1 - x0) * (y1 - y0) for x0, x1, y0, y1, _ in (pr._flux_box(p, gray.shape) for p in pairs)]
    assert any(s <= 0 or w == 0.0 for s, w in zip(sizes, want))
    assert (min(sizes) < 8 if pr.flux_margin_px == 0 else max(sizes) > 1024)


@pytest.mark.parametrize("kernel", [True, False])
def test_empty_frames_and_pairs(kernel, monkeypatch):
    """No tracks, no pairs, pairs without tracks: both paths give the same (empty) answers."""
    if not kernel:
        monkeypatch.setattr(pairing, "_k", None)
    elif _k is None:
        pytest.skip("compiled kernels not built (tests/engine/test_native.py fails then)")
    pr = Pairer()
    gray = np.zeros((40, 60), np.uint8)
    assert pr.step(gray, [], lambda g, t: 0.0, t_s=0.0) == []
    assert pr.shift_votes(np.zeros((0, 2)), 14.0).shape == (0, 2)
    assert len(pr.dx_offsets([], np.zeros((0, 2)), 0.0, 14.0)) == 0
    assert pr.emitters() == []
    rng = np.random.default_rng(3)
    pairs, items, _ = _scene(rng, 3, 1)
    for p, (mx, my, hx, hy, single), _ in items:
        p.base0, p.area0, p.mx, p.my = (2 * hx, 2 * hy), single, mx, my
    pr.pairs = pairs
    assert pr._first_pass([], np.zeros((0, 2))) == (0.0, {})
    assert pr.shift_votes(np.zeros((0, 2)), 14.0).shape == (0, 2)
    before = {p.uid: p.misses for p in pairs}
    live = pr.step(np.zeros((480, 700), np.uint8), [], lambda g, t: 0.0, t_s=0.1)
    assert live and all(p.misses == before[p.uid] + 1 and p.tracks == [] for p in live)


@needs_kernel
def test_kernels_refuse_arrays_of_the_wrong_size():
    """The kernels read without bounds checks: every size they rely on is checked first."""
    f8, u8, i32, i64 = np.float64, np.uint8, np.int32, np.int64
    tr, pp, cfg = np.zeros((4, 8)), np.zeros((2, 14)), np.zeros(12)

    def explain(tr=tr, pp=pp, excl=np.zeros((2, 4), u8), cfg=cfg, lists=np.zeros((3, 2, 4), i32),
                res=np.zeros((2, 10)), flat=np.zeros(24, i32), mine=np.zeros((2, 4), u8)):
        return _k.explain_pairs(tr, pp, excl, cfg, lists, res, flat, mine)

    assert explain() == 8  # all four tracks lie near both pairs (everything at (0, 0)): nearby
    for bad in (dict(tr=np.zeros((4, 7))), dict(pp=np.zeros((2, 13))), dict(excl=np.zeros((2, 3), u8)),
                dict(cfg=np.zeros(11)), dict(lists=np.zeros((3, 2, 3), i32)), dict(res=np.zeros((2, 9))),
                dict(flat=np.zeros(23, i32)), dict(mine=np.zeros((1, 4), u8))):
        with pytest.raises(ValueError):
            explain(**bad)
    with pytest.raises(ValueError):
        _k.shift_votes(np.zeros((4, 2)), np.zeros((2, 4)), 14.0, np.zeros((23, 2)))
    assert _k.shift_votes(np.zeros((4, 2)), np.zeros((2, 4)), 14.0, np.zeros((24, 2))) == 24
    with pytest.raises(ValueError):
        _k.dx_offsets(np.zeros((4, 8)), pp, cfg, 0.0, 14.0, np.zeros((7, 2)))
    gray = np.zeros((10, 10), u8)
    with pytest.raises(ValueError):  # its mask would reach past the buffer
        _k.masked_means(gray, np.zeros(8, u8), np.array([[0, 0, 3, 3, 0]], i64), np.zeros(1))
    with pytest.raises(ValueError):  # inverted
        _k.masked_means(gray, np.zeros(9, u8), np.array([[3, 0, 0, 3, 0]], i64), np.zeros(1))
    with pytest.raises(ValueError):
        _k.head_fluxes(gray, np.array([[0, 11, 0, 3]], i64), np.zeros(1), np.zeros(1))
    out = np.ones(1)
    _k.head_fluxes(gray, np.array([[5, 5, 0, 3]], i64), np.zeros(1), out)  # empty: 0.0
    assert out[0] == 0.0
    with pytest.raises(ValueError):
        _k.head_fluxes(gray, np.array([[0, 3, 0, 3]], i64), np.zeros(0), np.zeros(1))
