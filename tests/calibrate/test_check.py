"""`occloc check`: each fault injected into rendered video is flagged; the bundled recordings pass."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.calibrate.check import check_frames, render_text
from receiver.cli import main as occloc
from receiver.core.records import Frame

REC = Path(__file__).resolve().parents[2] / "recordings"
N = 12


def _render(**over):
    from tools.synth import make_scene, render_frames
    scene = make_scene("indoor-static", seed=2, n_frames=N, **over)
    frames = [Frame(t["frame"], t["t"], img) for img, t in render_frames(scene, seed=4)]
    return frames, scene


@pytest.fixture(scope="module")
def clean():
    return _render()


def _failed(frames, scene):
    fs = check_frames(frames, scene.camera, scene.led_map)
    return {f.name for f in fs if not f.ok}, fs


def test_clean_clip_passes(clean):
    bad, fs = _failed(*clean)
    assert bad == set(), render_text(fs)


def test_long_exposure():
    """Two 20 kHz chips of exposure: flagged, with the numbers and the exposure that works."""
    bad, fs = _failed(*_render(exposure_us=100.0))
    assert "exposure" in bad, render_text(fs)
    f = next(f for f in fs if f.name == "exposure")
    assert "20 kHz" in f.text and "<= 90 us" in f.text, f.text


@pytest.mark.parametrize("exposure_us", [130.0, 200.0])
def test_an_exposure_of_several_chips_is_measured_not_capped(exposure_us):
    """2.6 and 4 chips of 20 kHz exposure: the edge ramps saturate near two chips (they read
    ~95 us for both); the chip sequence fit says they are past the decoders' limit, as a lower
    bound, and the chip rate that would work follows from it."""
    bad, fs = _failed(*_render(exposure_us=exposure_us))
    f = next(f for f in fs if f.name == "exposure")
    assert "exposure" in bad and "(chip sequence fit" in f.text, f.text
    # past the decoders' 1.8 chips, and said to be a lower bound (an exposure two chips longer
    # fits a Manchester profile as well; the fit tries up to 2.5 chips)
    assert 90.0 < f.value["exposure_us"] <= min(exposure_us, 125.0) and "at least this long" in f.text, f.text


def test_long_exposure_is_judged_at_the_rate_run_decodes_a_light_without_rate():
    """A map's OOK light without `rate_hz` runs at the protocol's chip rate (what `occloc run`
    decodes it at): the exposure is judged against that chip, not only against the tone."""
    import dataclasses
    frames, scene = _render(exposure_us=100.0)
    leds = {i: dataclasses.replace(l, rate_hz=None) if l.mode == "ook" else l for i, l in scene.led_map.leds.items()}
    fs = check_frames(frames, scene.camera, dataclasses.replace(scene.led_map, leds=leds))
    assert "exposure" in {f.name for f in fs if not f.ok}, render_text(fs)
    f = next(f for f in fs if f.name == "exposure")
    assert "20 kHz" in f.text and "<= 90 us" in f.text, f.text


def test_exposure_the_model_reads_passes():
    """1.4 chips of exposure: readable by the exposure model, and said so."""
    bad, fs = _failed(*_render(exposure_us=70.0))
    assert "exposure" not in bad, render_text(fs)
    f = next(f for f in fs if f.name == "exposure")
    assert "exposure model" in f.text, f.text


def test_gain_drift(clean):
    frames, scene = clean
    out = [Frame(f.index, f.t_s, np.clip(f.gray * (1.0 - 0.5 * k / (N - 1)), 0, 255).astype(np.uint8))
           for k, f in enumerate(frames)]
    bad, fs = _failed(out, scene)
    assert "gain_drift" in bad, render_text(fs)


def test_banding(clean):
    frames, scene = clean
    rows = np.arange(frames[0].gray.shape[0])[:, None]
    out = []
    for f in frames:
        ph = 2 * np.pi * 100.0 * (f.t_s + rows * scene.camera.row_readout_us * 1e-6)
        amb = 30.0 + 10.0 * np.sin(ph)
        out.append(Frame(f.index, f.t_s, np.clip(f.gray + amb, 0, 255).astype(np.uint8)))
    bad, fs = _failed(out, scene)
    assert "banding" in bad, render_text(fs)


def test_dropped_frames(clean):
    frames, scene = clean
    out = [f for f in frames if f.index not in (4, 5, 9)]  # a V4L2 source leaves gaps in index and t
    bad, fs = _failed(out, scene)
    assert "timestamps" in bad, render_text(fs)
    dup = frames[:6] + [frames[5]] + frames[6:]  # a video whose encoder repeated a frame
    bad, fs = _failed([Frame(i, i / 30.0, f.gray) for i, f in enumerate(dup)], scene)
    assert "timestamps" in bad


def test_defocus():
    bad, fs = _failed(*_render(psf_sigma_px=4.0))
    assert "focus" in bad, render_text(fs)


@pytest.mark.parametrize("name", ["indoor-walk", "indoor-static", "indoor-sparse", "vehicle"])
def test_recordings_pass(name, capsys):
    rc = occloc(["check", str(REC / name), "--max-frames", "20", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["ok"], out


def test_exit_one_on_problem(tmp_path, capsys, clean):
    import cv2
    frames, _ = clean
    folder = tmp_path / "imgs"
    folder.mkdir()
    for f in frames[:4]:
        cv2.imwrite(str(folder / f"{f.index:03d}.png"), cv2.GaussianBlur(f.gray, (0, 0), 4.0))
    rc = occloc(["check", str(folder), "--map", str(REC / "indoor-static" / "map.json")])
    text = capsys.readouterr().out
    assert rc == 1 and "FAIL" in text and "verdict: problems found" in text


def test_edge_blur_is_measured_row_by_row_on_a_rotated_square():
    """A sharp square seen rotated has slanted left/right edges: a column profile averaged over
    rows would read them as blur (indoor-sparse read 4 px before); row by row it is sharp."""
    from receiver.calibrate.rows import edge_blur_px
    from receiver.vision.detect import detect
    img = np.zeros((600, 600), np.uint8)  # the square is under 5 % of the frame (a light, not a window)
    pts = cv2.boxPoints(((300.0, 300.0), (80.0, 80.0), 20.0))
    cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], 200, lineType=cv2.LINE_AA, shift=4)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    (blob,) = detect(img)
    assert edge_blur_px(img, blob) < 1.5


def _shifted(frames, step_px):
    """The clip as a camera panning `step_px` per frame would see it (the picture slides)."""
    out = []
    for k, f in enumerate(frames):
        M = np.float32([[1, 0, step_px * k], [0, 1, 0]])
        g = cv2.warpAffine(f.gray, M, f.gray.shape[::-1], borderMode=cv2.BORDER_REPLICATE)
        out.append(Frame(f.index, f.t_s, g))
    return out


def _background_fades(frames, to_frac, level_dn=40.0):
    """A lit room behind the lights (`level_dn`) that darkens to `to_frac` of it over the clip,
    the lights untouched: a darker part of the room coming into view."""
    out = []
    for k, f in enumerate(frames):
        g = f.gray.astype(np.float32)
        bg = g < 20
        g[bg] += level_dn * (1.0 - (1.0 - to_frac) * k / (len(frames) - 1))
        out.append(Frame(f.index, f.t_s, np.clip(g, 0, 255).astype(np.uint8)))
    return out


def test_background_change_of_a_moving_camera_is_the_scenes(clean):
    """A panning camera (the lights travel ~130 px) whose background darkens while the lights'
    own peaks stay: the scene changed, not the gain; the same fade seen by a still camera fails."""
    frames, scene = clean
    bad, fs = _failed(_background_fades(frames, 0.6), scene)
    drift = next(f for f in fs if f.name == "gain_drift")
    assert "gain_drift" in bad and drift.value["drift"]["background"] < -0.15, render_text(fs)
    bad, fs = _failed(_background_fades(_shifted(frames, 12), 0.6), scene)
    drift = next(f for f in fs if f.name == "gain_drift")
    assert drift.value["moved_px"] >= 40 and drift.value["drift"]["background"] < -0.15, drift.text
    assert "gain_drift" not in bad and "not judged: the camera moves" in drift.text, render_text(fs)
