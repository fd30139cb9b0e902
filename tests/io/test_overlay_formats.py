"""The overlay: format by extension (stills, videos players open), an error for one it cannot
write, and text scaled to the image."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.cli import main as occloc
from receiver.core.errors import InputError
from receiver.io.overlay import OverlayWriter, scale_for
from tests.io.test_overlay import _frame

STATIC = Path(__file__).resolve().parents[2] / "recordings" / "indoor-static"


def _text_rows(img) -> int:
    """Rows of the top-left text block with white text pixels."""
    band = img[: img.shape[0] // 4, : img.shape[1] // 3]
    return int((band.min(axis=2) > 200).any(axis=1).sum())


def test_text_scales_with_the_image(tmp_path):
    gray, res = _frame()
    small = OverlayWriter(str(tmp_path / "a.png"), (320, 240), 30.0).annotate(gray, res)
    big_gray = cv2.resize(gray, (3200, 2400), interpolation=cv2.INTER_NEAREST)
    big = OverlayWriter(str(tmp_path / "b.png"), (3200, 2400), 30.0).annotate(big_gray, res)
    assert scale_for((320, 240)) == 1.0 and scale_for((7712, 4352)) == pytest.approx(4352 / 720)
    # the same lines of text, about 3.3 x taller on the 10 x larger image (scale 2400 / 720)
    assert _text_rows(big) >= 2.5 * _text_rows(small) > 0


@pytest.mark.parametrize("name", ["still.jpg", "still.png", "clip.mp4", "clip.avi"])
def test_each_extension_gives_a_file_its_readers_open(tmp_path, name):
    gray, res = _frame()
    path = tmp_path / name
    w = OverlayWriter(str(path), (320, 240), 30.0)
    for _ in range(3):
        w.write(gray, res)
    w.close()
    if name.startswith("still"):
        assert cv2.imread(str(path)).shape == (240, 320, 3)
    else:
        cap = cv2.VideoCapture(str(path))
        ok, img = cap.read()
        assert ok and img.shape == (240, 320, 3) and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3


def test_an_extension_it_cannot_write_is_an_error(tmp_path, capsys):
    with pytest.raises(InputError):
        OverlayWriter(str(tmp_path / "x.gif"), (320, 240), 30.0)
    out = tmp_path / "x.gif"
    assert occloc(["run", str(STATIC), "--max-frames", "1", "--overlay", str(out),
                   "--out", str(tmp_path / "o.jsonl")]) == 2
    assert "cannot write .gif" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "o.jsonl").exists()
