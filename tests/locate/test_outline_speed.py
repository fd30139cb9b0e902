"""Speed of the outline path (receiver.vision.outline, receiver.locate.outline_pose): the edge
points of one frame, batched over its LEDs, and one warm-started outline solve, as
pytest-benchmark tests (skipped in timing under the project's --benchmark-disable: run with
`pytest tests/locate/test_outline_speed.py --benchmark-enable`), plus the checks that make the fast
paths safe: the batch equals the per-LED points, the analytic Jacobian equals central
differences."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.io.sources import open_source
from receiver.locate import outline_pose
from receiver.locate.indoor import Positioner
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS
from receiver.pipeline import Receiver
from receiver.vision.detect import detect
from receiver.vision.outline import stripe_edge_points, stripe_edge_points_batch

WALK = Path(__file__).resolve().parents[2] / "recordings" / "indoor-walk"
STATIC = Path(__file__).resolve().parents[2] / "recordings" / "indoor-static"


def _frame_blobs(folder, k=5):
    for i, f in enumerate(open_source(str(folder))):
        if i == k:
            return f.gray, detect(f.gray)
    raise AssertionError("recording too short")


def test_edge_points_batch_equals_per_led():
    for folder in (WALK, STATIC):
        gray, blobs = _frame_blobs(folder)
        assert blobs
        batch = stripe_edge_points_batch(gray, blobs)
        for b, (p, s) in zip(blobs, batch):
            p1, s1 = stripe_edge_points(gray, b)
            assert np.array_equal(p, p1) and np.array_equal(s, s1)
        assert sum(len(p) for p, _ in batch) > 0


def test_edge_points_frame_benchmark(benchmark):
    gray, blobs = _frame_blobs(WALK)
    out = benchmark(stripe_edge_points_batch, gray, blobs)
    assert len(out) == len(blobs)


def _warm_problem(folder, k):
    """(targets, R0, C0, solve keywords) of frame k of a recording as the Positioner's warm start
    sees them (the tracked orientation and the filter's predicted position)."""
    cam, led_map = load_camera(str(folder / "camera.yaml")), load_map(str(folder / "map.json"))
    pos = Positioner(cam, led_map)
    rx = Receiver(cam, led_map, positioner=pos)
    seen = {}
    step = pos.step

    def spy(t_s, leds):
        items = pos.ranger.usable(leds)
        frame, _ = pos._outline_targets(t_s, leds, items)
        targets = frame.targets if frame is not None else []
        R0 = pos.pose.R_prior(t_s)
        pred = pos.pose.kf.predict_at(t_s) if pos.pose.kf is not None else None
        if R0 is not None and pred is not None:
            seen["warm"] = (targets, R0, pred[0][:3])
        return step(t_s, leds)

    pos.step = spy
    for i, f in enumerate(open_source(str(folder))):
        seen.pop("warm", None)
        rx.process(f)
        if i == k:
            break
    targets, R0, C0 = seen["warm"]
    s = pos.settings
    kw = {"focal_px": cam.focal_px, "centroid_sigma_px": outline_pose.DEFAULT_CENTROID_SIGMA_PX,
          "up_prior": np.array([0.0, 0.0, 1.0]), "tilt_sigma_rad": np.radians(s.tilt_sigma_deg),
          "loss": DEFAULT_LOSS, "f_scale": DEFAULT_F_SCALE}
    return targets, R0, C0, kw


def test_outline_solve_frame_benchmark(benchmark):
    targets, R0, C0, kw = _warm_problem(WALK, 20)
    fix = benchmark(outline_pose.solve_outline_pose, targets, R0, C0, **kw)
    assert fix is not None and fix.chi2 / fix.dof < 4.0
    # A start 1 cm further off lands within a few mm (the edge assignment near the corners
    # depends on the start: different points are left out, ~1-2 mm).
    far = outline_pose.solve_outline_pose(targets, R0, C0 + np.array([0.01, -0.006, 0.004]), **kw)
    assert far is not None and far.chi2 / far.dof < 4.0 and np.linalg.norm(far.C - fix.C) < 3e-3


def _circle_targets(rng, n=5):
    """n circles on a 3 m ceiling with noisy normalized edge points, seen from below."""
    out = []
    for _ in range(n):
        xyz = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 3.0])
        r = rng.uniform(0.05, 0.15)
        a = rng.uniform(0, 2 * np.pi, 40)
        pts = (xyz[:2] + r * np.column_stack([np.cos(a), np.sin(a)])) / 2.0 + rng.normal(0, 1e-4, (40, 2))
        out.append(outline_pose.OutlineTarget(xyz, "circle", (r, r), pts, np.full(40, 1e-3)))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_batched_circles_equal_the_per_circle_residuals(seed):
    """`_Problem._circles` (all circles at once, through the conic R Q R^T) equals the per-circle
    `_circle_residuals` (through H^-T diag(1, 1, -r^2) H^-1), and a circle seen edge-on gets
    residuals of 1e3 without spoiling the others."""
    rng = np.random.default_rng(seed)
    targets = _circle_targets(rng)
    prob = outline_pose._Problem(targets, 1000.0, 1.0, None, 0.1)      # circle residuals only
    p = np.concatenate([rng.normal(0, 0.05, 3), [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 1.0]])

    def ref(q):
        Rq, _ = cv2.Rodrigues(q[:3].reshape(3, 1))
        return np.concatenate([outline_pose._circle_residuals(t, Rq, q[3:]) for t in targets])

    r = prob.residuals(p)[0]
    assert np.allclose(r, ref(p), rtol=1e-9, atol=1e-12)
    # The first circle edge-on: its centre in the plane through the camera centre spanned by
    # R e_x and R e_y (here the camera sits at the circle's height).
    flat = [outline_pose.OutlineTarget(np.array([0.5, 0.0, 1.0]), "circle", (0.1, 0.1), targets[0].pts,
                                       targets[0].sigma)] + targets[1:]
    prob = outline_pose._Problem(flat, 1000.0, 1.0, None, 0.1)
    p0 = np.zeros(6)
    p0[5] = 1.0
    r0 = prob.residuals(p0)[0]
    n0 = len(targets[0].pts)
    assert np.all(r0[:n0] == 1e3) and np.all(np.abs(r0[n0:]) < 1e3)


def test_point_beyond_a_corner_goes_to_the_first_edge_whatever_the_rounding():
    """A point past a corner (its nearest point on both edges meeting there is that corner) is a
    tie: it goes to the first of the two edges at every pose near it, not to whichever the
    rounding of the two segments' arithmetic favours (which made runs flip labels, and move
    fixes by millimetres, on float-order changes)."""
    h = 0.1
    beyond = np.array([[h / 3 + 0.01, h / 3 + 0.012],       # past corner 0 (+x, +y): edges 3 and 0
                       [-h / 3 - 0.011, -h / 3 - 0.01]])    # past corner 2 (-x, -y): edges 1 and 2
    on_edge = np.array([[0.0, h / 3], [h / 3, 0.0]])        # on edges 0 and 3
    t = outline_pose.OutlineTarget(np.array([0.0, 0.0, 3.0]), "square", (h, h), np.vstack([beyond, on_edge]),
                                   np.full(4, 1e-3))
    rng = np.random.default_rng(0)
    for _ in range(50):
        prob = outline_pose._Problem([t], 1000.0, 1.0, None, 0.1)
        p = np.concatenate([rng.normal(0, 1e-12, 3), rng.normal(0, 1e-12, 3)])
        prob.assign(p)
        assert prob.labels.tolist() == [0, 1, 0, 3]
