"""Work bounded by what an input holds, not by the numbers in it, and no input lost silently:
frame numbers are keys in `occloc eval`; an image's size is checked from its header before it is
decoded; a raw frame on stdin costs what it holds; a JPEG cut short is an error (one image) or a
counted skip (a folder), and libjpeg's own messages never reach standard error."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib

import cv2
import numpy as np
import pytest

from receiver.evaluate import metrics

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")
VEHICLE = os.path.join(ROOT, "recordings", "vehicle")
CAM, MAP = os.path.join(STATIC, "camera.yaml"), os.path.join(STATIC, "map.json")


def occloc(*args, stdin=subprocess.DEVNULL, cwd=None):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "receiver.cli", *map(str, args)], cwd=cwd or ROOT, stdin=stdin,
                          capture_output=True, timeout=300, env=env)


def _png_header_only(path, w, h):
    """A PNG whose header says w x h, with one tiny (broken) data chunk."""
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(data)


def _jpeg(path, cut=1.0):
    img = (np.indices((180, 320)).sum(axis=0) % 256).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", img)
    data = buf.tobytes()
    with open(path, "wb") as f:
        f.write(data[:int(len(data) * cut)])


# ------------------------------------------------------------------ eval

@pytest.mark.parametrize("big", [30_000_000, 10 ** 12])
def test_eval_frame_numbers_are_keys_not_ranges(monkeypatch, big):
    seen = []
    real = metrics.s2psk_qualifying

    def spy(truth, frames, **kw):
        frames = list(frames)
        seen.append(len(frames))
        return real(truth, frames, **kw)

    monkeypatch.setattr(metrics, "s2psk_qualifying", spy)
    run = [{"frame": 0, "leds": []}, {"frame": big, "leds": []}]
    truth = {0: {"t": 0.0, "targets": [], "s2psk": []}, big: {"t": 1.0, "targets": [], "s2psk": []}}
    out = metrics.s2psk_resolvable(run, truth)
    assert seen == [2] and out["wrong_ids"] == 0


def test_eval_command_with_a_huge_frame_number(tmp_path):
    run_file = tmp_path / "run.jsonl"
    p = occloc("run", VEHICLE, "--max-frames", "2", "--out", run_file)
    assert p.returncode == 0, p.stderr.decode()
    lines = run_file.read_text().splitlines()
    o = json.loads(lines[1])
    o["frame"] = 10 ** 12
    run_file.write_text(lines[0] + "\n" + json.dumps(o) + "\n")
    truth_lines = open(os.path.join(VEHICLE, "truth.jsonl"), encoding="utf-8").read().splitlines()
    t = json.loads(truth_lines[1])
    t["frame"] = 10 ** 12
    (tmp_path / "truth.jsonl").write_text(truth_lines[0] + "\n" + json.dumps(t) + "\n")
    p = occloc("eval", run_file, "--truth", tmp_path / "truth.jsonl", "--map", os.path.join(VEHICLE, "map.json"))
    assert p.returncode == 0 and b"Traceback" not in p.stderr, p.stderr.decode()


# ------------------------------------------------------------------ image size before decoding

def test_huge_png_is_refused_from_its_header(tmp_path):
    _png_header_only(tmp_path / "huge.png", 32000, 18000)
    p = occloc("run", tmp_path / "huge.png", "--camera", CAM, "--map", MAP)
    err = p.stderr.decode()
    assert p.returncode == 2 and "pixel limit" in err and "Traceback" not in err, err


def test_max_pixels_option(tmp_path):
    _jpeg(tmp_path / "a.jpg")
    p = occloc("run", tmp_path / "a.jpg", "--camera", CAM, "--map", MAP, "--max-pixels", "1000")
    assert p.returncode == 2 and b"320x180" in p.stderr
    p = occloc("run", tmp_path / "a.jpg", "--camera", CAM, "--map", MAP, "--max-pixels", "0")
    assert p.returncode == 2 and b"error: argument --max-pixels" in p.stderr


def test_stdin_size_over_the_limit_is_refused():
    p = occloc("run", "-", "--size", "100000x100000", "--camera", CAM, "--map", MAP)
    assert p.returncode == 2 and b"pixel limit" in p.stderr


def test_stdin_stride_check_costs_a_band_of_rows(monkeypatch):
    from receiver.io import sources
    sizes = []
    real = np.fft.rfft

    def spy(x, n=None, *a, **kw):
        sizes.append(n)
        return real(x, n, *a, **kw)

    monkeypatch.setattr(np.fft, "rfft", spy)
    w, h = 7680, 4320  # an 8K gray frame
    rng = np.random.default_rng(1)
    frame = np.repeat(rng.integers(0, 255, (h // 8, w), dtype=np.uint8), 8, axis=0)
    assert sources.likely_row_stride(frame.ravel(), w) is None
    assert sizes and max(sizes) <= 1 << 20


# ------------------------------------------------------------------ damaged photos

def test_single_jpeg_cut_to_a_third_is_an_error(tmp_path):
    _jpeg(tmp_path / "cut.jpg", cut=1 / 3)
    p = occloc("run", tmp_path / "cut.jpg", "--camera", CAM, "--map", MAP)
    err = p.stderr.decode()
    assert p.returncode == 2 and "cut short" in err, err
    assert "Premature end" not in err and "Traceback" not in err


def test_folder_whose_first_photo_is_damaged_is_not_refused(tmp_path):
    _jpeg(tmp_path / "a.jpg", cut=1 / 3)
    _jpeg(tmp_path / "b.jpg")
    _jpeg(tmp_path / "c.jpg")
    p = occloc("run", tmp_path, "--camera", CAM, "--map", MAP)
    err = p.stderr.decode()
    assert p.returncode == 0, err
    assert len(p.stdout.decode().splitlines()) == 2
    assert "skipped corrupt frames: 1" in err and "Premature end" not in err


@pytest.mark.parametrize("h, w", [(1, 100000), (100000, 1), (100, 100000)])
def test_calibration_strip_is_refused_before_the_board_search(monkeypatch, h, w):
    """OpenCV's chessboard search on a 100x100000 strip runs past ten minutes: a frame whose
    sides are further apart than any camera's (4:1) is refused before it is searched."""
    from receiver.calibrate import intrinsics
    from receiver.core.errors import InputError

    def never(*a, **k):
        raise AssertionError("the board search ran on a strip")
    monkeypatch.setattr(intrinsics.cv2, "findChessboardCornersSB", never)
    monkeypatch.setattr(intrinsics.cv2, "findChessboardCorners", never)
    col = intrinsics.ViewCollector(intrinsics.parse_board("chess:9x6", 20.0))
    with pytest.raises(InputError, match=f"{w}x{h}: not a camera's frame"):
        col.add(0, np.zeros((h, w), np.uint8))
    assert col.stats.seen == 0


def test_calibration_camera_frames_are_still_searched(monkeypatch):
    from receiver.calibrate import intrinsics
    seen = []

    def search(gray, *a, **k):
        seen.append(gray.shape)
        return False, None
    monkeypatch.setattr(intrinsics.cv2, "findChessboardCornersSB", search)
    monkeypatch.setattr(intrinsics.cv2, "findChessboardCorners", lambda *a, **k: (False, None))
    for shape in ((90, 160), (300, 1200)):   # 16:9 and a 4:1 panorama
        col = intrinsics.ViewCollector(intrinsics.parse_board("chess:9x6", 20.0))
        assert col.add(0, np.zeros(shape, np.uint8)) == "none"
        assert col.stats.seen == 1
    assert seen == [(90, 160), (300, 1200)]


def test_calibrate_command_on_a_strip_png(tmp_path):
    d = tmp_path / "views"
    d.mkdir()
    cv2.imwrite(str(d / "a.png"), np.zeros((1, 100000), np.uint8))
    p = occloc("calibrate", "intrinsics", d, "--board", "chess:9x6", "--square-mm", "20", "--out", tmp_path / "i.yaml")
    err = p.stderr.decode()
    assert p.returncode == 2 and "Traceback" not in err, err
    assert "100000x1: not a camera's frame" in err.splitlines()[-1], err
    assert not (tmp_path / "i.yaml").exists()
