"""`occloc run` on photos takes each photo's own shutter time (EXIF ExposureTime) instead of the
camera file's one number: a phone's exposure changes from photo to photo."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from receiver.cli import main as cli

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "recordings" / "indoor-static"


def _photo(path: Path, exposure_s: float | None) -> None:
    """One frame of indoor-static (20 kHz OOK lights, rendered at 20 us) saved as a JPEG whose
    EXIF records `exposure_s` (None: no EXIF)."""
    from PIL import Image
    from tools.synth import make_scene, render_frames
    scene = make_scene("indoor-static", seed=3, n_frames=1)
    img = next(iter(render_frames(scene, seed=5)))[0]
    kw = {}
    if exposure_s is not None:
        exif = Image.Exif()
        exif[0x8769] = {0x829A: exposure_s}
        kw["exif"] = exif
    Image.fromarray(np.asarray(img)).save(path, quality=95, **kw)


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("exif")
    _photo(folder / "a_long.jpg", 130e-6)
    _photo(folder / "b_short.jpg", 20e-6)
    _photo(folder / "c_none.jpg", None)
    return folder


def test_a_photos_exif_exposure_is_judged_photo_by_photo(photos, capsys):
    """The camera file says 20 us; a_long.jpg records 130 us (2.6 chips of 20 kHz): said for it
    alone, with its numbers; b_short.jpg (20 us) and c_none.jpg (the camera file's) are not."""
    assert cli(["run", str(photos), "--camera", str(STATIC / "camera.yaml"), "--map", str(STATIC / "map.json")]) == 0
    cap = capsys.readouterr()
    warned = [ln for ln in cap.err.splitlines() if "chips of the 20 kHz OOK chips" in ln]
    assert len(warned) == 1, cap.err
    assert warned[0].startswith("occloc: warning: a_long.jpg: exposure 130 us is 2.60 chips") and \
        "use an exposure <= 90 us" in warned[0] and warned[0].endswith("(the photo's EXIF)"), warned[0]
    assert sorted(json.loads(ln)["file"] for ln in cap.out.splitlines()) == ["a_long.jpg", "b_short.jpg", "c_none.jpg"]


def test_each_photos_receiver_decodes_with_its_own_exposure(photos, monkeypatch, capsys):
    """The OOK decoders of each photo are built with that photo's exposure (the camera file's
    where the photo records none)."""
    from receiver.decode import policy
    seen = []
    real = policy.OokDecoder

    def spy(rate, row_us, exposure_us, *a, **kw):
        seen.append(round(exposure_us, 3))
        return real(rate, row_us, exposure_us, *a, **kw)
    monkeypatch.setattr(policy, "OokDecoder", spy)
    for name, want in (("a_long.jpg", 130.0), ("b_short.jpg", 20.0), ("c_none.jpg", 20.0)):
        seen.clear()
        assert cli(["run", str(photos / name), "--camera", str(STATIC / "camera.yaml"),
                    "--map", str(STATIC / "map.json")]) == 0
        assert seen and set(seen) == {want}, (name, seen)
    capsys.readouterr()
