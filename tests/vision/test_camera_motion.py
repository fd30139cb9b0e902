"""receiver.vision.camera_motion: one camera-motion estimate per frame from all blobs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from receiver.vision.camera_motion import CameraMotion, MotionEstimate, MotionSettings

CENTER = (640.0, 360.0)


def _shake(rng, n, amp_px=4.0):
    """Per-frame image shifts (n, 2) px and rolls (n,) rad: slow swings of 0.5-2.5 Hz at 30 fps
    (the per-frame change of a swinging angle) plus frame-to-frame jitter."""
    k = np.arange(n)
    out = np.zeros((n, 2))
    for axis in range(2):
        for _ in range(3):
            f, ph = rng.uniform(0.5, 2.5), rng.uniform(0, 2 * np.pi)
            out[:, axis] += amp_px / 3 * np.cos(2 * np.pi * f * k / 30 + ph)
    out += rng.normal(0.0, 0.6, (n, 2))
    roll = np.radians(0.05) * np.sin(2 * np.pi * 1.3 * k / 30) + rng.normal(0, np.radians(0.01), n)
    return out, roll


def _scene(rng, n_heads, n_frames, lit_p=0.75, movers=0):
    """Blob centroids per frame of `n_heads` two-emitter heads (halves 4-30 px apart, each lit
    with probability `lit_p` per frame) under `_shake`, and `movers` blobs with their own random
    motion (cars). Returns (frames of (K, 2) centroids, true per-frame MotionEstimates)."""
    mid = np.column_stack([rng.uniform(80, 1200, n_heads), rng.uniform(150, 520, n_heads)])
    half = rng.uniform(2.0, 15.0, n_heads)
    pts = np.concatenate([mid - np.column_stack([half, 0 * half]), mid + np.column_stack([half, 0 * half])])
    cars = np.column_stack([rng.uniform(300, 900, movers), rng.uniform(380, 520, movers)])
    shifts, rolls = _shake(rng, n_frames)
    frames, truth = [], []
    for k in range(n_frames):
        est = MotionEstimate(shifts[k, 0], shifts[k, 1], rolls[k], 0.0, 0.0, 1, CENTER)
        if k:
            pts = est.apply(pts)
            cars = cars + rng.normal(0.0, 6.0, cars.shape)
        lit = rng.random(len(pts)) < lit_p
        xy = pts[lit] + rng.normal(0.0, 0.2, (int(lit.sum()), 2))
        frames.append(np.concatenate([xy, cars]))
        truth.append(est)
    return frames, truth


def _errors(frames, truth, settings=MotionSettings()):
    cm = CameraMotion(CENTER, settings)
    errs, ests = [], []
    for k, xy in enumerate(frames):
        est = cm.step(xy)
        ests.append(est)
        if k:
            errs.append(math.hypot(est.dx_px - truth[k].dx_px, est.dy_px - truth[k].dy_px))
    return np.array(errs), ests


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_blinking_heads_shift_followed(seed):
    """Twelve heads whose halves blink independently (a quarter of the emitters dark each frame):
    the image-centre shift is within 0.5 px in nearly every frame, though the halves of a head
    lie closer together than the shake moves them."""
    rng = np.random.default_rng(seed)
    frames, truth = _scene(rng, 12, 120)
    err, ests = _errors(frames, truth)
    assert np.median(err) < 0.3
    assert np.mean(err > 0.5) < 0.03
    assert all(e.measured for e in ests[1:])


def test_cars_moving_on_their_own_are_left_out():
    """Three blobs that move on their own (cars ahead) do not pull the shift."""
    rng = np.random.default_rng(4)
    frames, truth = _scene(rng, 10, 90, movers=3)
    err, _ = _errors(frames, truth)
    assert np.median(err) < 0.3
    assert np.mean(err > 1.0) < 0.05


def test_roll_about_the_centre_is_measured():
    """A pure roll of 0.2 degrees: the image centre does not move, the roll is found."""
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(50, 1230, 30), rng.uniform(50, 670, 30)])
    turn = MotionEstimate(0.0, 0.0, math.radians(0.2), 0.0, 0.0, 1, CENTER)
    cm = CameraMotion(CENTER)
    cm.step(pts)
    est = cm.step(turn.apply(pts))
    assert abs(math.degrees(est.roll_rad) - 0.2) < 0.01
    assert math.hypot(est.dx_px, est.dy_px) < 0.3
    x, y = pts[0]
    assert np.allclose(est.at(x, y), est.apply(pts[:1])[0] - pts[0])


def test_dark_frames_widen_the_uncertainty():
    """Frames without blobs keep the motion model's prediction, unmeasured, with a growing
    uncertainty; the summed variance over the dark run is what `sigma_since` gives, and it
    shrinks back once blobs are registered again."""
    rng = np.random.default_rng(6)
    frames, _ = _scene(rng, 12, 40)
    cm = CameraMotion(CENTER)
    for xy in frames[:20]:
        lit = cm.step(xy)
    then = lit.var_sum_px2
    dark = [cm.step(np.zeros((0, 2))) for _ in frames[20:23]]
    assert not any(e.measured for e in dark)
    sig = [lit.sigma_px] + [e.sigma_px for e in dark]
    assert all(b > a for a, b in zip(sig, sig[1:]))
    assert cm.sigma_since(then) == pytest.approx(math.sqrt(sum(e.sigma_px ** 2 for e in dark)))
    assert cm.sigma_since(then) > 3 * lit.sigma_px
    # blobs again after the dark run: registered on the last lit frame, the uncertainty back down
    back = cm.step(frames[23])
    assert back.measured
    assert back.sigma_px < dark[-1].sigma_px


def test_one_head_alone_is_no_measurement():
    """Two blobs (one head) match either way by its baseline: below `min_matches`, no
    measurement is made, the prediction stands."""
    cm = CameraMotion(CENTER)
    cm.step(np.array([[600.0, 300.0], [612.0, 300.0]]))
    est = cm.step(np.array([[603.0, 301.0], [615.0, 301.0]]))
    assert not est.measured
    assert est.sigma_px > MotionSettings().measure_floor_px


def test_no_blobs_at_all():
    """An empty frame first and after: finite numbers, nothing measured."""
    cm = CameraMotion(CENTER)
    for _ in range(4):
        est = cm.step(np.zeros((0, 2)))
        assert not est.measured
        assert all(math.isfinite(v) for v in (est.dx_px, est.dy_px, est.sigma_px, est.var_sum_px2))


def test_receiver_hook_follows_the_recorded_shake(tmp_path):
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
    assert np.median(err) < 0.6
    assert max(err) < 2.0


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
