"""`occloc check` on photos agrees with `occloc run` (passes where run decodes), names every
verdict's measured value and limit, and words its advice for the source."""

from __future__ import annotations

import json

import numpy as np
import pytest

from receiver.calibrate.check import FIXES, Finding, check_frames, fix_for
from receiver.cli import main as occloc
from receiver.core.records import Frame

PHOTOS = {"x_0_y_1.27.jpg": "map_test_rig.json", "small_blob.jpg": "map_test_rig.json",
          "chandelier0_2013-05-11--02-08-21-25.jpg": "map_chandelier0.json"}


@pytest.mark.parametrize("photo", sorted(PHOTOS))
def test_check_passes_every_real_photo_run_decodes(luxapose, photo, capsys):
    argv = [str(luxapose / photo), "--camera", str(luxapose / "camera_lumia1020.yaml"),
            "--map", str(luxapose / PHOTOS[photo])]
    assert occloc(["run", *argv]) == 0
    (rec,) = [json.loads(l) for l in capsys.readouterr().out.splitlines()]
    decoded = [d for d in rec["leds"] if d["id"] is not None]
    assert len(decoded) >= 3  # run decodes the photo ...
    rc = occloc(["check", *argv, "--json"])
    out = json.loads(capsys.readouterr().out)
    by = {f["check"]: f for f in out["findings"]}
    # ... and check sees those lights striped and passes every test
    assert by["stripes"]["ok"] and len(by["stripes"]["leds"]) >= len(decoded), by["stripes"]
    assert by["focus"]["ok"], by["focus"]
    assert all(f["ok"] for f in by.values()), out
    assert rc == 0


def _clip(n=4):
    g = np.full((240, 320), 20, np.uint8)
    return [Frame(i, i / 30.0, g.copy()) for i in range(n)]


def test_advice_fits_the_source():
    for name in FIXES:
        assert "v4l2-ctl" in fix_for(name, "v4l2") or name == "no_leds"
        assert "v4l2-ctl" not in fix_for(name, "images") or name not in ("no_leds", "stripes", "focus")
    photo = check_frames(_clip(1), source_kind="images")
    stripes = next(f for f in photo if f.name == "stripes")
    assert not stripes.ok and "photo" in stripes.text and "v4l2" not in stripes.fix
    assert {f.name: f.text for f in photo}["timestamps"].endswith("not applicable to independent photos")
    cam = check_frames(_clip(), source_kind="v4l2")
    assert next(f for f in cam if f.name == "stripes").fix == fix_for("no_leds", "v4l2")
    assert "photograph" in fix_for("no_leds", "images") and "photograph" not in fix_for("no_leds", "v4l2")


def test_every_clip_verdict_names_its_limit():
    from pathlib import Path
    from receiver.io.camera import load_camera
    from receiver.io.ledmap import load_map
    from receiver.io.sources import open_source
    rec = Path(__file__).resolve().parents[2] / "recordings" / "indoor-static"
    cam, led_map = load_camera(str(rec / "camera.yaml")), load_map(str(rec / "map.json"))
    src = open_source(str(rec), camera=cam)
    try:
        fs = check_frames(src, cam, led_map, max_frames=12, source_kind="recording")
    finally:
        src.close()
    texts = {f.name: f.text for f in fs}
    assert "(each needs >= 0.35)" in texts["stripes"]
    assert "limit" in texts["gain_drift"] and "limit" in texts["banding"] and "limit" in texts["focus"]
    assert "limit" in texts["timestamps"]
    assert isinstance(fs[0], Finding)


def test_check_on_a_folder_of_photos_of_several_sizes(luxapose, tmp_path, capsys):
    """Photos of one camera saved at several sizes (and one turned to portrait): every check
    gives a verdict (banding over the photos of the most common size), no traceback."""
    import cv2
    g = cv2.imread(str(luxapose / "x_0_y_1.27.jpg"), cv2.IMREAD_GRAYSCALE)
    folder = tmp_path / "photos"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), g)
    cv2.imwrite(str(folder / "b.png"), cv2.resize(g, (g.shape[1] // 2, g.shape[0] // 2), interpolation=cv2.INTER_AREA))
    cv2.imwrite(str(folder / "c.png"), cv2.rotate(g, cv2.ROTATE_90_CLOCKWISE))
    cv2.imwrite(str(folder / "d.png"), cv2.resize(g, (g.shape[1] // 4, g.shape[0] // 4), interpolation=cv2.INTER_AREA))
    rc = occloc(["check", str(folder), "--camera", str(luxapose / "camera_lumia1020.yaml"),
                 "--map", str(luxapose / "map_test_rig.json"), "--json"])
    assert rc in (0, 1)
    out = json.loads(capsys.readouterr().out)
    by = {f["check"]: f for f in out["findings"]}
    assert "banding" in by and by["stripes"]["ok"], out


@pytest.mark.parametrize("photo", sorted(PHOTOS))
def test_exposure_verdict_of_a_photo_names_value_and_limit(luxapose, photo, capsys):
    argv = [str(luxapose / photo), "--camera", str(luxapose / "camera_lumia1020.yaml"),
            "--map", str(luxapose / PHOTOS[photo]), "--json"]
    occloc(["check", *argv])
    by = {f["check"]: f for f in json.loads(capsys.readouterr().out)["findings"]}
    exp = by["exposure"]
    # the limit of the map's fastest tone (4000 or 5000 Hz): its half period (full-depth stripes)
    fastest = 5000.0 if "chandelier" in photo else 4000.0
    assert exp["limit_us"] == pytest.approx(1e6 / (2 * fastest))
    # every photo was taken at 1/16667 s (60 us; the camera file), which run decodes: check agrees
    assert exp["ok"], exp
    assert f"(limit {exp['limit_us']:.0f} us" in exp["text"], exp["text"]
    # a value, never the "~0 us" of a stripe fit that resolved no ramp
    assert "~0 us" not in exp["text"] and "exposure ~" in exp["text"]
    assert by["banding"]["text"] == "not applicable to independent photos"


def test_exposure_advice_fits_the_source():
    from receiver.calibrate.check import exposure_fix
    photo = exposure_fix("images", 62.5)
    assert "shutter time of 1/16000 s or shorter" in photo and "v4l2" not in photo
    assert "exposure_time_absolute=N" in exposure_fix("v4l2", 250.0) and "N <= 2" in exposure_fix("v4l2", 250.0)
    video = exposure_fix("video", 250.0)
    assert "<= 250 us" in video and "1/4000 s" in video


def test_a_too_long_exposure_on_a_photo_is_failed_with_photo_advice(luxapose, tmp_path, capsys):
    """The camera file's exposure (the photo's EXIF) far beyond what the tones allow, on a photo
    without stripes to measure it from (so the camera file's value is judged): the verdict names
    both numbers, and the advice is the camera app's, not v4l2-ctl."""
    from receiver.calibrate.check import check_frames
    from receiver.io.camera import load_camera
    from receiver.io.ledmap import load_map
    import cv2
    import dataclasses
    cam = dataclasses.replace(load_camera(str(luxapose / "camera_lumia1020.yaml")), exposure_us=2000.0)
    g = cv2.imread(str(luxapose / "x_0_y_1.27.jpg"), cv2.IMREAD_GRAYSCALE)
    fs = check_frames([Frame(0, 0.0, np.full_like(g, 10))], cam, load_map(str(luxapose / "map_test_rig.json")),
                      source_kind="images")
    exp = next(f for f in fs if f.name == "exposure")
    assert not exp.ok and "exposure ~2000 us (limit 125 us" in exp.text and "(camera file)" in exp.text
    assert "shutter time" in exp.fix and "v4l2" not in exp.fix


def test_the_photos_own_exif_exposure_is_judged(luxapose, tmp_path, capsys):
    """A photo records its shutter time (EXIF ExposureTime): check judges that, whatever the
    camera file says; the Luxapose photos' 60 us pass, the same photo marked 1/500 s fails with
    both numbers and the camera app's advice."""
    from PIL import Image
    from receiver.io.imagefile import exif_exposure_us
    assert exif_exposure_us(str(luxapose / "x_0_y_1.27.jpg")) == pytest.approx(60.0)
    slow = tmp_path / "slow.jpg"
    exif = Image.Exif()
    exif[0x8769] = {0x829A: 0.002}
    with Image.open(luxapose / "x_0_y_1.27.jpg") as im:
        im.convert("L").resize((1928, 1088)).save(slow, exif=exif, quality=95)
    assert exif_exposure_us(str(slow)) == pytest.approx(2000.0)
    assert exif_exposure_us(str(tmp_path)) is None
    argv = ["--camera", str(luxapose / "camera_lumia1020.yaml"), "--map", str(luxapose / "map_test_rig.json"), "--json"]
    assert occloc(["check", str(luxapose / "x_0_y_1.27.jpg"), *argv]) == 0
    exp = {f["check"]: f for f in json.loads(capsys.readouterr().out)["findings"]}["exposure"]
    assert exp["ok"] and exp["text"].endswith("(the photos' EXIF)") and exp["exposure_us"] == pytest.approx(60.0)
    assert occloc(["check", str(slow), *argv]) == 1
    exp = {f["check"]: f for f in json.loads(capsys.readouterr().out)["findings"]}["exposure"]
    assert not exp["ok"] and "exposure ~2000 us (limit 125 us" in exp["text"] and "EXIF" in exp["text"]
    assert "shutter time of 1/8000 s or shorter" in exp["fix"]
