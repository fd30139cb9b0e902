"""`occloc run` on photos: each photo is an independent observation (its own fit to the camera,
its own receiver, its file named), and a frame without a position says why (`no_fix`)."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from receiver.cli import main as cli
from receiver.io.output import RunSummary, with_fields
from pathlib import Path

WALK = Path(__file__).resolve().parents[2] / "recordings" / "indoor-walk"


def _lines(text):
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def _run(capsys, source, *extra):
    assert cli(["run", str(source), "--camera", str(WALK / "camera.yaml"), "--map", str(WALK / "map.json"),
                *extra]) == 0
    out, err = capsys.readouterr()
    return _lines(out), err


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """Two frames of the bundled walk as photos (far apart on the walk), the second also turned
    to portrait and shrunk to half size, and a dark photo."""
    folder = tmp_path_factory.mktemp("photos")
    cap = cv2.VideoCapture(str(WALK / "video.avi"))
    for i in range(31):
        ok, img = cap.read()
        assert ok
        gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if i == 5:
            cv2.imwrite(str(folder / "a.png"), gray)
        if i == 30:
            cv2.imwrite(str(folder / "b.png"), gray)
            small = cv2.resize(gray, (640, 360), interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(folder / "c_portrait_half.png"), cv2.rotate(small, cv2.ROTATE_90_CLOCKWISE))
    cap.release()
    cv2.imwrite(str(folder / "d_dark.png"), np.zeros((720, 1280), np.uint8))
    return folder


def test_each_photo_of_a_folder_is_located_on_its_own(photos, capsys, tmp_path):
    recs, err = _run(capsys, photos)
    assert [r["file"] for r in recs] == ["a.png", "b.png", "c_portrait_half.png", "d_dark.png"]
    assert "skipped" not in err.split("skipped corrupt frames")[0]  # the portrait photo is not skipped
    by = {r["file"]: r for r in recs}
    for name in ("a.png", "b.png"):
        alone, _ = _run(capsys, photos / name)
        (one,) = alone
        assert one["file"] == name
        # The same position as the photo run alone: nothing carried over from the photo before.
        assert by[name]["position"] is not None
        for k in ("x", "y", "z"):
            assert by[name]["position"][k] == one["position"][k]
        assert [d["id"] for d in by[name]["leds"]] == [d["id"] for d in one["leds"]]
    a, b = by["a.png"]["position"], by["b.png"]["position"]
    assert np.hypot(a["x"] - b["x"], a["y"] - b["y"]) > 0.3  # two different places on the walk
    # The portrait half-size copy of b: turned back, the camera scaled, the same place within 5 cm.
    c = by["c_portrait_half.png"]["position"]
    assert c is not None
    assert np.hypot(c["x"] - b["x"], c["y"] - b["y"]) < 0.05
    assert by["d_dark.png"]["position"] is None and by["d_dark.png"]["no_fix"] == "no LED seen"
    assert "no position: 1 no LED seen" in err


def test_a_photo_of_another_aspect_ratio_in_a_folder_is_skipped_and_named(photos, capsys, tmp_path):
    folder = tmp_path / "mixed"
    shutil.copytree(photos, folder)
    cv2.imwrite(str(folder / "e_square.png"), np.zeros((500, 500), np.uint8))
    recs, err = _run(capsys, folder)
    assert "e_square.png" not in [r["file"] for r in recs] and len(recs) == 4
    assert "e_square.png" in err and "aspect ratio" in err


def test_frames_with_a_position_carry_no_reason(photos, capsys):
    recs, _ = _run(capsys, photos / "a.png")
    assert recs[0]["position"] is not None and "no_fix" not in recs[0]


def test_summary_counts_the_reasons():
    s = RunSummary()

    class R:
        leds, position, vehicle, latency_ms = [], None, None, 1.0
    for why in ("no decoded ID", "no decoded ID", "too few LEDs", None):
        s.add(R(), no_fix=why)
    assert "no position: 2 no decoded ID, 1 too few LEDs" in s.text()
    assert with_fields('{"a":1}', {"file": "x.jpg"}) == '{"a":1,"file":"x.jpg"}'
    assert with_fields('{"a":1}', {}) == '{"a":1}'


# -- the real phone photos (../shared/real/luxapose) -------------------------------------------

def test_real_photos_in_one_folder_each_on_its_own(luxapose, tmp_path, capsys):
    folder = tmp_path / "lux"
    folder.mkdir()
    for name in ("small_blob.jpg", "x_0_y_1.27.jpg"):
        (folder / name).symlink_to(luxapose / name)
    gray = cv2.imread(str(luxapose / "x_0_y_1.27.jpg"), cv2.IMREAD_GRAYSCALE)
    # the same photo, portrait and at a quarter of the pixels: turned back and scaled, not skipped
    cv2.imwrite(str(folder / "z_portrait.jpg"),
                cv2.rotate(cv2.resize(gray, (3856, 2176), interpolation=cv2.INTER_AREA), cv2.ROTATE_90_CLOCKWISE),
                [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert cli(["run", str(folder), "--camera", str(luxapose / "camera_lumia1020.yaml"),
                "--map", str(luxapose / "map_test_rig.json")]) == 0
    out, err = capsys.readouterr()
    recs = {r["file"]: r for r in _lines(out)}
    assert sorted(recs) == ["small_blob.jpg", "x_0_y_1.27.jpg", "z_portrait.jpg"]
    truth = (0.0, 0.0127)
    for name in ("x_0_y_1.27.jpg", "z_portrait.jpg"):
        p = recs[name]["position"]
        assert p is not None and np.hypot(p["x"] - truth[0], p["y"] - truth[1]) < 0.05, (name, p)
    # small_blob: four IDs, the map does not say its handedness and neither fit decides it
    blob = recs["small_blob.jpg"]
    assert len([d for d in blob["leds"] if d["id"] is not None]) == 4
    assert blob["position"] is None and blob["no_fix"] == "handedness undecided"
    assert "no position: 1 handedness undecided" in err and '"handedness"' in err
    # ... but another photo of the folder tells it (on its own receiver): the summary names it
    assert 'x_0_y_1.27.jpg tells it is left-handed: add "handedness": "left" to the map' in err


def test_a_photo_alone_whose_handedness_is_undecided_gets_the_general_advice(luxapose, capsys):
    assert cli(["run", str(luxapose / "small_blob.jpg"), "--camera", str(luxapose / "camera_lumia1020.yaml"),
                "--map", str(luxapose / "map_test_rig.json")]) == 0
    err = capsys.readouterr().err
    assert 'no photo/frame could tell it (both fits poor): add "handedness": "left" or "right"' in err
