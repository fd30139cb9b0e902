"""--realtime: the reader thread is stopped and joined before the capture is released; a pipe
is read with os.read so that a reader blocked at shutdown cannot abort the interpreter.
Before the fix: video runs hung in VideoCapture.release or aborted (SIGABRT, rc 134); a stdin
run whose writer kept the pipe open aborted with `_enter_buffered_busy` every time."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REC = os.path.join(ROOT, "recordings", "indoor-walk")


def _run(args, **kw):
    return subprocess.run([sys.executable, "-m", "receiver.cli", "run", *args], cwd=ROOT,
                          capture_output=True, timeout=60, **kw)


class _SlowCapture:
    """A VideoCapture stand-in that records a release() while another thread is in read()."""

    def __init__(self, *a):
        self.in_read = False
        self.violations = 0
        self.n = 0

    def isOpened(self):
        return True

    def set(self, *a):
        return True

    def get(self, prop):
        import cv2
        return {cv2.CAP_PROP_FRAME_WIDTH: 8, cv2.CAP_PROP_FRAME_HEIGHT: 6, cv2.CAP_PROP_FPS: 30,
                cv2.CAP_PROP_FRAME_COUNT: 1000, cv2.CAP_PROP_POS_MSEC: self.n * 1000 / 30}.get(prop, 0)

    def read(self):
        import time
        import numpy as np
        self.in_read = True
        time.sleep(0.02)
        self.n += 1
        self.in_read = False
        return True, np.zeros((6, 8), np.uint8)

    def release(self):
        if self.in_read:
            self.violations += 1


def test_realtime_close_never_releases_during_read():
    from receiver.io.sources import LatestFrameSource, VideoFileSource
    caps = []

    def factory(*a):
        caps.append(_SlowCapture())
        return caps[-1]
    for _ in range(10):
        src = LatestFrameSource(VideoFileSource(os.path.join(REC, "video.avi"), capture_factory=factory))
        it = iter(src)
        next(it)
        src.close()
    assert sum(c.violations for c in caps) == 0
    assert not src._thread.is_alive()


def test_realtime_video_stops_cleanly():
    for _ in range(2):
        p = _run([REC, "--realtime", "--max-frames", "3"])
        assert p.returncode == 0, p.stderr.decode()[-500:]
        assert b"3 frames" in p.stderr


@pytest.mark.parametrize("attempt", [1, 2])
def test_realtime_stdin_with_open_writer_exits_cleanly(attempt):
    cam, map_ = os.path.join(REC, "camera.yaml"), os.path.join(REC, "map.json")
    frame = bytes(1280 * 720)
    # the writer keeps the pipe open after 10 frames: the reader thread stays blocked in read
    writer = subprocess.Popen([sys.executable, "-c",
                               "import sys,time; sys.stdout.buffer.write(bytes(1280*720*10)); "
                               "sys.stdout.flush(); time.sleep(20)"], stdout=subprocess.PIPE)
    try:
        p = _run(["-", "--camera", cam, "--map", map_, "--size", "1280x720", "--realtime",
                  "--max-frames", "3"], stdin=writer.stdout)
    finally:
        writer.kill()
        writer.wait()
    assert p.returncode == 0, p.stderr.decode()[-500:]
    assert b"Fatal Python error" not in p.stderr
    assert len(frame) == 1280 * 720
