"""The compiled envelope kernels (receiver/vision/_envelope.pyx): the hull (`convex_hull_f32`) on
ties whose bits differ (-0.0 and 0.0 are equal points, as OpenCV compares floats), and hulls
the merge does not take refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from receiver.core.native import require
from tests.engine.test_track_kernels import same_hull

_env = require("receiver.vision._envelope")


def test_hull_of_signed_zero_ties_equals_opencv():
    rng = np.random.default_rng(11)
    signed = 0
    for t in range(3000):
        n = int(rng.integers(1, 60 if t % 2 else 20))  # short (insertion sort) and long (merge) inputs
        p = rng.integers(-2, 3, size=(n, 2)).astype(np.float32)
        p[rng.random((n, 2)) < 0.5] *= -1  # 0.0 -> -0.0 in about half the zeros
        if (p == p[0]).all():
            continue  # one point in several spellings: this port returns no vertex, cv2 one (not this test)
        want = cv2.convexHull(p.reshape(-1, 1, 2)).reshape(-1, 2)
        got = np.array(_env.convex_hull_f32(p), np.float32).reshape(-1, 2)
        assert same_hull(got, want), p.tolist()
        signed += int(np.signbit(want[want == 0]).any())
    assert signed > 100  # the inputs did hold -0.0 ties


def test_envelope_history_refuses_hulls_the_merge_does_not_take():
    """Blobs whose hulls are not (K, 2) float64 (here int32): the kernel declines (None) and the
    history says so with a ValueError."""
    import dataclasses
    from receiver.cli.benchscene import bench_scene, render_bench_frame
    from receiver.vision.detect import detect
    from receiver.vision.envelope import EnvelopeHistory
    from receiver.vision.track import Track

    g = render_bench_frame(bench_scene(n_leds=4, radius_px=30.0, seed=5), 0, rng=np.random.default_rng(0))
    blobs = detect(g, stripe_gap_px=12)
    assert len(blobs) == 4
    hist = EnvelopeHistory(3)
    assert sorted(hist.step([Track(i, b, 0, 0) for i, b in enumerate(blobs)], 0, g.shape)) == [0, 1, 2, 3]
    tracks = [Track(i, dataclasses.replace(b, hull=np.round(b.hull).astype(np.int32)), 0, 1)
              for i, b in enumerate(blobs)]
    assert _env.merge(tracks, 1, [], g.shape[1], g.shape[0]) is None
    with pytest.raises(ValueError, match="float64"):
        hist.step(tracks, 1, g.shape)
