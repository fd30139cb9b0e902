"""receiver.io.overlay.OverlayWriter: a PNG for one frame, a short video; annotations where blobs are."""

from __future__ import annotations

import cv2
import numpy as np

from receiver.core.records import FrameResult, LedObservation, PairObservation
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.io.overlay import OverlayWriter
from pathlib import Path

REC = Path(__file__).resolve().parents[2] / "recordings" / "indoor-static"


def _frame():
    gray = np.zeros((240, 320), np.uint8)
    gray[100:140, 150:190] = 180
    c = np.array([[150, 100], [189, 100], [189, 139], [150, 139]], float)
    led = LedObservation(track=3, cx=169.5, cy=119.5, area_px=1600.0, contour=c, id=42, mode="ook",
                         distance_m=2.5)
    pair = PairObservation((1, 2), 0x81, "FV", (40.0, 200.0), (90.0, 200.0), 30.0, 30.0, 50.0, True)
    res = FrameResult(0, 0.0, 1.0, [led], position={"x": 2.0, "y": 2.0, "z": 1.0, "method": "pose", "n_leds": 3},
                      vehicle={"hv": {"x": 1.0, "y": 0.0}, "fv": [{"id": 129, "distance_m": 12.0, "angle_deg": 2.0}]},
                      pairs=(pair,))
    return gray, res


def test_png_and_video(tmp_path):
    cam, m = load_camera(str(REC / "camera.yaml")), load_map(str(REC / "map.json"))
    gray, res = _frame()
    png = tmp_path / "one.png"
    w = OverlayWriter(str(png), (320, 240), 30.0, cam, m)
    w.write(gray, res)
    w.close()
    img = cv2.imread(str(png))
    assert img.shape == (240, 320, 3)
    # the envelope drawn in green on the blob's outline, the pair line in cyan
    edge = img[100, 150:190]
    assert (edge[:, 1] > 200).any() and (edge[:, 0] < 100).any()
    assert (img[200, 50:80, 0] > 200).any()
    plain = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    assert (img != plain).any(axis=2)[:60, :].sum() > 50  # text, and the inset top right
    avi = tmp_path / "clip.avi"
    w = OverlayWriter(str(avi), (320, 240), 30.0, cam, m)
    for k in range(5):
        w.write(gray, res)
    w.close()
    cap = cv2.VideoCapture(str(avi))
    n = 0
    while True:
        ok, f = cap.read()
        if not ok:
            break
        assert f.shape == (240, 320, 3)
        n += 1
    assert n == 5


def test_occloc_run_overlay_writes_the_picture_and_never_an_input(tmp_path):
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    walk = root / "recordings" / "indoor-walk"
    png = tmp_path / "o.png"
    proc = subprocess.run([sys.executable, "-m", "receiver.cli", "run", str(walk), "--max-frames", "3",
                           "--overlay", str(png), "--out", str(tmp_path / "o.jsonl")],
                          cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    img = cv2.imread(str(png))
    assert img is not None and img.shape[:2] == (720, 1280)
    assert not list(tmp_path.glob(".*tmp*"))  # the temporary sibling was renamed into place
    before = (walk / "map.json").read_bytes()
    proc = subprocess.run([sys.executable, "-m", "receiver.cli", "run", str(walk), "--max-frames", "1",
                           "--overlay", str(walk / "map.json")], cwd=root, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert (walk / "map.json").read_bytes() == before
