"""The compiled envelope hull (receiver/vision/_envelope.pyx, `convex_hull_f32`) on ties whose
bits differ: -0.0 and 0.0 sort as equal (OpenCV compares floats), so among equal points the
input position decides which one's bits the hull reports, as cv2.convexHull does."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from receiver.core.native import load

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
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), p.tolist()
        signed += int(np.signbit(want[want == 0]).any())
    assert signed > 100  # the hulls did report -0.0 vertices: the tie order was tested
