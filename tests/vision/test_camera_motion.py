"""receiver.vision.camera_motion: one camera-motion estimate per frame, from the lights that agree."""

from __future__ import annotations

import math

import numpy as np
import pytest

from receiver.vision.camera_motion import CameraMotion, MotionSettings

CENTER = (640.0, 360.0)
FOE = (650.0, 330.0)  # the focus of expansion, off the principal point as a pitched camera has it


def _shake(rng, n, amp_px=8.0):
    """Per-frame image shifts (n, 2) px: the per-frame change of slow swings (0.5-2.5 Hz at
    30 fps) plus frame-to-frame jitter."""
    k = np.arange(n)
    out = np.zeros((n, 2))
    for axis in range(2):
        for _ in range(3):
            f, ph = rng.uniform(0.5, 2.5), rng.uniform(0, 2 * np.pi)
            out[:, axis] += amp_px / 3 * np.cos(2 * np.pi * f * k / 30 + ph)
    return out + rng.normal(0.0, 1.0, (n, 2))


def _road(rng, n_frames, n_heads=6, movers=0, lit_p=0.5):
    """Blob centroids and areas per frame of a drive past S2-PSK heads, and the true per-frame
    shifts. Each head is two emitters side by side (4-20 px apart), each lit with probability
    `lit_p` per frame (about half the emitters dark, as S2-PSK has them); driving forward moves
    every head away from FOE by its own growing fraction per frame (a far head barely, a near
    one by several px), and the camera's shake moves them all alike. A head that leaves the
    frame comes back far ahead. `movers` blobs move on their own, each at its own steady 1-3 px
    per frame sideways (cars changing lanes)."""
    shifts = _shake(rng, n_frames)
    foe = np.array(FOE)

    def far_head():
        return (foe + rng.uniform(-1, 1, 2) * (200.0, 60.0), rng.uniform(2.0, 10.0), rng.uniform(0.004, 0.02))

    heads = [far_head() for _ in range(n_heads)]
    cars = np.column_stack([rng.uniform(400, 900, movers), rng.uniform(380, 520, movers)])
    car_v = np.column_stack([rng.choice([-1.0, 1.0], movers) * rng.uniform(1.0, 3.0, movers), np.zeros(movers)])
    cam = np.zeros(2)
    frames = []
    for k in range(n_frames):
        cam = cam + shifts[k]
        nxt, xy, area = [], [], []
        for mid, half, kap in heads:
            if k:
                # the expansion grows as the head comes nearer
                mid, half, kap = foe + (mid - foe) * (1 + kap), half * (1 + kap), kap * (1 + kap)
            if not (20 < mid[0] + cam[0] < 1260 and 20 < mid[1] + cam[1] < 700):
                mid, half, kap = far_head()
            nxt.append((mid, half, kap))
            for side in (-1.0, 1.0):
                if rng.random() < lit_p:
                    xy.append(mid + cam + (side * half, 0.0) + rng.normal(0.0, 0.2, 2))
                    area.append(3.0 + half)
        heads = nxt
        if movers:
            cars = cars + car_v + shifts[k] * (k > 0)
            xy += list(cars + rng.normal(0.0, 0.2, cars.shape))
            area += [30.0] * movers
        frames.append((np.array(xy, float).reshape(-1, 2), np.array(area, float)))
    return frames, shifts


def _errors(frames, shifts, candidates=None, settings=MotionSettings()):
    cm = CameraMotion(CENTER, settings)
    errs, ests = [], []
    for k, (xy, area) in enumerate(frames):
        est = cm.step(xy, area, candidates=candidates[k] if candidates is not None else ())
        ests.append(est)
        if k:
            errs.append(math.hypot(est.dx_px - shifts[k, 0], est.dy_px - shifts[k, 1]))
    return np.array(errs), ests


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_blinking_heads_driving_past(seed):
    """Six heads, half their emitters dark each frame, spreading away from the focus of
    expansion by their own motion, under a shake of about 4 px per frame (more than a far
    head's halves are apart): the shift is found to about a px, and over 2 px off in under a
    quarter of the frames (no estimate would be off by the whole shake in most)."""
    rng = np.random.default_rng(seed)
    frames, shifts = _road(rng, 150)
    err, ests = _errors(frames, shifts)
    assert np.median(np.hypot(*shifts[1:].T)) > 3.5
    assert np.median(err) < 1.5
    assert np.mean(err > 2.0) < 0.25
    assert np.mean([e.measured for e in ests[1:]]) > 0.9


def test_cars_moving_on_their_own_are_left_out():
    """Two blobs that move sideways on their own by 1-3 px per frame do not carry the shift
    with them."""
    rng = np.random.default_rng(4)
    frames, shifts = _road(rng, 120, movers=2)
    err, _ = _errors(frames, shifts)
    assert np.median(err) < 2.0
    assert np.mean(err > 2.0) < 0.2


def test_a_wrong_shift_from_elsewhere_is_refused():
    """A shift measured elsewhere (the pairs' own estimate) that is 6 px off in every frame is
    one candidate among the vote's: where more lights agree on another shift, it is refused
    (it still wins some frames where few lights are lit)."""
    rng = np.random.default_rng(5)
    frames, shifts = _road(rng, 120)
    wrong = [((s[0] + 6.0, s[1]),) for s in shifts]
    err, _ = _errors(frames, shifts, candidates=wrong)
    assert np.median(err) < 1.5
    assert np.mean(np.abs(err - 6.0) < 0.5) < 0.5


def test_a_right_shift_from_elsewhere_is_taken_in_sparse_frames():
    """Two heads only (often one blob a frame, ambiguous by a head's baseline): a right shift
    given from elsewhere is a candidate the blobs agree with, and the estimate is better than
    without it."""
    rng = np.random.default_rng(6)
    frames, shifts = _road(rng, 150, n_heads=2)
    right = [((s[0] + rng.normal(0, 0.3), s[1] + rng.normal(0, 0.3)),) for s in shifts]
    err_with, _ = _errors(frames, shifts, candidates=right)
    err_alone, _ = _errors(frames, shifts)
    assert np.median(err_with) < np.median(err_alone)
    assert np.mean(err_with > 2.0) < np.mean(err_alone > 2.0) - 0.1


def test_dark_frames_widen_the_uncertainty():
    """Frames without blobs are unmeasured (shift 0) with a growing uncertainty; the summed
    variance over the dark run is what `sigma_since` gives, and the shift is measured again
    once blobs are back."""
    rng = np.random.default_rng(7)
    frames, shifts = _road(rng, 40)
    cm = CameraMotion(CENTER)
    for xy, area in frames[:20]:
        lit = cm.step(xy, area)
    then = lit.var_sum_px2
    dark = [cm.step(np.zeros((0, 2))) for _ in range(3)]
    assert not any(e.measured for e in dark)
    assert all(e.dx_px == 0.0 and e.dy_px == 0.0 for e in dark)
    sig = [lit.sigma_px] + [e.sigma_px for e in dark]
    assert all(b > a for a, b in zip(sig, sig[1:]))
    assert cm.sigma_since(then) == pytest.approx(math.sqrt(sum(e.sigma_px ** 2 for e in dark)))
    assert cm.sigma_since(then) > 3 * lit.sigma_px
    back = cm.step(*frames[20])
    assert back.measured
    assert back.sigma_px < dark[-1].sigma_px


def test_no_blobs_at_all():
    """An empty frame first and after: finite numbers, nothing measured."""
    cm = CameraMotion(CENTER)
    for _ in range(4):
        est = cm.step(np.zeros((0, 2)), candidates=((1.0, 2.0),))
        assert not est.measured
        assert all(math.isfinite(v) for v in (est.dx_px, est.dy_px, est.sigma_px, est.var_sum_px2))


@pytest.mark.parametrize("field", ["history_frames", "min_matches", "beam", "peaks"])
def test_counts_below_one_are_refused(field):
    with pytest.raises(ValueError, match=f"{field} must be at least 1"):
        MotionSettings(**{field: 0})


@pytest.mark.parametrize("field,value,msg", [("shake_px", 0.0, "must be positive"),
                                              ("velocity_gain", 1.5, "at most 1"),
                                              ("foe_gain", float("nan"), "finite number"),
                                              ("miss_cost", -1.0, "at least 0")])
def test_meaningless_values_are_refused(field, value, msg):
    with pytest.raises(ValueError, match=msg):
        MotionSettings(**{field: value})


def test_receiver_hook_follows_the_recorded_shake():
    """`PairSettings.shake` "motion" in the receiver on the bundled vehicle recording: the shift
    it gives the tracks follows the camera's true turn (truth.jsonl) over the first 30 frames."""
    from pathlib import Path

    from receiver.io.camera import load_camera
    from tools.shift_truth import receiver_shifts, true_motion

    rec = Path(__file__).resolve().parents[2] / "recordings" / "vehicle"
    cam = load_camera(str(rec / "camera.yaml"))
    truth = true_motion(str(rec / "truth.jsonl"), 0.5 * (cam.fx + cam.fy), (cam.cx, cam.cy))
    got = receiver_shifts(str(rec), "motion", 30)
    err = [np.median(np.hypot(*(got[f](p0) - p0 - d).T)) for f, p0, d, _ in truth if f in got and len(p0)]
    assert len(err) == 29
    # the scene pitches by up to 1.1 px per frame: a shift of the wrong sign is 2 px off
    assert np.median(err) < 1.0
    assert np.mean(np.array(err) > 2.0) < 0.1


def test_true_motion_signs_from_the_lights(tmp_path):
    """The truth tool's camera turn: a renderer that counts yaw the other way round still gives
    the lights' displacement (the sign is taken from the lights)."""
    import json

    from tools.shift_truth import true_motion

    f = 1000.0
    rows, pts = [], np.array([[300.0, 200.0], [900.0, 250.0], [640.0, 400.0]])
    yaw = [0.0, 0.1, 0.25, 0.2]
    for k, y in enumerate(yaw):
        xy = pts + np.array([f * math.radians(y), 0.0])  # + yaw moves the image right here
        leds = [{"id": i, "emitters": [{"cx": float(x), "cy": float(v), "visible": True}]} for i, (x, v) in enumerate(xy)]
        rows.append({"frame": k, "camera": {"yaw": y, "pitch": 0.0, "roll": 0.0}, "leds": leds})
    path = tmp_path / "truth.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    out = true_motion(str(path), f, CENTER)
    assert [o[0] for o in out] == [1, 2, 3]
    for (_, p0, d, whole), dy in zip(out, np.diff(yaw)):
        assert np.allclose(d, whole)
        assert np.allclose(d, [[f * math.radians(dy), 0.0]] * 3)


def test_shift_truth_with_no_frame_to_score_says_so(monkeypatch, capsys):
    """No truth light seen in two frames the receiver ran: a line saying so, not a traceback."""
    from pathlib import Path

    import tools.shift_truth as tool

    monkeypatch.setattr(tool, "true_motion", lambda *a, **k: [])
    monkeypatch.setattr(tool, "receiver_shifts", lambda *a, **k: {})
    rec = Path(__file__).resolve().parents[2] / "recordings" / "vehicle"
    assert tool.main([str(rec), "--shake", "pairs"]) == 0
    assert capsys.readouterr().out.splitlines() == ["      pairs vs   turn: no frame to score",
                                                    "      pairs vs lights: no frame to score"]


def test_vehicle_score_settings_file_errors_are_one_line(tmp_path, capsys):
    """`tools.vehicle_score --settings`: a missing file, or one given with --truth-shift, is a
    one-line error and exit 2 before anything runs."""
    from tools.vehicle_score import main

    assert main([str(tmp_path), "--runs", str(tmp_path / "runs"), "--settings", str(tmp_path / "no.json")]) == 2
    f = tmp_path / "s.json"
    f.write_text('{"receiver": {"pair": {"shake": "motion"}}}')
    assert main([str(tmp_path), "--runs", str(tmp_path / "runs"), "--settings", str(f), "--truth-shift"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "no such file" in err and "not with --truth-shift" in err
    assert not (tmp_path / "runs").exists()


def test_search_distances_past_any_shake_are_refused():
    """A search radius past MAX_RADIUS_PX (its vote grid would not fit in memory) or a smoothing
    window wider than the search is a one-line ValueError, not an overflow mid-run."""
    import pytest

    from receiver.vision.camera_motion import MAX_RADIUS_PX, MotionSettings

    MotionSettings(radius_px=MAX_RADIUS_PX, match_px=MAX_RADIUS_PX)
    for kw in ({"radius_px": 1e9}, {"match_px": 15.0}, {"gate_px": 1e9}):
        with pytest.raises(ValueError):
            MotionSettings(**kw)
