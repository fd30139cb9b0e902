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
    # ... and check sees those lights striped and passes (its own finding on exposure aside:
    # that verdict is the exposure stage's)
    assert by["stripes"]["ok"] and len(by["stripes"]["leds"]) >= len(decoded), by["stripes"]
    assert by["focus"]["ok"], by["focus"]
    assert all(f["ok"] for name, f in by.items() if name != "exposure"), out
    assert all("v4l2-ctl" not in f["fix"] for name, f in by.items() if name != "exposure")
    if by["exposure"]["ok"]:
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
