"""Positioning against synthetic truth: multilateration (eqs. 26-34), PnP, range+angle, the
mirror rejection, xy addressing, and the Positioner stage end to end."""

import math

import numpy as np
import pytest

from receiver.io.camera import CameraModel
from receiver.io.ledmap import parse_map
from receiver.locate.posefilter import MIRROR_CAM, MIRROR_WORLD
from receiver.locate.indoor import Positioner
from receiver.locate.pose import is_collinear, pnp_candidates, rotation_to_ypr_deg, solve_fix, ypr_to_rotation
from receiver.locate.multilat import multilaterate, multilaterate_linear
from receiver.locate.ranging import led_outline_world, polygon_area_perimeter, polygon_centroid, project_world, undistort_points
from receiver.core.records import LedObservation

CEILING_M = 3.0

def _distances(res) -> dict:
    """track -> (distance_m, estimator) of a LocateResult's ranged LEDs."""
    return {o.track: (o.distance_m, o.distance_estimator) for o in res.leds if o.distance_m is not None}



def make_camera(dist=(-0.08, 0.02, 0.0, 0.0, 0.0)):
    K = np.array([[600.0, 0, 640.0], [0, 600.0, 360.0], [0, 0, 1]])
    return CameraModel(1280, 720, K, np.array(dist, float), fps=30.0)


def make_map(addressing="map"):
    if addressing == "xy":
        return parse_map({"units": "m", "addressing": "xy", "ceiling_z": CEILING_M, "shape": "square",
                          "size": [0.1, 0.1], "rate_hz": 20000, "leds": []})
    leds = [{"id": 10 + 3 * i + j, "mode": "ook", "x": 1.2 * i, "y": 1.2 * j, "z": CEILING_M,
             "shape": "square", "size": [0.1, 0.1], "rate_hz": 20000} for i in range(3) for j in range(3)]
    return parse_map({"units": "m", "addressing": "map", "leds": leds})


def observe(camera, led_map, C, R_cw, rng=None, px_noise=0.0, ids=None):
    """What an ideal detector reports: the projected LED outlines as contours (distorted px)."""
    out = []
    for track, led in enumerate(led_map.leds.values() if ids is None else [led_map.lookup(i) for i in ids]):
        Xc = (led.xyz - C) @ R_cw.T
        if Xc[2] <= 0:
            continue
        poly = project_world(led_outline_world(led, 16), camera, R_cw, C)
        if rng is not None and px_noise:
            poly = poly + rng.normal(0, px_noise, poly.shape)
        if poly.min() < 0 or poly[:, 0].max() > camera.width - 1 or poly[:, 1].max() > camera.height - 1:
            continue
        area, _ = polygon_area_perimeter(poly)
        cx, cy = polygon_centroid(poly)
        out.append(LedObservation(track=track, cx=cx, cy=cy, area_px=area, contour=poly, id=led.id, mode="ook"))
    return out


def test_ypr_round_trip():
    for ypr in [(10, 20, 30), (-120, 60, -5), (0, -30, 170)]:
        assert np.allclose(rotation_to_ypr_deg(ypr_to_rotation(*ypr)), ypr, atol=1e-9)


def test_multilateration_linear_exact_and_mirror():
    L = np.array([[0, 0, 3.0], [1.2, 0, 3.0], [0, 1.2, 3.0], [1.2, 1.2, 3.0]])
    C = np.array([0.4, 0.7, 1.1])
    d = np.linalg.norm(L - C, axis=1)
    cands = multilaterate_linear(L, d)
    # Coplanar LEDs: the two roots of eqs. 30-31 are the camera and its mirror above the ceiling.
    assert len(cands) == 2
    zs = sorted(c[2] for c in cands)
    assert zs[0] == pytest.approx(1.1, abs=1e-9) and zs[1] == pytest.approx(4.9, abs=1e-9)
    fix = multilaterate(L, d, np.full(4, 0.01))
    assert np.allclose(fix.C, C, atol=1e-7)
    # LEDs off one plane: full rank, eq. 34 alone.
    L2 = L.copy()
    L2[3, 2] = 2.5
    (c,) = multilaterate_linear(L2, np.linalg.norm(L2 - C, axis=1))
    assert np.allclose(c, C, atol=1e-9)


def test_multilateration_noisy_covariance_is_honest():
    rng = np.random.default_rng(1)
    L = np.array([[0, 0, 3.0], [1.2, 0, 3.0], [0, 1.2, 3.0], [1.2, 1.2, 3.0], [0.6, 2.4, 3.0]])
    C = np.array([0.5, 0.9, 1.2])
    sig = 0.01
    nees = []
    for _ in range(200):
        d = np.linalg.norm(L - C, axis=1) + rng.normal(0, sig, len(L))
        fix = multilaterate(L, d, np.full(len(L), sig), loss="linear")
        assert fix.C[2] < CEILING_M
        e = fix.C - C
        nees.append(e @ np.linalg.solve(fix.cov, e))
    # chi-square, 3 dof: mean 3; s^2 >= 1 inflation can only make it smaller.
    assert 1.5 < np.mean(nees) < 3.6


def test_pnp_recovers_pose_with_valid_rotation():
    L = np.array([[0, 0, 3.0], [1.2, 0, 3.0], [0, 1.2, 3.0], [1.2, 1.2, 3.0], [2.4, 1.2, 3.0]])
    C = np.array([0.8, 0.3, 1.0])
    R = ypr_to_rotation(30, 75, 5)
    X = (L - C) @ R.T
    uv = X[:, :2] / X[:, 2:]
    fix = solve_fix(L, uv, np.full(5, np.nan), np.full(5, np.nan), sigma_uv=1e-4)
    assert fix.method == "pnp"
    assert np.allclose(fix.C, C, atol=1e-6)
    assert np.allclose(fix.R_cw, R, atol=1e-6)
    assert np.linalg.det(fix.R_cw) == pytest.approx(1.0, abs=1e-9)
    # three points: the P3P ambiguity is resolved (camera below the ceiling, best fit).
    assert any(np.allclose(c, C, atol=1e-6) for _, c in pnp_candidates(L[:3], uv[:3]))


def test_two_leds_ranges_and_angles():
    L = np.array([[0, 0, 3.0], [1.2, 0, 3.0]])
    C = np.array([0.5, 0.4, 1.2])
    R = ypr_to_rotation(-40, 86, 0)
    X = (L - C) @ R.T
    uv = X[:, :2] / X[:, 2:]
    d = np.linalg.norm(L - C, axis=1)
    # The rotation about the LED baseline comes from the tilt prior: exact prior, exact answer;
    # the "looking up" default is 4 degrees off here and costs centimetres, not metres.
    fix = solve_fix(L, uv, d, np.full(2, 0.005), sigma_uv=1e-4, R_prior=R, tilt_sigma_deg=1.0)
    assert fix.method == "range+angle"
    assert np.linalg.norm(fix.C - C) < 1e-4
    fix_up = solve_fix(L, uv, d, np.full(2, 0.005), sigma_uv=1e-4)
    assert 1e-3 < np.linalg.norm(fix_up.C - C) < 0.15
    assert solve_fix(L[:1], uv[:1], d[:1], np.full(1, 0.005), sigma_uv=1e-4) is None


@pytest.mark.parametrize("solver", ["auto", "multilateration", "pnp"])
def test_positioner_on_projected_scene(solver):
    cam, m = make_camera(), make_map()
    C = np.array([1.3, 1.1, 1.0])
    R = ypr_to_rotation(20, 82, 3)
    pos = Positioner(cam, m, solver=solver, edge_offset_px=0.0, kalman=False)
    res = pos.step(0.0, observe(cam, m, C, R))
    p = res.position
    assert p["method"] == {"auto": "range+angle", "multilateration": "multilateration", "pnp": "pnp"}[solver]
    err = math.dist((p["x"], p["y"], p["z"]), C)
    assert err < {"auto": 0.003, "multilateration": 0.03, "pnp": 0.003}[solver]
    # Distances from the oblique estimator, within 0.5 % of the truth for every visible LED.
    for led in observe(cam, m, C, R):
        d_true = float(np.linalg.norm(m.lookup(led.id).xyz - C))
        d, name = _distances(res)[led.track]
        assert abs(d - d_true) / d_true < 0.005, (name, d, d_true)
    if solver != "multilateration":
        Rwc = np.array(p["R_wc"])
        assert np.allclose(Rwc @ Rwc.T, np.eye(3), atol=1e-5) and np.linalg.det(Rwc) > 0.99999
        assert np.allclose(Rwc.T, R, atol=2e-3)


def test_positioner_xy_addressing_and_unknown_ids():
    cam, m = make_camera(), make_map("xy")
    ids = [(x << 8) | y for x in (10, 22) for y in (10, 22)]   # decimetres: (1.0|2.2, 1.0|2.2)
    C = np.array([1.5, 1.7, 1.2])
    R = ypr_to_rotation(0, 90, 0)
    obs = observe(cam, m, C, R, ids=ids)
    assert len(obs) == 4
    pos = Positioner(cam, m, edge_offset_px=0.0, kalman=False)
    p = pos.step(0.0, obs).position
    assert math.dist((p["x"], p["y"], p["z"]), C) < 0.003
    m2 = make_map()
    extra = LedObservation(track=99, cx=5.0, cy=5.0, area_px=100.0, contour=np.zeros((0, 2)), id=4242)
    pos2 = Positioner(cam, m2, kalman=False)
    pos2.step(0.0, observe(cam, m2, C, R) + [extra])
    assert pos2.unknown_ids == {4242}


def test_positioner_one_led_and_kalman_coast():
    cam, m = make_camera(), make_map()
    C = np.array([1.2, 1.2, 1.0])
    R = ypr_to_rotation(0, 90, 0)
    pos = Positioner(cam, m, edge_offset_px=0.0)
    full = observe(cam, m, C, R)
    p0 = pos.step(0.0, full).position
    assert p0["filtered"] is True and p0["raw"] is not None
    one = [o for o in full if o.id == 14]
    res = pos.step(0.1, one)
    assert 14 in [o.id for o in one] and len(_distances(res)) == 1
    assert res.position["method"] == "kalman-coast" and res.position["raw"] is None
    assert res.position["std_m"][0] > p0["std_m"][0]          # coasting: covariance grows
    assert Positioner(cam, m).step(0.0, one).position is None


def test_walk_with_noise_kalman_beats_raw():
    """A noisy straight walk: filtered error below raw error, both small."""
    cam, m = make_camera(), make_map()
    rng = np.random.default_rng(7)
    pos = Positioner(cam, m, edge_offset_px=0.0, pixel_sigma_px=0.3, edge_sigma_px=0.3)
    raw_err, filt_err = [], []
    for k in range(60):
        t = k / 30.0
        C = np.array([0.8 + 0.6 * t, 0.9 + 0.2 * t, 1.1])
        R = ypr_to_rotation(10 * t, 88, 0)
        p = pos.step(t, observe(cam, m, C, R, rng=rng, px_noise=0.3)).position
        if k >= 10:
            raw_err.append(math.dist((p["raw"]["x"], p["raw"]["y"], p["raw"]["z"]), C))
            filt_err.append(math.dist((p["x"], p["y"], p["z"]), C))
    assert np.median(filt_err) < np.median(raw_err)
    assert np.median(filt_err) < 0.02


def test_is_collinear():
    row = np.array([[0.4, 0.25 + 0.5 * i, 3.0] for i in range(5)])
    assert is_collinear(row) and is_collinear(row[:2])
    two_rows = np.vstack([row, row + [1.2, 0, 0]])
    assert not is_collinear(two_rows)


def test_single_row_uses_tilt_prior_and_flags_the_blind_direction():
    # One row of LEDs along world y: ranges and angles cannot see a rotation about the row, so
    # the fix follows the "held up" tilt prior and its covariance says x (across the row) and z
    # are poorly known, while y (along the row) stays sharp.
    cam = make_camera(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    leds = [{"id": 100 + i, "mode": "ook", "x": 1.0, "y": 0.6 * i, "z": CEILING_M, "shape": "square",
             "size": [0.1, 0.1], "rate_hz": 20000} for i in range(4)]
    m = parse_map({"units": "m", "addressing": "map", "leds": leds})
    C = np.array([1.3, 0.9, 1.0])
    for pitch, tol_m in [(90.0, 0.003), (88.0, 0.12)]:
        R = ypr_to_rotation(0.0, pitch, 0.0)
        pos = Positioner(cam, m, edge_offset_px=0.0, kalman=False)
        p = pos.step(0.0, observe(cam, m, C, R)).position
        assert p["method"] == "range+angle" and p["n_leds"] == 4
        err = np.array([p["x"], p["y"], p["z"]]) - C
        assert np.linalg.norm(err) < tol_m, (pitch, err)
        assert abs(err[1]) < 0.003
        std = p["raw_std_m"]
        assert std[0] > 10 * std[1]        # across the row: the prior's 10 degrees, not the data


def test_blobs_near_the_image_edge_are_left_out():
    cam, m = make_camera(), make_map()
    C = np.array([1.3, 1.1, 1.0])
    R = ypr_to_rotation(20, 82, 3)
    obs = observe(cam, m, C, R)
    o = obs[0]
    shifted = o.contour - o.contour.min(axis=0) + 5.0          # inside the frame but 5 px from it
    cut = LedObservation(track=o.track, cx=o.cx, cy=o.cy, area_px=o.area_px, contour=shifted,
                         id=o.id, mode="ook")
    pos = Positioner(cam, m, kalman=False)
    res = pos.step(0.0, [cut] + obs[1:])
    assert o.track not in _distances(res)
    assert res.position["n_leds"] == len(obs) - 1
    res = Positioner(cam, m, kalman=False, border_margin_px=1.0).step(0.0, [cut] + obs[1:])
    assert o.track in _distances(res)


def mirrored_map(m, handedness=None):
    """The same physical LEDs described in a left-handed frame (y negated)."""
    obj = m.to_json()
    for led in obj["leds"]:
        led["y"] = -led["y"]
    if handedness:
        obj["handedness"] = handedness
    return parse_map(obj)


@pytest.mark.parametrize("declared", [None, "left"])
def test_left_handed_map_is_solved_in_its_mirror(declared):
    cam, m = make_camera(), make_map()
    C, R = np.array([1.3, 1.1, 1.0]), ypr_to_rotation(20, 82, 3)
    obs = observe(cam, m, C, R)
    assert len(obs) >= 3 and not is_collinear(np.array([m.lookup(o.id).xyz for o in obs]))
    mm = mirrored_map(m, declared)
    assert Positioner(cam, mm, kalman=False, handedness="right").step(0.0, obs).position is None
    pos = Positioner(cam, mm, edge_offset_px=0.0, kalman=False)
    p = pos.step(0.0, obs).position
    assert p["handedness"] == "left" and pos.pose.handedness_source == ("map" if declared else "detected")
    assert math.dist((p["x"], p["y"], p["z"]), MIRROR_WORLD @ C) < 0.003
    Rwc = np.array(p["R_wc"])
    assert np.allclose(Rwc @ Rwc.T, np.eye(3), atol=1e-5) and np.linalg.det(Rwc) > 0.99999
    assert np.allclose(Rwc.T, MIRROR_CAM @ R @ MIRROR_WORLD, atol=2e-3)
    # The filter keeps going in the mirror on later frames, with collinear LEDs too.
    C2 = C + [0.02, 0.01, 0.0]
    p2 = pos.step(0.1, observe(cam, m, C2, R)).position
    assert math.dist((p2["x"], p2["y"], p2["z"]), MIRROR_WORLD @ C2) < 0.003


def test_right_handed_map_is_detected_as_such():
    cam, m = make_camera(), make_map()
    C, R = np.array([1.3, 1.1, 1.0]), ypr_to_rotation(20, 82, 3)
    pos = Positioner(cam, m, edge_offset_px=0.0, kalman=False)
    p = pos.step(0.0, observe(cam, m, C, R)).position
    assert p["handedness"] == "right" and pos.pose.handedness_source == "detected"
    assert math.dist((p["x"], p["y"], p["z"]), C) < 0.003


def test_map_handedness_round_trip_and_validation():
    from receiver.core.errors import InputError
    m = mirrored_map(make_map(), "left")
    assert parse_map(m.to_json()).handedness == "left"
    assert "handedness" not in make_map().to_json()
    with pytest.raises(InputError, match="handedness"):
        parse_map({**make_map().to_json(), "handedness": "up"})


def test_handedness_needs_a_good_fit_to_decide():
    from receiver.locate.pose import Fix
    from receiver.locate.posefilter import is_mirror_fit_better
    C, cov, R = np.zeros(3), np.eye(3), np.eye(3)
    good = Fix(C, cov, R, "pnp", 4, chi2=12.0, dof=6)
    bad = Fix(C, cov, R, "pnp", 4, chi2=700.0, dof=6)       # 117 per dof: explains nothing
    assert is_mirror_fit_better(good, None) and is_mirror_fit_better(good, bad)
    assert not is_mirror_fit_better(bad, None) and not is_mirror_fit_better(None, good)
    assert not is_mirror_fit_better(good, Fix(C, cov, R, "pnp", 4, chi2=100.0, dof=6))  # < 10x


def test_s2psk_lights_are_not_indoor_fixtures():
    """Street lights / taillights (S2-PSK) give neither ranges nor fixes here (thesis eqs. 44-53
    are the vehicle stage's): the same observations as OOK LEDs do."""
    cam, m = make_camera(), make_map()
    obj = m.to_json()
    for led in obj["leds"]:
        led.update(mode="s2psk", rate_hz=200.0)
    m2 = parse_map(obj)
    C, R = np.array([1.3, 1.1, 1.0]), ypr_to_rotation(20, 82, 3)
    obs = observe(cam, m, C, R)
    assert Positioner(cam, m, kalman=False).step(0.0, obs).position is not None
    s2 = [LedObservation(**{**o.__dict__, "mode": "s2psk"}) for o in obs]
    res = Positioner(cam, m2, kalman=False).step(0.0, s2)
    assert res.position is None and _distances(res) == {}


def _warm_problems(n_problems=12, seed=1):
    """Random frames of 3-6 ceiling LEDs (some ranges missing) with starts near the truth: the
    problems, and `refine_pose`'s answers (R, C, cov, chi2, dof) from the same starts."""
    import cv2
    from receiver.locate.pose import WarmProblem, refine_pose
    rng = np.random.default_rng(seed)
    problems, refs = [], []
    for b in range(n_problems):
        n = 3 + b % 4
        L = np.column_stack([rng.uniform(0, 3, n), rng.uniform(0, 3, n), np.full(n, CEILING_M)])
        C = np.array([1.5, 1.5, 1.2]) + rng.normal(0, 0.3, 3)
        R = ypr_to_rotation(rng.uniform(-180, 180), 85 + rng.uniform(-5, 5), rng.uniform(-5, 5))
        X = (L - C) @ R.T
        uv = X[:, :2] / X[:, 2:] + rng.normal(0, 3e-4, (n, 2))
        d = np.linalg.norm(L - C, axis=1) + rng.normal(0, 0.01, n)
        if b % 3 == 0:
            d[0] = np.nan
        sd = np.full(n, 0.01)
        R0, C0 = cv2.Rodrigues(rng.normal(0, 0.03, 3))[0] @ R, C + rng.normal(0, 0.05, 3)
        problems.append(WarmProblem(L, uv, 3e-4, d, sd, np.array([0, 0, 1.0]), math.radians(10), R0, C0))
        refs.append(refine_pose(L, uv, 3e-4, d, sd, R0, C0, R_prior=np.eye(3), tilt_sigma_rad=math.radians(10)))
    return problems, refs


def test_warm_batch_jacobian_is_the_derivative():
    """The batched solver's closed-form Jacobian (multiplicative rotation step, padded rows of
    frames with fewer LEDs) equals central differences of its residuals along its steps."""
    from receiver.locate.pose import warm_batch_functions
    problems, _ = _warm_problems(6)
    fun_jac, step, _, state, _ = warm_batch_functions(problems)
    r0, J = fun_jac(state)
    Jn = np.empty_like(J)
    for k in range(6):
        dp = np.zeros((len(problems), 6))
        dp[:, k] = 1e-6
        Jn[:, :, k] = (fun_jac(step(state, dp))[0] - fun_jac(step(state, -dp))[0]) / 2e-6
    assert np.abs(J - Jn).max() < 1e-6 * np.abs(Jn).max()
    # Frame 0 has 3 LEDs (padded to 6) and no range for its first: those rows are zero.
    assert r0.shape == J.shape[:2] == (6, 2 * 6 + 6 + 3)
    assert np.all(r0[0, 6:12] == 0) and np.all(r0[0, 15:18] == 0) and r0[0, 12] == 0 and np.all(r0[0, :6] != 0)


def test_warm_batch_reaches_refine_poses_minimum():
    """Many frames solved together from warm starts land where `refine_pose` (one frame, rotation
    vector, IRLS) does: the same centre to 2 um, orientation, covariance, chi^2 and dof; and a
    frame solved alone equals the same frame in the batch."""
    from receiver.locate.pose import refine_warm_batch
    problems, refs = _warm_problems()
    R, C, cov, chi2, dof, ok = refine_warm_batch(problems)
    assert ok.all()
    for b, (Rr, Cr, covr, chi2r, dofr) in enumerate(refs):
        assert np.abs(C[b] - Cr).max() < 2e-6 and np.abs(R[b] - Rr).max() < 2e-6
        assert np.abs(cov[b] - covr).max() <= 1e-4 * np.abs(covr).max()
        # the same chi^2 to the solvers' stopping rules (chi^2 is not the robust cost minimised:
        # it moves to first order with the solution, 1.3e-5 of it for a frame 1 sigma off)
        assert chi2[b] == pytest.approx(chi2r, rel=1e-4) and dof[b] == dofr
    R1, C1, *_ = refine_warm_batch(problems[4:5])
    assert np.abs(C1[0] - C[4]).max() < 1e-9


def test_warm_started_filter_keeps_the_cold_fix_and_falls_back():
    """PoseFilter(warm_start=True) after a first (cold) fix: the next frames' fixes equal the cold
    solve within 2 um, also after a 2 m jump with a 70 degree turn (the warm start converges);
    with an orientation prior that sees every LED behind the camera the warm start cannot
    explain the frame and the frame is solved from scratch, as without the warm start."""
    from receiver.locate.pose import solve_warm_batch
    from receiver.locate.posefilter import PoseFilter
    led_map = make_map()
    ids = [led.id for led in led_map.leds.values()]
    L = np.array([led_map.lookup(i).xyz for i in ids])

    def frame(C, yaw):
        X = (L - C) @ ypr_to_rotation(yaw, 88.0, 2.0).T
        return X[:, :2] / X[:, 2:], np.linalg.norm(L - C, axis=1), np.full(len(L), 0.005)

    upside_down = np.diag([1.0, -1.0, -1.0])
    warm, cold = PoseFilter(sigma_uv=3e-4, warm_start=True), PoseFilter(sigma_uv=3e-4)
    for t, C, yaw, flip in [(0.0, np.array([1.2, 1.1, 1.0]), 10.0, False),
                            (0.033, np.array([1.22, 1.1, 1.0]), 11.0, False),
                            (0.066, np.array([3.2, 0.1, 1.0]), 80.0, False),
                            (0.1, np.array([3.2, 0.12, 1.0]), 81.0, True)]:
        uv, d, sd = frame(C, yaw)
        R_prior = warm.R_prior(t)
        if flip:
            R_prior = upside_down @ R_prior
        q = warm.warm_problem(t, L, uv, d, sd, R_prior)
        assert (q is None) is (t == 0.0)                       # no previous fix: no warm start
        if q is not None:
            assert (solve_warm_batch([q])[0] is None) is flip
        fw = warm.solve(t, L, uv, d, sd, R_prior)
        fc = cold.solve(t, L, uv, d, sd, cold.R_prior(t))
        assert np.abs(fw.C - fc.C).max() < 2e-6 and np.abs(fw.C - C).max() < 1e-3
        warm.update(t, fw, len(L))
        cold.update(t, fc, len(L))
