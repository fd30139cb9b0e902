"""receiver.vision.motion: the camera's frame-to-frame image shift from blob constellations."""

from __future__ import annotations

import numpy as np
import pytest

from receiver.vision.motion import vertical_shift, yaw_pitch_shift


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
def test_yaw_pitch_shift_finds_the_common_shift_of_blinking_heads(seed):
    rng = np.random.default_rng(seed)
    mid, half = _heads(rng, 24)
    refs = np.concatenate([_lit(rng, mid, half) for _ in range(3)])  # the last frames, one view
    shift = np.array([rng.uniform(-9, 9), rng.uniform(-9, 9)])
    cur = _lit(rng, mid + shift, half) + rng.normal(0, 0.2, (1, 2))
    got = yaw_pitch_shift(refs, cur, radius_px=14.0)
    assert got is not None
    assert abs(got[0] - shift[0]) < 1.0 and abs(got[1] - shift[1]) < 1.0
    dy = vertical_shift(refs, cur, radius_px=14.0)
    assert dy is not None and abs(dy - shift[1]) < 1.0


def test_yaw_pitch_shift_needs_agreeing_votes():
    one = np.array([[100.0, 100.0]])
    assert yaw_pitch_shift(one, one + (3.0, 2.0)) is None  # one blob: fewer than min_votes
    assert yaw_pitch_shift(np.zeros((0, 2)), one) is None
