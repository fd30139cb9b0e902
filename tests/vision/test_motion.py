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


def test_vertical_shift_without_enough_votes_is_none():
    assert vertical_shift(np.zeros((0, 2)), np.zeros((0, 2)), extra=None) is None
    assert vertical_shift(np.zeros((1, 2)), np.array([[50.0, 50.0]])) is None      # beyond the radius
