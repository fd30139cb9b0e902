"""The positioner's compiled pose filter (receiver.locate.fastfilter) against PoseFilter, the
numpy reference: the same position objects frame for frame (keys in order, numbers to rounding of
the last printed digit), and the positioner takes it exactly when the kernels are built."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from receiver.core import native
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.locate.fastfilter import KERNEL, CompiledPoseFilter, pose_filter_class
from receiver.locate.indoor import Positioner
from receiver.locate.lsq import Fix
from receiver.locate.pose import ypr_to_rotation
from receiver.locate.posefilter import PoseFilter

WALK = Path(__file__).resolve().parents[2] / "recordings" / "indoor-walk"


def _close(a, b, path=""):
    """Equal structure and keys in order; floats within one unit of their printed last digit."""
    if isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b)):
            _close(u, v, f"{path}[{i}]")
    elif isinstance(a, float):
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1.01e-5), (path, a, b)
    else:
        assert a == b, path


def test_compiled_filter_gives_posefilter_positions(monkeypatch):
    """A walk of 300 frames with noisy fixes, fixes without orientation, coasting gaps and an
    outlier: every position object of the compiled filter equals PoseFilter's."""
    monkeypatch.delenv("OCCLOC_PURE", raising=False)
    assert native.load(KERNEL) is not None, "receiver.locate._kalman is not built (tools/dev reinstalls it)"
    kw = dict(handedness="right", sigma_uv=1e-3)
    ref, fast = PoseFilter(**kw), pose_filter_class()(**kw)
    assert isinstance(fast, CompiledPoseFilter)
    rng = np.random.default_rng(3)
    C = np.array([1.0, 2.0, 0.0])
    for i in range(300):
        t = i / 30
        C = C + np.array([0.01, 0.004, 0.0])
        fix = None
        if i % 23 not in (7, 8, 9):
            A = rng.normal(0, 0.01, (3, 3))
            R = ypr_to_rotation(*rng.uniform(-30, 30, 3)) if i % 5 else None
            z = C + rng.normal(0, 0.01, 3) + (3.0 if i == 100 else 0.0)
            fix = Fix(z, A @ A.T + 1e-6 * np.eye(3), R, "outline", 4)
        a, b = ref.update(t, fix, 4), fast.update(t, fix, 4)
        assert (a is None) == (b is None), i
        if a is not None:
            _close(a, b, f"frame {i}")


@pytest.mark.parametrize("pure", [False, True])
def test_positioner_takes_the_compiled_filter_when_built(monkeypatch, pure):
    if pure:
        monkeypatch.setenv("OCCLOC_PURE", "1")
    else:
        monkeypatch.delenv("OCCLOC_PURE", raising=False)
    p = Positioner(load_camera(str(WALK / "camera.yaml")), load_map(str(WALK / "map.json")))
    assert isinstance(p.pose, CompiledPoseFilter) is (not pure)
    assert isinstance(p.pose, PoseFilter)


def test_fast_kalman_predict_at_equals_position_kalman(monkeypatch):
    """FastKalman.predict_at (the compiled predict step on copies) is PositionKalman's to rounding,
    None where it is None, and leaves the filter's state as it was."""
    from receiver.locate.fastfilter import FastKalman
    from receiver.locate.kalman import PositionKalman
    monkeypatch.delenv("OCCLOC_PURE", raising=False)
    ref, fast = PositionKalman(), FastKalman(native.load(KERNEL))
    rng = np.random.default_rng(5)
    assert fast.predict_at(0.0) is None
    for i in range(60):
        t = i / 30
        z = np.array([1.0 + 0.02 * i, 2.0, 0.5]) + rng.normal(0, 0.01, 3)
        ref.step(t, z, 1e-4 * np.eye(3))
        fast.step(t, z, 1e-4 * np.eye(3))
        before = fast.state
        for ahead in (0.0, 1 / 60, 0.5, 2.5):
            a, b = ref.predict_at(t + ahead), fast.predict_at(t + ahead)
            assert (a is None) == (b is None), (i, ahead)
            if a is not None:
                np.testing.assert_allclose(b[0], a[0], rtol=1e-10, atol=1e-12)
                np.testing.assert_allclose(b[1], a[1], rtol=1e-9, atol=1e-16)
        assert fast.predict_at(t - 0.1) is None
        np.testing.assert_array_equal(fast.state[0], before[0])
        np.testing.assert_array_equal(fast.state[1], before[1])
