"""Frame sources: video files, images, raw pipes, V4L2 (through a fake capture), --realtime."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest

from receiver.cli.benchscene import bench_camera
from receiver.core.errors import InputError
from receiver.core.records import Frame
from receiver.io.sources import FrameSource, LatestFrameSource, V4l2Source, open_source, parse_size, to_gray


def _gradient(k: int, w: int = 64, h: int = 48) -> np.ndarray:
    """A frame whose content identifies its index k."""
    img = np.add.outer(np.arange(h), np.arange(w)) % 128
    return (img + 5 * k).astype(np.uint8)


def _write_video(path, frames, fourcc, fps=25.0, color=False):
    h, w = frames[0].shape
    vw = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*fourcc), fps, (w, h),
                         isColor=color)
    assert vw.isOpened()
    for f in frames:
        vw.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if color else f)
    vw.release()


def test_gray_ffv1_video_is_lossless_with_index_timestamps(tmp_path):
    frames = [_gradient(k) for k in range(5)]
    _write_video(tmp_path / "v.mkv", frames, "FFV1")
    src = open_source(str(tmp_path / "v.mkv"))
    got = list(src)
    assert [f.index for f in got] == [0, 1, 2, 3, 4]
    assert [f.t_s for f in got] == pytest.approx([k / 25.0 for k in range(5)])
    for f, want in zip(got, frames):
        assert f.gray.shape == (48, 64) and f.gray.dtype == np.uint8
        assert np.array_equal(f.gray, want)
    assert src.size == (64, 48) and src.skipped == 0


@pytest.mark.parametrize("fourcc,ext,color", [("MJPG", "avi", True), ("FFV1", "mkv", True)])
def test_colour_videos_become_gray_once(tmp_path, fourcc, ext, color):
    frames = [_gradient(k) for k in range(3)]
    _write_video(tmp_path / f"v.{ext}", frames, fourcc, color=color)
    got = list(open_source(str(tmp_path / f"v.{ext}")))
    assert len(got) == 3
    for f, want in zip(got, frames):
        assert f.gray.ndim == 2
        # MJPEG is lossy: the luma stays within a few levels of the gray frame.
        assert np.abs(f.gray.astype(int) - want).mean() < 3.0


def test_recording_folder_picks_up_camera_map_truth(tmp_path):
    _write_video(tmp_path / "video.mkv", [_gradient(0)], "FFV1")
    for name in ("camera.yaml", "map.json", "truth.jsonl"):
        (tmp_path / name).write_text("x")
    src = open_source(str(tmp_path))
    assert src.kind == "recording"
    assert src.camera_path.endswith("camera.yaml") and src.map_path.endswith("map.json")
    assert src.truth_path.endswith("truth.jsonl")


def test_image_folder_skips_and_counts_unreadable_images(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), _gradient(0))
    (tmp_path / "b.png").write_bytes(b"not a png")
    cv2.imwrite(str(tmp_path / "c.jpg"), _gradient(2))
    cam = bench_camera()
    import dataclasses
    src = open_source(str(tmp_path), camera=dataclasses.replace(cam, fps=10.0))
    got = list(src)
    assert [f.index for f in got] == [0, 2]
    assert [f.t_s for f in got] == pytest.approx([0.0, 0.2])
    assert src.skipped == 1 and src.is_still
    assert np.array_equal(got[0].gray, _gradient(0))


@pytest.mark.parametrize("content", [b"", b"garbage" * 100])
def test_unreadable_files_are_one_line_errors(tmp_path, content):
    for name in ("x.mkv", "x.jpg"):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(InputError) as e:
            list(open_source(str(tmp_path / name)))
        assert "\n" not in str(e.value)
    with pytest.raises(InputError):
        open_source(str(tmp_path / "missing.mkv"))


def test_truncated_video_keeps_the_good_frames_and_reports(tmp_path):
    frames = [_gradient(k) for k in range(30)]
    _write_video(tmp_path / "v.avi", frames, "MJPG")
    data = (tmp_path / "v.avi").read_bytes()
    (tmp_path / "t.avi").write_bytes(data[: len(data) // 2])
    try:
        src = open_source(str(tmp_path / "t.avi"))
    except InputError:  # a container whose index is gone may be refused up front: also fine
        return
    got = list(src)
    assert 0 < len(got) < 30
    assert src.truncated == 30 - len(got) - src.skipped and src.truncated > 0
    for f in got:  # every delivered frame is a real one
        assert np.abs(f.gray.astype(int) - frames[f.index]).mean() < 3.0


def test_raw_gray_and_bgr24_from_a_pipe():
    a, b = _gradient(0), _gradient(1)
    src = open_source("-", size="64x48", pix_fmt="gray", stdin=io.BytesIO(a.tobytes() + b.tobytes()))
    got = list(src)
    assert len(got) == 2 and np.array_equal(got[1].gray, b)
    bgr = cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    got = list(open_source("-", size=(64, 48), pix_fmt="bgr24", stdin=io.BytesIO(bgr.tobytes())))
    assert np.array_equal(got[0].gray, a)


def test_pipe_truncated_last_frame_is_counted_and_reported(capsys):
    a = _gradient(0)
    src = open_source("-", size="64x48", stdin=io.BytesIO(a.tobytes() * 2 + a.tobytes()[:100]))
    assert len(list(src)) == 2
    assert src.truncated == 1 and src.truncated_bytes == 100
    assert "100 of 3072 bytes" in capsys.readouterr().err


def test_pipe_wrong_size_or_missing_size_is_a_clear_error():
    with pytest.raises(InputError, match="wrong --size"):
        list(open_source("-", size="640x480", stdin=io.BytesIO(b"\0" * 1000)))
    with pytest.raises(InputError, match="--size"):
        open_source("-", stdin=io.BytesIO(b""))
    with pytest.raises(InputError):
        parse_size("640by480")
    with pytest.raises(InputError):
        open_source("-", size="4x4", pix_fmt="rgb48", stdin=io.BytesIO(b""))


def test_to_gray_accepts_yuyv_and_rejects_garbage():
    y = _gradient(1, 8, 4)
    yuyv = np.empty((4, 16), np.uint8)
    yuyv[:, ::2], yuyv[:, 1::2] = y, 128
    assert np.array_equal(to_gray(yuyv, 8, 4), y)
    assert np.array_equal(to_gray(yuyv.reshape(1, -1), 8, 4), y)
    assert to_gray(np.zeros((3, 5), np.uint8), 8, 4) is None
    assert to_gray(None) is None


class FakeCapture:
    """cv2.VideoCapture stand-in for a V4L2 driver: records set() calls, refuses some,
    serves frames with given buffer timestamps (ms)."""

    def __init__(self, frames, stamps_ms, *, refuse=(), fourccs=("YUYV",), opened=True):
        self.props = {cv2.CAP_PROP_FRAME_WIDTH: 64.0, cv2.CAP_PROP_FRAME_HEIGHT: 48.0,
                      cv2.CAP_PROP_FPS: 0.0, cv2.CAP_PROP_FOURCC: float(cv2.VideoWriter_fourcc(*"MJPG"))}
        self.frames, self.stamps = list(frames), list(stamps_ms)
        self.refuse, self.fourccs, self.opened = set(refuse), fourccs, opened
        self.calls: list = []
        self.api = None

    def __call__(self, path, api):
        self.path, self.api = path, api
        return self

    def isOpened(self):
        return self.opened

    def set(self, prop, value):
        self.calls.append(prop)
        if prop in self.refuse:
            return False
        if prop == cv2.CAP_PROP_FOURCC:
            name = "".join(chr((int(value) >> (8 * i)) & 0xFF) for i in range(4))
            if name not in self.fourccs:
                return False
        self.props[prop] = float(value)
        return True

    def get(self, prop):
        return self.props.get(prop, 0.0)

    def read(self):
        if not self.frames:
            return False, None
        self.props[cv2.CAP_PROP_POS_MSEC] = self.stamps.pop(0)
        return True, self.frames.pop(0)

    def release(self):
        pass


def test_v4l2_settings_order_readback_and_drops():
    import dataclasses
    cam = dataclasses.replace(bench_camera((64, 48)), fps=100.0, exposure_us=250.0)
    y = [_gradient(k) for k in range(4)]
    yuyv = []
    for g in y:
        p = np.full((48, 128), 128, np.uint8)
        p[:, ::2] = g
        yuyv.append(p)
    # 10 ms apart, then a 30 ms gap: two frames lost.
    fake = FakeCapture(yuyv, [1000.0, 1010.0, 1040.0, 1050.0], refuse={cv2.CAP_PROP_EXPOSURE})
    warnings = []
    src = V4l2Source("/dev/video7", camera=cam, capture_factory=fake, warn=warnings.append)
    assert fake.api == cv2.CAP_V4L2 and src.fourcc == "YUYV"
    order = fake.calls
    # FOURCC before size, size before fps, fps before exposure; manual mode before exposure value.
    assert order.index(cv2.CAP_PROP_FOURCC) < order.index(cv2.CAP_PROP_FRAME_WIDTH) < order.index(cv2.CAP_PROP_FPS)
    assert order.index(cv2.CAP_PROP_FPS) < order.index(cv2.CAP_PROP_AUTO_EXPOSURE) < order.index(cv2.CAP_PROP_EXPOSURE)
    assert fake.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1.0
    assert len(warnings) == 1 and "exposure" in warnings[0] and "2.5" in warnings[0]
    got = list(src)
    assert [f.index for f in got] == [0, 1, 4, 5]
    assert [f.t_s for f in got] == pytest.approx([1.0, 1.01, 1.04, 1.05])
    assert src.dropped == 2
    assert np.array_equal(got[2].gray, y[2])


def test_v4l2_absent_device_is_an_input_error():
    with pytest.raises(InputError, match="no such camera device"):
        open_source("/dev/video99")
    with pytest.raises(InputError, match="cannot open"):
        V4l2Source("/dev/video3", capture_factory=FakeCapture([], [], opened=False))


class _ListSource(FrameSource):
    def __init__(self, n):
        super().__init__("list")
        self.n = n

    def __iter__(self):
        for k in range(self.n):
            yield Frame(k, k * 0.01, np.zeros((2, 2), np.uint8))


def test_realtime_keeps_newest_and_counts_every_dropped_frame():
    import time
    src = LatestFrameSource(_ListSource(50))
    got = []
    for f in src:
        got.append(f.index)
        time.sleep(0.002)  # a slow consumer: the reader overwrites frames meanwhile
    assert got == sorted(got) and got[-1] == 49
    assert len(got) + src.dropped == 50


def test_phone_formats_opencv_cannot_read_are_named_with_what_to_do(tmp_path, capsys):
    """An iPhone's HEIC (or a raw DNG) photo: an error naming the format and the conversion, not
    'not a readable video file'; a folder of them likewise; beside JPEGs a warning counts them."""
    heic = tmp_path / "IMG_0001.HEIC"
    heic.write_bytes(b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic")
    with pytest.raises(InputError, match=r"IMG_0001.HEIC: HEIC photos are not read .*convert them to JPEG"):
        open_source(str(heic))
    (tmp_path / "raw.dng").write_bytes(b"II*\x00")
    with pytest.raises(InputError, match=r"no images in folder \(2 DNG/HEIC photo\(s\) are not read"):
        open_source(str(tmp_path))
    cv2.imwrite(str(tmp_path / "a.png"), _gradient(0))
    src = open_source(str(tmp_path))
    assert len(src.files) == 1
    assert "2 DNG/HEIC photo(s) are not read" in capsys.readouterr().err
