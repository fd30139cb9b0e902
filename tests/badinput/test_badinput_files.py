"""Bad input files and arguments: one-line InputError (exit 2), never a traceback, a crash or
an overwritten input. Each case was reproduced on the code before the fix (traceback, SIGSEGV,
hang or a destroyed input file); see tools/badinput_sweep.py for the whole table."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from receiver.cli import main as cli
from receiver.core.errors import InputError
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.io.truth import load_run, load_truth

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")
WALK = os.path.join(ROOT, "recordings", "indoor-walk")
CAM_TEXT = open(os.path.join(STATIC, "camera.yaml"), encoding="utf-8").read()
MAP_OBJ = json.load(open(os.path.join(STATIC, "map.json"), encoding="utf-8"))


def _sha(p):
    return hashlib.sha256(open(p, "rb").read()).hexdigest()


def _one_line(e):
    assert "\n" not in str(e.value)
    return str(e.value)


# ------------------------------------------------------------------ camera.yaml

def test_deeply_nested_camera_file_is_refused_before_opencv(tmp_path):
    # before: SIGSEGV inside cv2.FileStorage
    p = tmp_path / "c.yaml"
    p.write_text("%YAML 1.2\n---\nimage_width: " + "[" * 50000 + "\n")
    with pytest.raises(InputError, match="nested"):
        load_camera(str(p))


def test_oversized_camera_file_is_refused(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(CAM_TEXT + "#" * (2 << 20))
    with pytest.raises(InputError, match="larger than"):
        load_camera(str(p))


@pytest.mark.parametrize("key,value", [
    ("pixel_size_um", ".nan"), ("focal_length_mm", ".inf"), ("row_readout_us", ".nan"),
    ("row_readout_us", "1e300"), ("row_readout_us", "1e-300"), ("image_width", ".nan"),
    ("image_width", ".inf"), ("exposure_us", ".nan"), ("exposure_us", "2e6"), ("fps", "1e300"),
    ("pixel_size_um", "1e-9"), ("image_height", "1e9")])
def test_camera_numbers_outside_their_physical_range(tmp_path, key, value):
    p = tmp_path / "c.yaml"
    p.write_text(re.sub(rf"(?m)^{key}:.*$", f"{key}: {value}", CAM_TEXT))
    with pytest.raises(InputError) as e:
        load_camera(str(p))
    assert key in _one_line(e)


def test_camera_nan_distortion_is_refused(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(re.sub(r"data: \[ -0\.04[^\]]*\]", "data: [ .nan, 0., 0., 0., 0. ]", CAM_TEXT))
    with pytest.raises(InputError, match="distortion"):
        load_camera(str(p))


def test_global_shutter_camera_with_ook_lights_is_one_line(tmp_path, capsys):
    # before: ValueError traceback from the OOK decoder
    p = tmp_path / "c.yaml"
    p.write_text(re.sub(r"(?m)^row_readout_us:.*$", "row_readout_us: 0.", CAM_TEXT))
    assert load_camera(str(p)).row_readout_us == 0  # a global shutter is a valid camera
    assert cli(["run", STATIC, "--camera", str(p), "--max-frames", "1"]) == 2
    assert "rolling shutter" in capsys.readouterr().err


# ------------------------------------------------------------------ map.json

def _map_file(tmp_path, obj=None, text=None):
    p = tmp_path / "map.json"
    p.write_text(text if text is not None else json.dumps(obj))
    return str(p)


def _led0(**kw):
    m = json.loads(json.dumps(MAP_OBJ))
    m["leds"][0].update(kw)
    return m


@pytest.mark.parametrize("obj,needle", [
    (_led0(rate_hz=1e300), "rate_hz"), (_led0(rate_hz=1e-300), "rate_hz"),
    # strings of 3 digits were read as 3 coordinates each; a 401-digit integer overflowed float()
    (_led0(emitters=["123", "456"]), "emitters"), (_led0(emitters=[[10 ** 400, 0, 0], [0, 0, 0]]), "emitters"),
    (_led0(id=70000), "'id'"), (_led0(x=1e7), "'x'"), (_led0(size=[1e-9]), "size"),
    (_led0(size=[500.0]), "size"), (_led0(mode="tone", freq_hz=1e9), "freq_hz")])
def test_map_numbers_outside_their_physical_range(tmp_path, obj, needle):
    with pytest.raises(InputError) as e:
        load_map(_map_file(tmp_path, obj))
    assert needle in _one_line(e)


def test_map_deep_nesting_and_huge_integers(tmp_path):
    # before: RecursionError / ValueError (int too long) tracebacks
    with pytest.raises(InputError, match="nested"):
        load_map(_map_file(tmp_path, text="[" * 100000 + "]" * 100000))
    text = json.dumps(MAP_OBJ).replace('"id": ', '"id": ' + "9" * 5001 + ', "_": ', 1)
    with pytest.raises(InputError, match="not valid JSON"):
        load_map(_map_file(tmp_path, text=text))


def test_map_rate_1e300_is_refused_by_occloc_run(tmp_path, capsys):
    # before: ran 9 frames, then a traceback
    assert cli(["run", STATIC, "--map", _map_file(tmp_path, _led0(rate_hz=1e300)), "--max-frames", "12"]) == 2
    assert "rate_hz" in capsys.readouterr().err


# ------------------------------------------------------------------ truth / run files

def test_truth_and_run_deep_nesting(tmp_path):
    p = tmp_path / "t.jsonl"
    p.write_text("[" * 100000 + "]" * 100000 + "\n")
    with pytest.raises(InputError, match="nested"):
        load_truth(str(p))
    with pytest.raises(InputError, match="nested"):
        load_run(str(p), {})


def test_eval_refuses_another_recordings_truth(tmp_path, capsys):
    run = tmp_path / "run.jsonl"
    assert cli(["run", STATIC, "--out", str(run)]) == 0
    capsys.readouterr()
    # indoor-walk's truth has frames 0..53, covering the run's 0..29: before, scored silently
    assert cli(["eval", str(run), "--truth", os.path.join(WALK, "truth.jsonl")]) == 2
    assert "wrong truth" in capsys.readouterr().err
    assert cli(["eval", str(run), "--truth", os.path.join(STATIC, "truth.jsonl")]) == 0


# ------------------------------------------------------------------ nothing overwritten

@pytest.fixture
def rec(tmp_path):
    d = tmp_path / "rec"
    shutil.copytree(STATIC, d)
    return d


@pytest.mark.parametrize("name", ["video.avi", "map.json", "camera.yaml", "truth.jsonl"])
def test_run_out_never_overwrites_an_input(rec, name, capsys):
    before = _sha(rec / name)
    assert cli(["run", str(rec), "--out", str(rec / name), "--max-frames", "1"]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert _sha(rec / name) == before


def test_run_out_through_a_symlink_is_refused(rec, tmp_path, capsys):
    link = tmp_path / "out.jsonl"
    link.symlink_to(rec / "map.json")
    before = _sha(rec / "map.json")
    assert cli(["run", str(rec), "--out", str(link), "--max-frames", "1"]) == 2
    assert _sha(rec / "map.json") == before
    assert cli(["run", str(rec), "--max-frames", "1", "--out", str(tmp_path / "o.jsonl"),
                "--settings-out", str(rec / "camera.yaml")]) == 2


def test_run_out_is_renamed_into_place(rec, tmp_path, capsys):
    out = tmp_path / "o.jsonl"
    out.write_text("old\n")
    assert cli(["run", str(rec), "--out", str(out), "--max-frames", "2"]) == 0
    assert len(out.read_text().splitlines()) == 2
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp file left


def test_eval_plot_never_overwrites_the_run(tmp_path, capsys):
    run = tmp_path / "run.jsonl"
    assert cli(["run", STATIC, "--out", str(run), "--max-frames", "3"]) == 0
    before = _sha(run)
    assert cli(["eval", str(run), "--truth", os.path.join(STATIC, "truth.jsonl"), "--plot", str(run)]) == 2
    assert _sha(run) == before


def test_synth_out_existing_recording_needs_force(rec, capsys):
    before = _sha(rec / "video.avi")
    assert cli(["synth", "indoor-static", "--frames", "1", "--out", str(rec)]) == 2
    assert "--force" in capsys.readouterr().err
    assert _sha(rec / "video.avi") == before


@pytest.mark.parametrize("args,needle", [
    (["--set", "fps=1e400"], "fps"), (["--set", "dist=(1,2)"], "dist"), (["--set", "read_noise_dn=nan"], "read_noise_dn"),
    (["--set", "fps=-1"], "fps"), (["--set", "width=0"], "image_width"), (["--out", "/proc/x"], "/proc/x")])
def test_synth_bad_values_are_one_line_before_rendering(tmp_path, args, needle, capsys):
    argv = ["synth", "indoor-static", "--frames", "1", "--out", str(tmp_path / "new")] + args
    assert cli(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "FFV1" not in err and len(err.strip().splitlines()) == 1


def test_synth_out_an_existing_file(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("keep")
    assert cli(["synth", "indoor-static", "--frames", "1", "--out", str(f)]) == 2
    assert f.read_text() == "keep"


def test_hil_negative_seed(capsys):
    assert cli(["hil", "--seed", "-1"]) == 2
    assert "--seed" in capsys.readouterr().err


# ------------------------------------------------------------------ sources and arguments

def test_fifo_as_a_photo_is_an_error_not_a_hang(tmp_path, capsys):
    fifo = tmp_path / "x.png"
    os.mkfifo(fifo)
    assert cli(["run", str(fifo), "--camera", os.path.join(STATIC, "camera.yaml"),
                "--map", os.path.join(STATIC, "map.json")]) == 2
    assert "FIFO" in capsys.readouterr().err


def test_fps_inf_is_refused(capsys):
    with pytest.raises(SystemExit) as e:  # range-checked at parse time (an infinite rate would make every t 0)
        cli(["run", STATIC, "--fps", "inf"])
    assert e.value.code == 2 and "--fps" in capsys.readouterr().err


def _sh(cmd):
    return subprocess.run(["bash", "-c", cmd], cwd=ROOT, capture_output=True, timeout=60, text=True)


def test_closed_stdin_and_stdout_are_one_line_errors():
    py = sys.executable
    p = _sh(f"exec {py} -m receiver.cli run - --size 64x36 --camera {STATIC}/camera.yaml --map {STATIC}/map.json <&-")
    assert p.returncode == 2 and "standard input is closed" in p.stderr and "Traceback" not in p.stderr
    p = _sh(f"exec {py} -m receiver.cli run {STATIC} --max-frames 1 >&-")
    assert p.returncode == 2 and "standard output is closed" in p.stderr and "Traceback" not in p.stderr


def test_json_lines_never_hold_nan():
    from receiver.io.files import dumps
    assert dumps({"a": float("nan"), "b": [float("inf"), 1.5]}) == '{"a": null, "b": [null, 1.5]}'


# ------------------------------------------------------------------ file names OpenCV cannot take

def _latin1_tree(tmp_path) -> bytes:
    """A copy of indoor-static in a folder whose name is Latin-1, not UTF-8 ('caf\\xe9')."""
    base = os.fsencode(str(tmp_path))
    rec = base + b"/caf\xe9"
    os.mkdir(rec)
    for name in ("camera.yaml", "map.json", "video.avi"):
        shutil.copy(os.path.join(STATIC, name), rec + b"/" + name.encode())
    return rec


@pytest.mark.parametrize("case", ["run", "check", "calibrate", "camera", "overlay", "synth"])
def test_non_utf8_file_names_are_refused_not_a_crash(tmp_path, case):
    """OpenCV's binding segfaults on a file name Python holds with surrogates (bytes that are not
    UTF-8, under LANG=C as under a UTF-8 locale): every OpenCV call that takes a name goes
    through receiver.io.files.cv_path, a one-line refusal (exit 2) before any work."""
    rec = _latin1_tree(tmp_path)
    cam, map_ = os.path.join(STATIC, "camera.yaml"), os.path.join(STATIC, "map.json")
    out = os.fsencode(str(tmp_path / "o.jsonl"))
    argv = {"run": [b"run", rec, b"--max-frames", b"2", b"--camera", cam, b"--out", out],
            "check": [b"check", rec, b"--max-frames", b"2", b"--camera", cam],
            "calibrate": [b"calibrate", b"rows", rec, b"--camera", cam, b"--ook-rate", b"20000",
                          b"--out", os.fsencode(str(tmp_path / "r.yaml"))],
            "camera": [b"run", STATIC, b"--max-frames", b"2", b"--camera", rec + b"/camera.yaml", b"--out", out],
            "overlay": [b"run", STATIC, b"--max-frames", b"2", b"--out", out, b"--overlay", rec + b"/o.avi"],
            "synth": [b"synth", b"indoor-static", b"--frames", b"2", b"--out", rec + b"/new"]}[case]
    env = dict(os.environ, LANG="C", LC_ALL="C", PYTHONPATH=ROOT)
    p = subprocess.run([sys.executable, "-m", "receiver.cli", *map(os.fsencode, argv)], cwd=ROOT, env=env,
                       stdin=subprocess.DEVNULL, capture_output=True, timeout=300)
    err = p.stderr.decode("utf-8", "replace")
    assert p.returncode == 2, (p.returncode, err)
    lines = [ln for ln in err.splitlines() if ln.startswith("occloc: ")]
    assert len(lines) == 1 and "path is not valid UTF-8" in lines[0], err
    assert "\\xe9" in lines[0]  # the name is shown, escaped
    assert not os.path.exists(out) and not os.path.exists(rec + b"/new")


# ------------------------------------------------------------------ what an error line shows

@pytest.mark.parametrize("name", ["/nonexistent/a\nb", "/nonexistent/\x1b[2J\x1b[31mred", "/nonexistent/\r\t\x7f"])
def test_control_characters_in_a_name_are_escaped_in_the_error(capsys, name):
    """A newline in a file name split the error over two lines, a terminal escape sequence in
    it cleared or recoloured the user's terminal: control characters are shown as \\xNN."""
    assert cli(["run", name, "--camera", os.path.join(STATIC, "camera.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.endswith("\n"), repr(err)
    assert not any(ord(ch) < 32 and ch != "\n" or ord(ch) == 127 for ch in err), repr(err)
    assert "\\x" in err


def test_empty_source_name_is_not_the_bundled_recording(capsys):
    """`occloc run "$REC"` with REC unset ran the bundled demo recording, exit 0."""
    assert cli(["run", ""]) == 2
    assert capsys.readouterr().err == ("occloc: empty source name: give a recording folder, video, photo, "
                                       "photo folder or -\n")
