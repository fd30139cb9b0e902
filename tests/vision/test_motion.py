"""receiver.vision.motion: the camera's frame-to-frame image shift from blob constellations."""

from __future__ import annotations

import numpy as np
import pytest

from receiver.vision.motion import vertical_shift


def _heads(rng, n):
    """n street-light heads: midpoints (px) and half baselines (px, horizontal)."""
    mid = np.column_stack([rng.uniform(100, 1100, n), rng.uniform(200, 500, n)])
    half = rng.uniform(4.0, 15.0, n)
    return mid, half


def _lit(rng, mid, half):
    """One frame's blob centroids: each head shows A, B, both merged (midpoint) or nothing."""
    out = []
    for (x, y), h in zip(mid, half):
        state = rng.integers(4)
        if state == 0:
            out.append((x - h, y))
        elif state == 1:
            out.append((x + h, y))
        elif state == 2:
            out.append((x, y))
    return np.array(out, float).reshape(-1, 2)


@pytest.mark.parametrize("seed", range(5))
def test_vertical_shift_finds_the_common_pitch_of_blinking_heads(seed):
    rng = np.random.default_rng(seed)
    mid, half = _heads(rng, 24)
    refs = np.concatenate([_lit(rng, mid, half) for _ in range(3)])  # the last frames, one view
    shift = np.array([rng.uniform(-9, 9), rng.uniform(-9, 9)])
    cur = _lit(rng, mid + shift, half) + rng.normal(0, 0.2, (1, 2))
    dy = vertical_shift(refs, cur, radius_px=14.0)
    assert dy is not None and abs(dy - shift[1]) < 1.0


# ---- pair_dx: the yaw shift from the pairs' expected places (PairSettings.shake "pairs")

def _head_offsets(dx, heads, rng):
    """Offsets (receiver.vision.motion.pair_dx) of one blob per head (half baseline h px), each
    head showing A, B or both lit at random, all shifted by dx px (+ 0.2 px noise)."""
    from numpy import array
    out = []
    for h in heads:
        kind = rng.integers(3)
        x = dx + rng.normal(0.0, 0.2) + (0.0 if kind == 2 else (-h if kind == 0 else h))
        out.append(array([x]) if kind == 2 else array([x + h, x - h]))
    return out


@pytest.mark.parametrize("dx", [-7.3, -2.0, 3.6, 8.9])
def test_pair_dx_settles_each_heads_side_by_the_others(dx):
    from receiver.vision.motion import pair_dx
    rng = np.random.default_rng(int(10 * dx) % 97)
    heads = [2.0, 2.6, 3.1, 4.4, 5.0, 6.2, 9.5]  # far to near heads: different baselines
    got = pair_dx(_head_offsets(dx, heads, rng))
    assert got is not None and abs(got - dx) <= 0.5, (got, dx)


def test_pair_dx_keeps_zero_without_yaw_and_none_without_blobs():
    from receiver.vision.motion import pair_dx
    rng = np.random.default_rng(3)
    heads = [2.0, 2.6, 3.1, 4.4, 5.0]
    assert pair_dx(_head_offsets(0.3, heads, rng)) == 0.0  # within zero_rel of the best: 0
    assert pair_dx([]) is None
    assert pair_dx([np.array([30.0])]) is None  # outside the radius: no score


def _shift_case(rng, n_prev, n_xy, n_extra, dy, integer=False):
    prev = rng.uniform(0, 200, (n_prev, 2))
    xy = prev[rng.permutation(n_prev)[:n_xy]] + [rng.normal(0, 3), dy] if n_xy <= n_prev else rng.uniform(0, 200, (n_xy, 2))
    xy = np.vstack([xy, rng.uniform(0, 200, (3, 2))])
    extra = np.column_stack([rng.normal(0, 4, n_extra), dy + rng.normal(0, 0.4, n_extra)])
    if integer:      # ties in the histogram and the median's two middles
        prev, xy, extra = np.round(prev), np.round(xy), np.round(extra * 2) / 2
    return prev, xy, extra


@pytest.mark.parametrize("seed", range(40))
def test_vertical_shift_kernel_equals_numpy(monkeypatch, seed):
    import receiver.vision.motion as motion
    if motion._k is None:
        pytest.skip("compiled kernel not built")
    rng = np.random.default_rng(seed)
    cases = [_shift_case(rng, int(rng.integers(0, 30)), int(rng.integers(0, 30)), int(rng.integers(0, 40)),
                         float(rng.uniform(-8, 8)), integer=seed % 2 == 1) for _ in range(5)]
    kw = [dict(), dict(radius_px=6.0, bin_px=0.25, refine_px=0.5, min_votes=5), dict(min_votes=1)]
    got = [[vertical_shift(p, x, extra=e, **k) for k in kw] + [vertical_shift(p, x, extra=None)]
           for p, x, e in cases]
    monkeypatch.setattr(motion, "_k", None)
    want = [[vertical_shift(p, x, extra=e, **k) for k in kw] + [vertical_shift(p, x, extra=None)]
            for p, x, e in cases]
    assert got == want          # bit-identical, None alike


def test_vertical_shift_kernel_finds_the_shift_and_rejects_bad_sizes():
    import receiver.vision.motion as motion
    if motion._k is None:
        pytest.skip("compiled kernel not built")
    rng = np.random.default_rng(3)
    prev, xy, extra = _shift_case(rng, 25, 20, 10, 4.25)
    assert abs(vertical_shift(prev, xy, extra=extra) - 4.25) < 0.5
    assert vertical_shift(np.zeros((0, 2)), np.zeros((0, 2)), extra=None) is None
    with pytest.raises(ValueError):
        motion._k.vertical_shift(np.zeros((2, 3)), np.zeros((2, 2)), np.zeros((0, 2)), 14.0, 0.5, 1.0, 3)
    with pytest.raises(ValueError):
        motion._k.vertical_shift(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((0, 2)), 14.0, 0.0, 1.0, 3)
