"""Every command's outputs go through one helper (receiver.io.files.claim_output): an output
that resolves to an input (through symlinks and hard links), to a folder or to another output
is refused before any work with a one-line error and exit 2; a device or FIFO is written
directly and a symlink followed (never replaced); an existing file keeps its mode, a new one
gets the umask's; nothing hidden is left behind after an error or a signal; a full disk names
the output, never the input. The commands run as `python -m receiver.cli` in a child process."""

from __future__ import annotations

import hashlib
import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from receiver.core.errors import InputError
from receiver.io.files import claim_output

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")
WALK = os.path.join(ROOT, "recordings", "indoor-walk")


def occloc(*args, stdout=subprocess.PIPE, preexec_fn=None, timeout=300, cwd=None):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "receiver.cli", *map(str, args)], cwd=cwd or ROOT,
                          stdin=subprocess.DEVNULL, stdout=stdout, stderr=subprocess.PIPE,
                          timeout=timeout, env=env, preexec_fn=preexec_fn)


def _err(p) -> str:
    return p.stderr.decode("utf-8", "replace")


def _refused(p, *words):
    err = _err(p)
    assert p.returncode == 2, err
    assert "Traceback" not in err
    # progress lines ("occloc calibrate: ...", "occloc bench: ...") may come before the error
    lines = [ln for ln in err.splitlines() if ln.startswith("occloc: ")]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def _sha(p):
    with open(p, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def _hidden(folder):
    return sorted(n for n in os.listdir(folder) if n.startswith("."))


@pytest.fixture()
def rec(tmp_path):
    d = tmp_path / "rec"
    shutil.copytree(STATIC, d)
    for name in os.listdir(d):
        os.chmod(d / name, 0o644)
    return d


def _small_full_disk():
    """preexec_fn: files the child writes stop growing at 64 KB (EFBIG, SIGXFSZ is ignored by
    Python), standing in for a full disk."""
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 << 10, 64 << 10))


# ------------------------------------------------------------------ the helper

def test_helper_refuses_inputs_through_hard_and_symbolic_links(tmp_path):
    src = tmp_path / "in.png"
    src.write_bytes(b"x")
    os.link(src, tmp_path / "hard")
    os.symlink(src, tmp_path / "soft")
    for out in ("hard", "soft"):
        with pytest.raises(InputError, match="input of this command"):
            claim_output(str(tmp_path / out), [str(src)], "--out")
    # a folder input stands for the media and recording files in it
    with pytest.raises(InputError, match="input of this command"):
        claim_output(str(tmp_path / "hard"), [str(tmp_path)], "--out")
    with pytest.raises(InputError, match="is a folder"):
        claim_output(str(tmp_path), [], "--out")
    with pytest.raises(InputError, match="no folder"):
        claim_output(str(tmp_path / "nope" / "x.json"), [], "--out")


def test_helper_follows_symlink_keeps_mode_and_leaves_nothing(tmp_path):
    target = tmp_path / "target.json"
    target.write_text("old")
    os.chmod(target, 0o640)
    link = tmp_path / "link.json"
    os.symlink(target, link)
    out = claim_output(str(link), [], "--out")
    f = out.open()
    f.write("new")
    assert _hidden(tmp_path) == []          # staged anonymously
    f.commit()
    assert os.path.islink(link) and target.read_text() == "new"
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o640
    f = claim_output(str(tmp_path / "other.json"), [], "--out").open()
    f.write("x")
    f.discard()
    assert sorted(os.listdir(tmp_path)) == ["link.json", "target.json"]


def test_helper_new_file_gets_the_umask_mode(tmp_path):
    old = os.umask(0o027)
    try:
        claim_output(str(tmp_path / "n.json"), [], "--out").write_text("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "n.json").st_mode) == 0o640


def test_helper_writes_a_fifo_directly(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    claim_output(str(fifo), [], "--out").write_text("line\n")
    reader.join(30)
    assert got == [b"line\n"] and stat.S_ISFIFO(os.stat(fifo).st_mode)


# ------------------------------------------------------------------ run

def test_run_out_hard_link_to_the_video_is_refused(rec, tmp_path):
    os.link(rec / "video.avi", tmp_path / "run.jsonl")
    before = _sha(rec / "video.avi")
    _refused(occloc("run", rec, "--max-frames", "2", "--out", tmp_path / "run.jsonl"),
             "is an input of this command")
    assert _sha(rec / "video.avi") == before


@pytest.mark.parametrize("flag", ["--out", "--settings-out", "--overlay"])
def test_run_outputs_into_inputs_are_refused(rec, flag):
    """Refused as the input it is, before any check of its name (the map is not a .png)."""
    before = _sha(rec / "map.json")
    line = _refused(occloc("run", rec, "--max-frames", "2", flag, rec / "map.json"))
    assert line == f"occloc: {flag} {rec / 'map.json'} is an input of this command ({rec / 'map.json'}): " \
                   "refusing to overwrite it", line
    assert _sha(rec / "map.json") == before


def test_run_same_file_for_two_outputs_is_said_before_its_extension(rec, tmp_path):
    line = _refused(occloc("run", rec, "--max-frames", "2", "--out", tmp_path / "o.png", "--overlay", tmp_path / "o.png"))
    assert line == f"occloc: --overlay {tmp_path / 'o.png'} is also --out: give each output its own file", line


def test_run_two_outputs_one_file_is_refused(rec, tmp_path):
    _refused(occloc("run", rec, "--max-frames", "2", "--out", tmp_path / "a", "--settings-out", tmp_path / "a"),
             "--settings-out", "is also --out")


@pytest.mark.parametrize("flag", ["--out", "--overlay", "--settings-out"])
def test_run_output_folder_is_refused_before_work_and_leaves_nothing(rec, tmp_path, flag):
    d = tmp_path / "outdir"
    d.mkdir()
    _refused(occloc("run", rec, flag, d), f"{flag} {d} is a folder: give a file name")
    assert os.listdir(d) == [] and _hidden(tmp_path) == []


def test_run_out_symlink_is_followed_and_mode_kept(rec, tmp_path):
    target = tmp_path / "t.jsonl"
    target.write_text("")
    os.chmod(target, 0o604)
    link = tmp_path / "l.jsonl"
    os.symlink(target, link)
    p = occloc("run", rec, "--max-frames", "2", "--out", link)
    assert p.returncode == 0, _err(p)
    assert os.path.islink(link) and len(target.read_text().splitlines()) == 2
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o604


def test_run_out_fifo_is_written_not_replaced(rec, tmp_path):
    fifo = tmp_path / "p"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    p = occloc("run", rec, "--max-frames", "2", "--out", fifo)
    reader.join(60)
    assert p.returncode == 0, _err(p)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert got and len(got[0].splitlines()) == 2


def test_run_out_dev_stdout_on_a_pipe_is_written():
    """/dev/stdout -> /proc/self/fd/1 -> 'pipe:[N]', which is no path: the name given is opened
    (it was 'cannot write --out /dev/stdout: No such file or directory')."""
    p = occloc("run", STATIC, "--max-frames", "2", "--out", "/dev/stdout")
    assert p.returncode == 0, _err(p)
    lines = p.stdout.decode().splitlines()
    assert len(lines) == 2 and all(ln.startswith('{"frame":') for ln in lines), lines


def test_run_killed_leaves_no_hidden_file(tmp_path):
    """SIGKILL while the run waits for more frames on stdin (its output open): nothing is left,
    neither the output nor a hidden temporary file."""
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.Popen([sys.executable, "-m", "receiver.cli", "run", "-", "--size", "64x36",
                          "--camera", os.path.join(WALK, "camera.yaml"), "--map", os.path.join(WALK, "map.json"),
                          "--out", str(tmp_path / "r.jsonl")],
                         cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    p.stdin.write(bytes(64 * 36 * 2))
    p.stdin.flush()
    time.sleep(5.0)  # imports done, output opened, two frames processed, waiting for the third
    p.kill()
    p.wait()
    p.stdin.close()
    assert os.listdir(tmp_path) == []


def test_run_stdout_full_disk_names_standard_output():
    p = occloc("run", STATIC, "--max-frames", "3", stdout=open(os.devnull if not os.path.exists("/dev/full")
                                                                 else "/dev/full", "wb"))
    line = _refused(p, "standard output")
    assert "indoor-static" not in line


def _private_full_device(folder):
    """A character device like /dev/full in `folder` (root only), so that a regression that
    renames over its output can never replace the system's /dev/full; None when not allowed."""
    path = os.path.join(folder, "full")
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
    except (PermissionError, OSError):
        return None
    return path


def test_run_out_device_full_names_the_output(rec, tmp_path):
    dev = _private_full_device(str(tmp_path))
    if dev is not None:
        _refused(occloc("run", rec, "--max-frames", "2", "--out", dev), f"--out {dev}", "No space left")
        assert stat.S_ISCHR(os.stat(dev).st_mode)
    # a regular file on a full disk (files stop growing at 64 KB)
    out = tmp_path / "big.jsonl"
    _refused(occloc("run", WALK, "--out", out, preexec_fn=_small_full_disk), f"--out {out}")
    assert not out.exists() and _hidden(tmp_path) == []


def test_run_overlay_on_a_full_disk_is_an_error(rec, tmp_path):
    p = occloc("run", rec, "--max-frames", "12", "--overlay", tmp_path / "o.avi", "--out", tmp_path / "r.jsonl",
               preexec_fn=_small_full_disk)
    _refused(p, "--overlay")
    assert not os.path.exists(tmp_path / "o.avi") and _hidden(tmp_path) == []


def test_run_closed_stderr_keeps_stdout_json_lines():
    py = sys.executable
    p = subprocess.run(["bash", "-c", f"exec {py} -m receiver.cli run {STATIC} --max-frames 2 2>&-"], cwd=ROOT,
                       capture_output=True, timeout=300, env=dict(os.environ, PYTHONPATH=ROOT))
    assert p.returncode == 0
    lines = p.stdout.decode().splitlines()
    assert len(lines) == 2 and all(ln.startswith("{") for ln in lines)


def test_run_max_frames_zero_prints_no_nan(rec):
    p = occloc("run", rec, "--max-frames", "0")
    assert p.returncode == 0 and "nan" not in _err(p)


# ------------------------------------------------------------------ eval

def _run_file(tmp_path):
    out = tmp_path / "run.jsonl"
    p = occloc("run", STATIC, "--max-frames", "3", "--out", out)
    assert p.returncode == 0, _err(p)
    return out


def test_eval_plot_onto_the_map_beside_truth_is_refused(rec, tmp_path):
    run = _run_file(tmp_path)
    before = _sha(rec / "map.json")
    _refused(occloc("eval", run, "--truth", rec / "truth.jsonl", "--plot", rec / "map.json"), "--plot", "input")
    assert _sha(rec / "map.json") == before


def test_eval_stdout_full_disk_names_standard_output(tmp_path):
    run = _run_file(tmp_path)
    _refused(occloc("eval", run, "--truth", os.path.join(STATIC, "truth.jsonl"), stdout=open("/dev/full", "wb")),
             "standard output")


# ------------------------------------------------------------------ calibrate

def test_calibrate_rows_out_onto_the_video_is_refused(rec):
    before = _sha(rec / "video.avi")
    _refused(occloc("calibrate", "rows", rec, "--camera", rec / "camera.yaml", "--ook-rate", "20000",
                    "--out", rec / "video.avi"), "input")
    assert _sha(rec / "video.avi") == before


def test_calibrate_rows_in_place_keeps_the_mode(rec):
    p = occloc("calibrate", "rows", rec, "--camera", rec / "camera.yaml", "--ook-rate", "20000", "--max-frames", "10")
    assert p.returncode == 0, _err(p)
    assert stat.S_IMODE(os.stat(rec / "camera.yaml").st_mode) == 0o644
    assert _hidden(rec) == []


def test_calibrate_rows_stdout_full_disk_names_standard_output(rec):
    _refused(occloc("calibrate", "rows", rec, "--camera", rec / "camera.yaml", "--ook-rate", "20000",
                    "--max-frames", "10", "--out", rec.parent / "c.yaml", stdout=open("/dev/full", "wb")),
             "standard output")


def test_calibrate_intrinsics_out_onto_a_source_image_is_refused(tmp_path):
    import cv2
    views = tmp_path / "views"
    views.mkdir()
    for i in range(3):
        cv2.imwrite(str(views / f"v{i}.png"), np.full((48, 64), 40 * i, np.uint8))
    before = _sha(views / "v1.png")
    _refused(occloc("calibrate", "intrinsics", views, "--board", "chess:9x6", "--square-mm", "20",
                    "--out", views / "v1.png"), "input")
    assert _sha(views / "v1.png") == before


@pytest.mark.parametrize("args", [
    ("calibrate", "intrinsics", STATIC, "--board", "chess:9x6", "--square-mm", "1e300", "--out", "x.yaml"),
    ("calibrate", "intrinsics", STATIC, "--board", "chess:9x6", "--square-mm", "1e-300", "--out", "x.yaml"),
    ("calibrate", "intrinsics", STATIC, "--board", "chess:9x6", "--square-mm", "20", "--max-views", "0",
     "--out", "x.yaml"),
    ("calibrate", "intrinsics", STATIC, "--board", "chess:9x6", "--square-mm", "20", "--max-views", "1",
     "--out", "x.yaml"),
    ("calibrate", "rows", STATIC, "--camera", os.path.join(STATIC, "camera.yaml"), "--freq-hz", "1e-10"),
    ("calibrate", "rows", STATIC, "--camera", os.path.join(STATIC, "camera.yaml"), "--ook-rate", "1e-300"),
    ("run", STATIC, "--fps", "nan"),
    ("run", STATIC, "--max-frames", "-1"),
    ("eval", "x.jsonl", "--truth", "t.jsonl", "--gate-px", "inf"),
    ("eval", "x.jsonl", "--truth", "t.jsonl", "--fv-gate-deg", "1e300"),
    ("check", STATIC, "--max-frames", "0"),
    ("bench", "--frames", "0"),
    ("bench", "--repeat", "-3"),
])
def test_numeric_options_are_range_checked_at_parse_time(tmp_path, args):
    p = occloc(*args, cwd=str(tmp_path))
    err = _err(p)
    assert p.returncode == 2 and "Traceback" not in err and "error: argument" in err, err
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------ check, bench

def test_check_stdout_full_disk_names_standard_output():
    _refused(occloc("check", STATIC, "--max-frames", "5", stdout=open("/dev/full", "wb")), "standard output")


def test_bench_stdout_full_disk_names_standard_output():
    _refused(occloc("bench", STATIC, "--frames", "2", stdout=open("/dev/full", "wb")), "standard output")


@pytest.mark.parametrize("args", [("--help",), ("--version",), ("run", "--help"), ("calibrate", "rows", "--help"),
                                  ("-h", "eval")])
@pytest.mark.parametrize("unbuffered", ["1", ""])
def test_help_and_version_on_a_full_disk_are_an_error(args, unbuffered, monkeypatch):
    """argparse drops an OSError of its --help/--version text silently (exit 0, nothing
    printed): the standard output wrapper every command runs under turns it into one line."""
    monkeypatch.setenv("PYTHONUNBUFFERED", unbuffered)
    line = _refused(occloc(*args, stdout=open("/dev/full", "wb")), "cannot write standard output")
    assert "No space left" in line


def test_help_on_a_writable_stdout_still_exits_0():
    p = occloc("--version")
    assert p.returncode == 0 and p.stdout.decode().startswith("occloc "), _err(p)
    p = occloc("run", "--help")
    assert p.returncode == 0 and "--max-pixels" in p.stdout.decode() and not p.stderr, _err(p)


# ------------------------------------------------------------------ signals

def _wait_for_kernel_loaded(p: subprocess.Popen, timeout_s: float = 120.0) -> bool:
    """True once process `p` has mapped one of the receiver's compiled kernels (its own code is
    running past its imports); False if it ended first or `timeout_s` passed."""
    deadline = time.monotonic() + timeout_s
    while p.poll() is None and time.monotonic() < deadline:
        try:
            with open(f"/proc/{p.pid}/maps") as f:
                if any("receiver" in line and ".so" in line for line in f):
                    return True
        except OSError:
            return False
        time.sleep(0.01)
    return False


def test_sigint_while_loading_exits_130_quietly():
    """SIGINT at several moments of start-up and work: exit 130 (or killed by SIGINT before
    Python runs any of the project's code), never a traceback. The last moment is taken after
    the process has loaded the receiver, whatever the machine's load, so at least that one is
    always judged."""
    env = dict(os.environ, PYTHONPATH=ROOT)
    judged = 0
    for delay in (0.15, 0.3, 0.6, 1.0, 2.0, "loaded"):
        p = subprocess.Popen([sys.executable, "-m", "receiver.cli", "check", STATIC, "--max-frames", "40"],
                             cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        if delay == "loaded":
            assert _wait_for_kernel_loaded(p), "the receiver never loaded a compiled kernel"
        else:
            time.sleep(delay)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=120)
        text = err.decode()
        if text.startswith("Fatal Python error: init_import_site") and delay != "loaded":
            # the interpreter's own start-up (its site module), before any code of the project
            # runs: on a loaded machine it can still be there after the delay
            continue
        assert "Traceback" not in text, (delay, text)
        assert p.returncode in (130, -signal.SIGINT, 0, 1), (delay, p.returncode)
        judged += 1
    assert judged >= 1


def test_sigterm_in_eval_leaves_no_hidden_file(tmp_path):
    run = _run_file(tmp_path)
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.Popen([sys.executable, "-m", "receiver.cli", "eval", str(run), "--truth",
                          os.path.join(STATIC, "truth.jsonl"), "--plot", str(tmp_path / "p.png")],
                         cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    time.sleep(1.0)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert "Traceback" not in err.decode()
    assert _hidden(tmp_path) == []


def test_ctrl_c_wrapped_by_a_class_hook_while_loading_exits_130(monkeypatch, capsys):
    """Ctrl-C while a dataclass's field hook runs (a module being imported) arrives as a
    RuntimeError caused by the KeyboardInterrupt: the command still ends with exit 130 and one line."""
    import receiver.cli as cli

    def interrupted(argv):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance") from e

    monkeypatch.setattr(cli, "_main", interrupted)
    assert cli.main(["check", "x"]) == 130
    assert capsys.readouterr().err == "occloc: interrupted\n"


def test_other_errors_are_not_taken_for_ctrl_c(monkeypatch):
    import receiver.cli as cli

    def broken(argv):
        raise RuntimeError("not an interrupt")

    monkeypatch.setattr(cli, "_main", broken)
    with pytest.raises(RuntimeError):
        cli.main(["check", "x"])
