"""Cold starts from the panels alone (`outline_pose.panel_start_poses`, `Positioner._panel_fix`):
a phone tilted 25 degrees sees one whole square panel and part of another, no track; the solve
from the panel starts finds the true pose, and a lone square (four poses that fit equally) gives
no fix unless a tracked orientation picks one."""

import math

import numpy as np

from receiver.core.records import LedObservation
from receiver.io.camera import CameraModel
from receiver.io.ledmap import parse_map
from receiver.locate.indoor import Positioner
from receiver.locate.outline_pose import OutlineFrame, OutlineTarget, panel_start_poses
from receiver.locate.pose import ypr_to_rotation

HALF = 0.125
CEILING = 2.8


def _camera():
    K = np.array([[1100.0, 0, 640.0], [0, 1100.0, 360.0], [0, 0, 1]])
    return CameraModel(1280, 720, K, np.zeros(5), fps=30.0)


def _map():
    leds = [{"id": 100 + i, "mode": "ook", "x": 1.1 * i, "y": 0.0, "z": CEILING, "shape": "square",
             "size": [2 * HALF, 2 * HALF], "rate_hz": 20000} for i in range(2)]
    return parse_map({"units": "m", "addressing": "map", "leds": leds})


def _edge_points(R, C, L, keep=None):
    """Normalized image points along the 4 projected edges of the square at L (corners left out)."""
    s = np.linspace(0.08, 0.92, 40)
    c = L + np.array([[HALF, HALF, 0], [-HALF, HALF, 0], [-HALF, -HALF, 0], [HALF, -HALF, 0]])
    X = np.concatenate([c[i] + s[:, None] * (c[(i + 1) % 4] - c[i]) for i in range(4)])
    Xc = (X - C) @ R.T
    uv = Xc[:, :2] / Xc[:, 2:3]
    if keep is not None:
        uv = uv[keep(uv)]
    Lc = R @ (L - C)
    return uv, Lc[:2] / Lc[2]


def _frame(R, C, partial=True):
    rng = np.random.default_rng(5)
    a_pts, a_uv = _edge_points(R, C, np.array([0.0, 0.0, CEILING]))
    targets = [OutlineTarget(np.array([0.0, 0.0, CEILING]), "square", (HALF, HALF),
                             a_pts + rng.normal(0, 0.1 / 1100, a_pts.shape), np.full(len(a_pts), 0.3 / 1100), a_uv)]
    if partial:
        # The second panel cut by the image border: only its points left of a line, no centroid.
        b_pts, b_uv = _edge_points(R, C, np.array([1.1, 0.0, CEILING]))
        cut = (b_uv[0] + np.min(b_pts[:, 0])) / 2
        b_pts = b_pts[b_pts[:, 0] < cut]
        targets.append(OutlineTarget(np.array([1.1, 0.0, CEILING]), "square", (HALF, HALF), b_pts,
                                     np.full(len(b_pts), 0.3 / 1100), None))
    return OutlineFrame.from_targets(targets)


TRUE_R = ypr_to_rotation(200.0, 90.0 - 25.0, 2.0)
TRUE_C = np.array([0.4, -0.5, 1.15])


def test_panel_starts_include_the_true_pose():
    starts = panel_start_poses(_frame(TRUE_R, TRUE_C), 1100.0)
    assert starts
    # a start (the hull of points that miss the corners), not a fix: within reach of the solve
    assert min(np.linalg.norm(C - TRUE_C) for _, C in starts) < 0.25


def test_one_whole_and_one_cut_panel_give_the_fix_without_a_track():
    pos = Positioner(_camera(), _map())
    fix = pos._panel_fix(_frame(TRUE_R, TRUE_C), None)
    assert fix is not None and np.linalg.norm(fix.C - TRUE_C) < 0.005
    # the covariance says how well: the error within 4 sigma along every axis
    assert np.all(np.abs(fix.C - TRUE_C) < 4 * np.sqrt(np.diag(fix.cov)) + 1e-4)


def test_a_lone_square_is_ambiguous_until_a_tracked_orientation_picks_its_side():
    pos = Positioner(_camera(), _map())
    lone = _frame(TRUE_R, TRUE_C, partial=False)
    assert pos._panel_fix(lone, None) is None
    # a frame without a position says so (receiver.cli.run's "no_fix")
    obs = LedObservation(track=1, cx=640.0, cy=360.0, area_px=900.0, contour=np.zeros((0, 2)), id=100, mode="ook")
    assert pos._no_fix_reason([obs], pos.ranger.usable([obs])) == "panel pose ambiguous"
    turned = ypr_to_rotation(200.0 + 8.0, 90.0 - 25.0, 2.0)     # the track, 8 degrees off in yaw
    fix = pos._panel_fix(lone, turned)
    assert fix is not None and np.linalg.norm(fix.C - TRUE_C) < 0.01
    assert math.isfinite(fix.chi2)



def test_a_lone_small_panel_seen_nearly_square_on_gives_no_wrong_first_fix():
    """A rendered frame (tests/locate/data/lone_small_panel.json: its edge points and centroid,
    undistorted and normalized) with one decoded 0.2 m panel 2 m away, phone tilted 15 degrees.
    Its tilted-and-shifted pose branches fit about equally: a panel start that stops short of
    its branch's optimum lets a branch 0.8 m off win the ambiguity test. Without a track the
    fix is either right (within 5 cm) or not given."""
    import json
    from pathlib import Path

    d = json.loads((Path(__file__).parent / "data" / "lone_small_panel.json").read_text())
    frame = OutlineFrame(np.array(d["pts"]), np.array(d["sigma"]), np.array(d["ends"], np.int64),
                         np.array(d["xyz"]), np.array(d["half"]), tuple(d["shapes"]), np.array(d["uv"]))
    x, y, z = d["xyz"][0]
    led_map = parse_map({"units": "m", "addressing": "map", "leds": [
        {"id": 1, "mode": "ook", "x": x, "y": y, "z": z, "shape": "rect", "size": [0.2, 0.2], "rate_hz": 10000}]})
    fix = Positioner(_camera(), led_map)._panel_fix(frame, None)
    assert fix is None or np.linalg.norm(fix.C - np.array(d["true_camera_xyz"])) < 0.05
