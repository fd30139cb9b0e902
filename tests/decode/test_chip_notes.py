"""`DecodePolicy.chip_notes`: `occloc run` says, with the numbers, when the lights' images show
too few chips a frame for their packets to be read from their own chips (5-10 kHz chips on
small or far panels), and which chip rate or image height would; nothing when they show more."""

from __future__ import annotations

import numpy as np

from receiver.io.camera import CameraModel
from receiver.io.ledmap import parse_map
from receiver.pipeline import Receiver


def _receiver(rate_hz):
    K = np.array([[1100.0, 0, 640.0], [0, 1100.0, 360.0], [0, 0, 1]])
    cam = CameraModel(1280, 720, K, np.zeros(5), fps=30.0, row_readout_us=10.0, exposure_us=10.0)
    led_map = parse_map({"units": "m", "addressing": "map", "leds": [
        {"id": 7, "mode": "ook", "x": 0.0, "y": 0.0, "z": 3.0, "shape": "square", "size": [0.2, 0.2],
         "rate_hz": rate_hz}]})
    return Receiver(cam, led_map)


def test_few_chips_a_frame_are_named_with_the_rate_that_would_do():
    pol = _receiver(5000).policy
    assert pol.chip_notes() == []                   # nothing seen yet
    pol.chips_seen[5000.0].extend([6.0] * 9 + [5.0] * 3)   # 120-row images: 6 chips of 5 kHz
    (note,) = pol.chip_notes()
    assert "6 chips a frame" in note and "5 kHz" in note and "a packet is 54" in note
    # 16 chips (the pieces' limit) need 16 / 6 of the rate or of the image height
    assert "> 13 kHz" in note and "2.7x taller" in note


def test_enough_chips_a_frame_give_no_note():
    pol = _receiver(20000).policy
    pol.chips_seen[20000.0].extend([24.0] * 20)
    assert pol.chip_notes() == []


def test_the_notes_of_a_photo_folder_speak_for_every_photo():
    """Each photo has a receiver of its own: a few light images each, none enough alone; the
    notes pool them (`absorb_notes`), the later photos' images kept when the pool is full."""
    photos = [_receiver(5000).policy for _ in range(4)]
    tally = None
    for pol in photos:
        pol.chips_seen[5000.0].extend([6.0] * 3)
        assert pol.chip_notes() == []                # 3 images: too few to judge alone
        tally = pol.absorb_notes(tally)
    (note,) = tally.chip_notes()
    assert "6 chips a frame" in note and "5 kHz" in note
    assert len(tally.chips_seen[5000.0]) == 12


def test_the_exposure_learned_over_a_photo_folder():
    """Without an exposure in the camera file, each photo's stripes give a few estimates; the
    notes judge the exposure from all the photos' estimates together."""
    import dataclasses
    photos = []
    for _ in range(3):
        rx = _receiver(20000)
        rx = Receiver(dataclasses.replace(rx.camera, exposure_us=0.0), rx.led_map)
        lr = rx.policy.exposure_learners[20000.0]
        lr.estimates = [3.0, 3.0, 3.0]              # rows: 30 us at 10 us a row
        photos.append(rx.policy)
    assert "exposure unknown" in photos[-1].exposure_notes()[0][1]
    tally = None
    for pol in photos:
        tally = pol.absorb_notes(tally)
    ((readable, text),) = tally.exposure_notes()
    assert readable and "exposure 30 us" in text and "from the stripes' edges" in text


def test_occloc_run_on_a_photo_folder_gives_the_chip_note(tmp_path, capsys):
    """Twelve photos of small 5 kHz lights (3-4 light images a photo, each photo its own
    receiver): `occloc run` names the chips a frame from all of them."""
    import cv2

    from receiver.cli import main as occloc
    from receiver.io.camera import save_camera
    from receiver.io.ledmap import save_map
    from tools.synth import make_scene, render_frames

    folder = tmp_path / "photos"
    folder.mkdir()
    scene = make_scene("indoor-sparse", seed=2, n_frames=12, rate_hz=5000)
    for img, t in render_frames(scene, seed=4):
        cv2.imwrite(str(folder / f"{t['frame']:03d}.png"), img)
    save_map(str(tmp_path / "map.json"), scene.led_map)
    save_camera(str(tmp_path / "camera.yaml"), scene.camera)
    assert occloc(["run", str(folder), "--camera", str(tmp_path / "camera.yaml"), "--map", str(tmp_path / "map.json"),
                   "--out", str(tmp_path / "out.jsonl")]) == 0
    err = capsys.readouterr().err
    assert "chips a frame (median) of the 5 kHz OOK chips" in err, err


def test_check_says_how_many_frames_an_id_needs():
    """`occloc check` on small 5 kHz lights: a finding with the chips a frame, the frames an ID
    needs and the chip rate that would do; with "xy" addressing the pieces cannot be placed
    (no candidate IDs): a problem. Lights showing a whole packet a frame give no such finding."""
    import dataclasses

    from receiver.calibrate.check import check_frames
    from receiver.core.records import Frame
    from tools.synth import make_scene, render_frames

    def findings(rate_hz, addressing=None):
        scene = make_scene("indoor-sparse", seed=2, n_frames=8, rate_hz=rate_hz)
        frames = [Frame(t["frame"], t["t"], img) for img, t in render_frames(scene, seed=4)]
        led_map = (scene.led_map if addressing is None
                   else dataclasses.replace(scene.led_map, addressing=addressing, default_rate_hz=rate_hz))
        return {f.name: f for f in check_frames(frames, scene.camera, led_map)}

    fs = findings(5000)
    chips = fs["chips"]
    assert chips.ok and 3 <= chips.value["chips_a_frame"] <= 16, chips.text
    assert "frames of each light" in chips.text and "5 kHz" in chips.text and "kHz, or lights" in chips.text
    assert not findings(5000, addressing="xy")["chips"].ok
    assert "chips" not in findings(40000)
