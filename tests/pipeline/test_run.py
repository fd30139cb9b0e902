"""`occloc run` end to end: JSON lines, summary, options and one-line errors."""

from __future__ import annotations

import io
import json
import shutil
import sys

import cv2
import numpy as np
import pytest

from receiver.cli import main as cli
from receiver.cli.run import Progress
from receiver.io.camera import fit_camera
from receiver.cli.benchscene import bench_camera

REQUIRED = {"frame", "t", "latency_ms", "leds", "position", "vehicle"}
LED_REQUIRED = {"track", "id", "mode", "cx", "cy", "area_px", "distance_m"}


@pytest.fixture(autouse=True)
def no_positioner(monkeypatch):
    """These tests are about frames in / lines out; positioning has its own tests (and the
    bench map's LED positions are not a consistent scene)."""
    monkeypatch.setattr("receiver.cli.run.make_positioner", lambda camera, led_map: None)


def _lines(text):
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def test_run_on_a_recording_writes_one_line_per_frame(synth_recording, capsys):
    assert cli(["run", str(synth_recording["path"])]) == 0
    out, err = capsys.readouterr()
    recs = _lines(out)
    assert [r["frame"] for r in recs] == list(range(10))
    assert recs[3]["t"] == pytest.approx(0.1)
    ids = set()
    for r in recs:
        assert set(r) >= REQUIRED and "stage_ms" not in r
        assert len(r["leds"]) == 8
        for d in r["leds"]:
            assert set(d) >= LED_REQUIRED
            assert d["id"] is None or d["id"] in synth_recording["ids"]
            ids.add(d["id"])
    assert ids - {None} == set(synth_recording["ids"])
    summary = err.strip().splitlines()[-1]
    assert "10 frames" in summary and "p99" in summary and "skipped corrupt frames: 0" in summary


def test_run_profile_out_and_max_frames(synth_recording, tmp_path, capsys):
    out = tmp_path / "o.jsonl"
    assert cli(["run", str(synth_recording["path"]), "--profile", "--max-frames", "3", "--out", str(out)]) == 0
    recs = _lines(out.read_text())
    assert len(recs) == 3 and capsys.readouterr().out == ""
    assert {"detect", "track", "decode"} <= set(recs[0]["stage_ms"])


def test_run_raw_frames_on_stdin(synth_recording, monkeypatch, capsys):
    rec = synth_recording["path"]
    raw = b"".join(f.tobytes() for f in synth_recording["frames"][:4])
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(raw)))
    argv = ["run", "-", "--size", "1280x720", "--pix-fmt", "gray", "--fps", "30",
            "--camera", str(rec / "camera.yaml"), "--map", str(rec / "map.json")]
    assert cli(argv) == 0
    recs = _lines(capsys.readouterr().out)
    assert [r["frame"] for r in recs] == [0, 1, 2, 3]
    assert recs[2]["t"] == pytest.approx(2 / 30, abs=1e-6)


def test_run_realtime_counts_dropped_frames(synth_recording, capsys):
    assert cli(["run", str(synth_recording["path"]), "--realtime"]) == 0
    out, err = capsys.readouterr()
    recs = _lines(out)
    dropped = int(err.split("dropped: ")[1].split()[0].rstrip(";"))
    assert len(recs) + dropped == 10 and recs[-1]["frame"] == 9


def _err_one_line(capsys):
    err = capsys.readouterr().err.strip()
    assert err.startswith("occloc: ") and "\n" not in err and "Traceback" not in err
    return err


def test_bad_inputs_are_one_line_errors(synth_recording, tmp_path, monkeypatch, capsys):
    rec = synth_recording["path"]
    assert cli(["run", str(tmp_path / "nope.mkv")]) == 2
    _err_one_line(capsys)
    assert cli(["run", str(rec / "video.mkv")]) == 2  # a bare video needs --camera
    assert "--camera" in _err_one_line(capsys)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert cli(["run", str(rec), "--map", str(bad)]) == 2
    _err_one_line(capsys)
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"\0" * 5000)))
    assert cli(["run", "-", "--size", "1280x720", "--camera", str(rec / "camera.yaml"),
                "--map", str(rec / "map.json")]) == 2
    assert "wrong --size" in _err_one_line(capsys)
    assert cli(["run", "/dev/video97", "--camera", str(rec / "camera.yaml"), "--map", str(rec / "map.json")]) == 2
    _err_one_line(capsys)
    folder = tmp_path / "nocam"
    folder.mkdir()
    shutil.copy(rec / "video.mkv", folder / "video.mkv")
    assert cli(["run", str(folder)]) == 2
    assert "camera" in _err_one_line(capsys)
    assert cli(["run", str(tmp_path / "missing.mkv")]) == 2
    assert "no such file" in _err_one_line(capsys)


def test_photo_of_other_size_scales_or_rotates_the_camera(tmp_path):
    cam = bench_camera()  # 1280x720
    scaled, rot = fit_camera(cam, (640, 360))
    assert not rot and scaled.width == 640 and scaled.row_readout_us == pytest.approx(2 * cam.row_readout_us)
    same, rot = fit_camera(cam, (720, 1280))
    assert rot and same is cam
    from receiver.core.errors import InputError
    with pytest.raises(InputError, match="aspect"):
        fit_camera(cam, (640, 640))


def test_photo_with_wrong_aspect_is_an_error(synth_recording, tmp_path, capsys):
    rec = synth_recording["path"]
    cv2.imwrite(str(tmp_path / "p.png"), np.zeros((100, 100), np.uint8))
    assert cli(["run", str(tmp_path / "p.png"), "--camera", str(rec / "camera.yaml"),
                "--map", str(rec / "map.json")]) == 2
    assert "aspect" in _err_one_line(capsys)


def test_progress_line_on_tty_and_every_n_frames_otherwise():
    class Tty(io.StringIO):
        def isatty(self):
            return True
    t = iter(range(100))
    tty = Tty()
    p = Progress(tty, total=5, clock=lambda: next(t))
    for n in range(1, 6):
        p.update(n, 2)
    p.done()
    assert tty.getvalue().count("\r") == 5 and tty.getvalue().endswith("\n")
    plain = io.StringIO()
    p = Progress(plain, every=2)
    for n in range(1, 6):
        p.update(n, 0)
    assert plain.getvalue().splitlines() == ["frame 2, 0 IDs decoded", "frame 4, 0 IDs decoded"]


# -- real phone photos (../shared/real/luxapose): every LED found, IDs right ------------------

PHOTOS = {  # photo -> (map, {nominal Hz: approximate centre in sensor orientation, px})
    "x_0_y_1.27.jpg": ("map_test_rig.json", {3500: (3055, 1339), 2000: (4747, 1345), 4000: (3894, 2163),
                                            3000: (3046, 2967), 2500: (4735, 2983)}),
    "small_blob.jpg": ("map_test_rig.json", {2000: (3985, 595), 3500: (1460, 2392), 4000: (3782, 2553),
                                            2500: (6146, 2691)}),
    "chandelier0_2013-05-11--02-08-21-25.jpg": ("map_chandelier0.json", {
        3000: (4041, 1214), 4000: (3864, 1695), 5000: (3411, 1743), 2000: (4345, 1838)}),
}


@pytest.mark.parametrize("photo", sorted(PHOTOS))
def test_real_photos_every_led_found_and_no_wrong_id(luxapose, photo, capsys):
    map_name, leds = PHOTOS[photo]
    assert cli(["run", str(luxapose / photo), "--camera", str(luxapose / "camera_lumia1020.yaml"),
                "--map", str(luxapose / map_name)]) == 0
    (rec,) = _lines(capsys.readouterr().out)
    assert len(rec["leds"]) == len(leds)  # the small non-LED blob and the lamps are not reported
    for nominal, (x, y) in leds.items():
        d = min(rec["leds"], key=lambda d: (d["cx"] - x) ** 2 + (d["cy"] - y) ** 2)
        assert abs(d["cx"] - x) < 10 and abs(d["cy"] - y) < 10
        assert d["id"] in (None, nominal)  # a tone decode is never another LED's frequency
        if d["id"] is not None:
            assert d["mode"] == "tone"
            # The target is 1 %; the tone decoder meets it on most LEDs (README numbers).
            assert d["freq_hz"] == pytest.approx(nominal, rel=0.05)
    ids = [d["id"] for d in rec["leds"] if d["id"] is not None]
    assert len(ids) >= len(leds) - 1 and len(set(ids)) == len(ids)
