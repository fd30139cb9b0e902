"""The compiled envelope kernels (receiver/vision/_envelope.pyx): the hull (`convex_hull_f32`) on
ties whose bits differ (-0.0 and 0.0 are equal points, as OpenCV compares floats), and the
merge's fallback to the OpenCV path for hulls it does not take."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from receiver.core.native import load
from tests.engine.test_track_kernels import same_hull

_env = load("receiver.vision._envelope")
needs_kernel = pytest.mark.skipif(_env is None, reason="kernels not built or OCCLOC_PURE=1 (test_native checks the build)")


@needs_kernel
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


@needs_kernel
def test_envelope_merge_declines_hulls_it_does_not_take(monkeypatch):
    """The compiled merge reads the blobs' float64 hulls itself; a history whose blobs carry
    other hulls (int32) is merged by the pure path, as with no kernel at all."""
    import dataclasses
    from receiver.cli.benchscene import bench_scene, render_bench_frame
    from receiver.vision import envelope
    from receiver.vision.detect import detect
    from receiver.vision.envelope import EnvelopeHistory
    from receiver.vision.track import Track

    leds = bench_scene(n_leds=4, radius_px=30.0, seed=5)
    frames = [render_bench_frame(leds, k, rng=np.random.default_rng(k)) for k in range(4)]

    def run():
        hist, got = EnvelopeHistory(3), []
        for k, g in enumerate(frames):
            tracks = [Track(i, dataclasses.replace(b, hull=np.round(b.hull).astype(np.int32)), 0, k, vx=0.5, vy=-0.25)
                      for i, b in enumerate(detect(g, stripe_gap_px=12))]
            if _env is not None:
                assert _env.merge(tracks, k, [], g.shape[1], g.shape[0]) is None
            got.append(hist.step(tracks, k, g.shape))
        return got

    native = run()
    with monkeypatch.context() as m:
        m.setattr(envelope, "_k", None)
        pure = run()
    merged = 0
    for a, b in zip(native, pure):
        assert a.keys() == b.keys()
        for tid in a:
            assert a[tid].__dict__.keys() == b[tid].__dict__.keys()
            assert np.array_equal(a[tid].hull, b[tid].hull) and a[tid].hull.dtype == b[tid].hull.dtype
            assert (a[tid].cx, a[tid].cy, a[tid].area_px, a[tid].x0, a[tid].y1) == \
                (b[tid].cx, b[tid].cy, b[tid].area_px, b[tid].x0, b[tid].y1)
            merged += a[tid].hull.dtype == np.float64  # merged envelopes (float hulls)
    assert merged > 4
