"""Damaged, cut and mixed inputs: frame numbers from the container's timestamps, the real
count of missing frames, images of another size said and skipped, and clean stops on signals."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

from receiver.io.sources import ImageSource, VideoFileSource

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")
WALK = os.path.join(ROOT, "recordings", "indoor-walk")


class _Capture:
    """A capture whose reads follow a script: ('ok', pos_ms) or ('fail',)."""

    def __init__(self, script, count):
        self.script, self.count, self.pos = list(script), count, 0.0

    def isOpened(self):
        return True

    def set(self, *a):
        return True

    def get(self, prop):
        return {cv2.CAP_PROP_FRAME_WIDTH: 8, cv2.CAP_PROP_FRAME_HEIGHT: 6, cv2.CAP_PROP_FPS: 30.0,
                cv2.CAP_PROP_FRAME_COUNT: self.count, cv2.CAP_PROP_POS_MSEC: self.pos}.get(prop, 0)

    def read(self):
        if not self.script:
            return False, None
        step = self.script.pop(0)
        if step[0] == "fail":
            return False, None
        self.pos = step[1]
        return True, np.zeros((6, 8), np.uint8)

    def release(self):
        pass


def _frames(script, count):
    src = VideoFileSource(os.path.join(STATIC, "video.avi"), capture_factory=lambda *a: _Capture(script, count))
    return src, [(f.index, round(f.t_s, 6)) for f in src]


def test_frame_index_follows_container_timestamps_not_decode_count():
    ms = [k * 1000 / 30 for k in range(8)]
    # a damaged chunk: two failed reads for ONE lost frame (before: every later frame +1),
    # then a frame the demuxer dropped without a failure (before: every later frame -1)
    script = [("ok", ms[0]), ("ok", ms[1]), ("fail",), ("fail",), ("ok", ms[3]), ("ok", ms[4]),
              ("ok", ms[6]), ("ok", ms[7])]
    src, got = _frames(script, 8)
    assert got == [(k, round(k / 30, 6)) for k in (0, 1, 3, 4, 6, 7)]
    assert src.skipped == 2 and src.truncated == 0  # before: a false "truncated" at the end


def _movi_chunks(data):
    p, out = data.find(b"movi") + 4, []
    while p + 8 <= len(data):
        size = struct.unpack("<I", data[p + 4:p + 8])[0]
        if data[p:p + 4] == b"idx1":
            break
        out.append(p)
        p += 8 + size + (size & 1)
    return out


def test_truncated_video_reports_the_frames_really_missing(tmp_path):
    data = open(os.path.join(STATIC, "video.avi"), "rb").read()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[:_movi_chunks(data)[2]])  # 2 of 30 frames left
    src = VideoFileSource(str(cut))
    n = len(list(src))
    assert n == 2
    assert src.truncated == 28  # before: 25 (the consecutive-failure limit)


def test_damaged_chunk_header_keeps_frame_numbers(tmp_path):
    data = bytearray(open(os.path.join(STATIC, "video.avi"), "rb").read())
    ch = _movi_chunks(bytes(data))
    data[ch[10] + 4:ch[10] + 8] = b"\xff\xff\x00\x00"
    p = tmp_path / "d.avi"
    p.write_bytes(bytes(data))
    good = {f.index: f.gray for f in VideoFileSource(os.path.join(STATIC, "video.avi"))}
    src = VideoFileSource(str(p))
    got = list(src)
    assert all(0 <= f.index < 30 for f in got) and len({f.index for f in got}) == len(got)
    # after the damaged stretch the frames are the undamaged file's frames with the same numbers
    late = [f for f in got if f.index >= 20]
    assert late and all(np.array_equal(f.gray, good[f.index]) for f in late)
    assert src.truncated == 0


def test_image_of_another_size_in_a_folder_is_skipped_and_said(tmp_path, capsys):
    big = np.full((72, 128), 40, np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), big)
    cv2.imwrite(str(tmp_path / "b.png"), cv2.resize(big, (64, 36)))
    cv2.imwrite(str(tmp_path / "c.png"), big)
    src = ImageSource(str(tmp_path))
    got = list(src)
    assert [f.index for f in got] == [0, 2] and src.skipped == 1  # before: b.png measured with a's camera
    assert "b.png: 64x36" in capsys.readouterr().err


def _unread(pipe) -> int:
    """Bytes waiting in a pipe (FIONREAD on its read end)."""
    import fcntl
    import struct
    import termios
    return struct.unpack("i", fcntl.ioctl(pipe.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_stop_signals_flush_whole_lines_and_print_the_summary(tmp_path, sig):
    # before: SIGTERM/SIGHUP killed the process (lines lost, no summary); SIGINT: no summary
    out = tmp_path / "o.jsonl"
    writer = subprocess.Popen([sys.executable, "-c",
                               "import sys,time; sys.stdout.buffer.write(bytes(64*36*5)); sys.stdout.flush(); "
                               "time.sleep(600)"], stdout=subprocess.PIPE)   # killed below
    p = subprocess.Popen([sys.executable, "-m", "receiver.cli", "run", "-", "--size", "64x36", "--fps", "30",
                          "--camera", os.path.join(STATIC, "camera.yaml"), "--map", os.path.join(STATIC, "map.json"),
                          "--out", str(out)], cwd=ROOT, stdin=writer.stdout, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 40
        # wait until the run has opened its output (a temp file beside it) and read the 5 frames
        # (nothing left unread in the pipe), not for a fixed time: the machine may be slow
        while time.monotonic() < deadline and not (
                any(q.name.startswith(".o.jsonl") for q in tmp_path.iterdir()) and _unread(writer.stdout) == 0):
            time.sleep(0.1)
        time.sleep(1.5)                  # the last frame read is processed meanwhile
        p.send_signal(sig)
        _, err = p.communicate(timeout=30)
    finally:
        writer.kill()
        writer.wait()
        if p.poll() is None:
            p.kill()
    err = err.decode()
    assert p.returncode == 128 + sig, err
    assert "5 frames" in err and f"stopped by {sig.name}" in err and "Traceback" not in err
    text = out.read_text()
    assert text.endswith("\n") and len(text.splitlines()) == 5


def test_decoder_garbage_after_damaged_data_is_skipped_and_counted(tmp_path, capsys):
    # before: the garbage frames (mean 75 and 49 DN in a 3 DN scene) were processed as valid,
    # 'skipped corrupt frames: 0'
    import random
    data = bytearray(open(os.path.join(STATIC, "video.avi"), "rb").read())
    p = _movi_chunks(bytes(data))[10]
    data[p + 8:p + 8 + 4096] = random.Random(10).randbytes(4096)
    path = tmp_path / "g.avi"
    path.write_bytes(bytes(data))
    src = VideoFileSource(str(path))
    got = [f.index for f in src]
    assert 10 not in got and src.skipped >= 1
    assert set(range(13, 30)) <= set(got)  # the frames after the damaged stretch are kept
    assert "implausible" in capsys.readouterr().err
    clean = VideoFileSource(os.path.join(STATIC, "video.avi"))
    assert len(list(clean)) == 30 and clean.skipped == 0
