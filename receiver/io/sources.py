"""Frame sources behind one tiny interface: `open_source(spec)` -> iterable of `Frame`.

The SOURCE string picks the kind (like pyserial's `serial_for_url`):

* a recording folder (`video.*`, `camera.yaml`, `map.json`, optional `truth.jsonl`),
* a video file (anything OpenCV's FFmpeg backend reads: FFV1, MJPEG, H.264 ...),
* a still image or a folder of images (JPEG/PNG),
* `-`: raw frames on standard input (`--size WxH --pix-fmt gray|bgr24`, as
  `ffmpeg ... -f rawvideo -` writes them),
* a V4L2 device `/dev/videoN`.

Every frame is converted to gray once, as cheaply as the source allows: video files are read
with `CAP_PROP_CONVERT_RGB` off, which gives the Y plane directly for YUV codecs (MJPEG,
H.264) and gray for gray FFV1; a V4L2 camera is asked for GREY or YUYV (Y taken from the packed
bytes); images are decoded straight to gray. Images are read in stored (sensor) orientation,
ignoring EXIF rotation, because the rolling-shutter rows must stay image rows.

Timestamps (`Frame.t_s`) come from the source: video index / fps (CAP_PROP_POS_MSEC when the
container gives no rate), V4L2 buffer timestamps (CAP_PROP_POS_MSEC), images and pipes
index / fps or 0 when no rate is known. A frame that cannot be decoded mid-stream is skipped
and counted (`skipped`); a V4L2 timestamp gap counts as dropped frames (`dropped`) and leaves
a gap in `Frame.index`. Bad input raises `InputError` with one line.
"""

from __future__ import annotations

import glob
import os
import re
import sys
import threading
from pathlib import Path
import time
from typing import Callable, Iterator

# FFmpeg's own log lines ("moov atom not found" ...) would follow our one-line errors on
# stderr; AV_LOG_QUIET (-8) unless the user asked otherwise. Read when OpenCV loads FFmpeg.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from receiver.core.errors import InputError  # noqa: E402
from receiver.io.files import cv_path  # noqa: E402
from receiver.core.records import Frame

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
# Photo formats a phone or camera saves that OpenCV does not decode (HEIF: iPhones by default;
# raw sensor files): named in the error with what to do, never "not a readable video".
UNREAD_PHOTO_EXTS = (".heic", ".heif", ".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2")
CONVERT_HINT = ("convert them to JPEG or PNG (e.g. heif-convert IMG.HEIC IMG.jpg; or set the camera "
                "to save JPEG: on an iPhone, Settings > Camera > Formats > Most Compatible)")
V4L2_RE = re.compile(r"^/dev/video\d+$")
PIX_FMTS = {"gray": 1, "bgr24": 3}
# V4L2 pixel formats, most useful first: raw luma keeps the stripes, MJPEG blurs them.
V4L2_FOURCCS = ("GREY", "YUYV", "MJPG")
# A frame interval longer than this many nominal intervals means frames were dropped.
DROP_GAP_FACTOR = 1.5
# Consecutive undecodable frames after which a video is taken as ended, not corrupt.
MAX_CONSECUTIVE_BAD = 25


# Implausible frames (a decoder's garbage after damaged data, which decodes "fine"): a frame
# whose mean brightness jumps from the last accepted frame's by more than
# max(IMPLAUSIBLE_MEAN_FACTOR x the typical frame-to-frame step, IMPLAUSIBLE_MEAN_DN), or whose
# thumbnail differs from the previous (accepted) frame's by more than
# max(IMPLAUSIBLE_MAD_FACTOR x the typical difference, typical + IMPLAUSIBLE_MAD_DN), is skipped
# and counted. A change that lasts IMPLAUSIBLE_MAX_RUN frames is taken as real (the scene changed).
IMPLAUSIBLE_MEAN_DN = 8.0
IMPLAUSIBLE_MEAN_FACTOR = 6.0
IMPLAUSIBLE_MAD_DN = 20.0
IMPLAUSIBLE_MAD_FACTOR = 4.0
IMPLAUSIBLE_MAX_RUN = 30
THUMB_SIZE = (32, 18)


class PlausibilityCheck:
    """Judges each decoded frame of a video against its accepted neighbours (see constants)."""

    def __init__(self):
        from collections import deque
        self.ref = None            # (thumbnail, mean) of the last accepted frame
        self.prev_ok = False       # was the previous decoded frame accepted?
        self.steps = deque(maxlen=16)
        self.mads = deque(maxlen=16)
        self.run = 0

    def accept(self, gray: np.ndarray) -> bool:
        th = cv2.resize(gray, THUMB_SIZE, interpolation=cv2.INTER_AREA).astype(np.float32)
        mean = float(th.mean())
        if self.ref is None:
            self.ref, self.prev_ok = (th, mean), True
            return True
        step = abs(mean - self.ref[1])
        mad = float(np.abs(th - self.ref[0]).mean())
        typ_step = float(np.median(self.steps)) if self.steps else 0.0
        typ_mad = float(np.median(self.mads)) if self.mads else None
        bad = step > max(IMPLAUSIBLE_MEAN_FACTOR * typ_step, IMPLAUSIBLE_MEAN_DN)
        if not bad and self.prev_ok and typ_mad is not None and len(self.mads) >= 3:
            bad = mad > max(IMPLAUSIBLE_MAD_FACTOR * typ_mad, typ_mad + IMPLAUSIBLE_MAD_DN)
        if bad and self.run < IMPLAUSIBLE_MAX_RUN:
            self.run += 1
            self.prev_ok = False
            return False
        if self.prev_ok and not bad:
            self.steps.append(step)
            self.mads.append(mad)
        self.ref, self.prev_ok, self.run = (th, mean), True, 0
        return True


def _warn(msg: str) -> None:
    print(f"occloc: warning: {msg}", file=sys.stderr)


def to_gray(img: np.ndarray | None, width: int | None = None, height: int | None = None):
    """(H, W) uint8 gray from whatever a capture returned, or None if it is not a frame.

    Accepts gray (H, W), (H, W, 1), BGR (H, W, 3), BGRA (H, W, 4), and packed YUYV
    ((H, 2W) or (1, 2WH) bytes) when `width` and `height` are given."""
    if img is None or img.size == 0:
        return None
    if img.dtype != np.uint8:
        return None
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.shape[2] == 3:
            return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        elif img.shape[2] == 4:
            return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
        else:
            return None
    if width and height and img.ndim == 2:
        if img.shape == (height, width):
            return img
        if img.size == 2 * width * height:  # YUYV: Y0 U Y1 V ..., luma at even bytes
            return np.ascontiguousarray(img.reshape(height, 2 * width)[:, ::2])
        return None
    return img if img.ndim == 2 else None


class FrameSource:
    """Iterable of `Frame`. Attributes after (or during) iteration:

    kind: 'recording' | 'video' | 'images' | 'stdin' | 'v4l2'; path: what was opened;
    size: (width, height) px or None until known; fps: nominal frames/s (0 = unknown);
    camera_path, map_path, truth_path: files of a recording folder (None otherwise);
    skipped: undecodable frames skipped mid-stream; dropped: frames lost (V4L2 timestamp
    gaps, --realtime overwrites); truncated: frames missing at the end (a video file cut
    short, or 1 when a raw pipe ended inside a frame); truncated_bytes: that partial frame's bytes.
    """

    kind = "?"

    def __init__(self, path: str):
        self.path = path
        self.size: tuple[int, int] | None = None
        self.fps = 0.0
        self.camera_path: str | None = None
        self.map_path: str | None = None
        self.truth_path: str | None = None
        self.skipped = 0
        self.dropped = 0
        self.truncated = 0
        self.truncated_bytes = 0
        self.is_still = False

    def __iter__(self) -> Iterator[Frame]:
        raise NotImplementedError

    def close(self) -> None:
        pass


class VideoFileSource(FrameSource):
    kind = "video"

    def __init__(self, path: str, *, fps: float = 0.0, capture_factory=cv2.VideoCapture,
                 threads: int | None = None):
        super().__init__(path)
        if not os.path.isfile(path):
            raise InputError(f"no such file: {path}")
        self._factory = capture_factory
        # FFmpeg's decoding threads (CAP_PROP_N_THREADS, open-only); None: OpenCV's default
        # (one per core).
        self.threads = threads
        cap = self._open(convert=False)
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if w <= 0 or h <= 0:
            cap.release()
            raise InputError(f"{path}: no video stream")
        self.size = (w, h)
        self.fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) or fps
        self.frame_count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        self._cap = cap

    def _open(self, convert: bool):
        level = cv2.utils.logging.getLogLevel()
        # FFmpeg warns on every raw YUV frame ("treated as 8UC1"): that is the Y plane we want.
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        try:
            path = cv_path(self.path, "video")
            if self.threads is None:
                cap = self._factory(path, cv2.CAP_FFMPEG)
            else:
                cap = self._factory(path, cv2.CAP_FFMPEG, [cv2.CAP_PROP_N_THREADS, int(self.threads)])
            if not cap.isOpened():
                raise InputError(f"{self.path}: not a readable video file")
            if not convert:
                cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        finally:
            cv2.utils.logging.setLogLevel(level)
        return cap

    def _container_index(self, cap, prev: int) -> int:
        """The frame index of the frame just read, from the container's timestamp
        (CAP_PROP_POS_MSEC x fps), not from a count of decoded frames: a damaged chunk that the
        demuxer drops, or that fails to decode more than once, must not shift later frames.
        Falls back to prev + 1 when the container gives no usable timestamp."""
        ms = float(cap.get(cv2.CAP_PROP_POS_MSEC))
        if not (self.fps > 0 and np.isfinite(ms) and ms >= 0):
            return prev + 1
        k = int(round(ms * self.fps / 1000.0))
        limit = max(self.frame_count, 0) * 2 + MAX_CONSECUTIVE_BAD
        if k <= prev or (self.frame_count and k > limit):
            return prev + 1  # a timestamp that goes back or far past the end is not trusted
        return k

    def __iter__(self) -> Iterator[Frame]:
        w, h = self.size
        cap, bad_run, converting, yielded = self._cap, 0, False, 0
        check = PlausibilityCheck()
        implausible = 0
        prev = -1        # index of the last frame read (decodable or not)
        fails = 0        # read failures since the last good read
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    # Past the known end, or many failures in a row: the file has ended.
                    if (self.frame_count and prev + 1 + fails >= self.frame_count) or not self.frame_count \
                            or bad_run >= MAX_CONSECUTIVE_BAD:
                        break
                    bad_run += 1
                    fails += 1
                    continue
                gray = to_gray(img, w, h)
                if gray is None and prev < 0 and not converting:
                    # The raw format is not luma-first: fall back to OpenCV's BGR conversion.
                    cap.release()
                    cap = self._cap = self._open(convert=True)
                    converting = True
                    continue
                index = self._container_index(cap, prev)
                # frames between the previous one and this were lost (undecodable or dropped)
                self.skipped += index - prev - 1
                prev, fails = index, 0
                if gray is None:
                    self.skipped += 1
                    continue
                if not check.accept(gray):
                    self.skipped += 1
                    implausible += 1
                    continue
                bad_run = 0
                yielded += 1
                if self.fps > 0:
                    t = index / self.fps
                else:
                    t = float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
                yield Frame(index, t, gray)
        finally:
            cv2.utils.logging.setLogLevel(level)
        if implausible:
            _warn(f"{self.path}: skipped {implausible} implausible frames (brightness or content jumps "
                  f"from their neighbours: decoder garbage after damaged data?)")
        missing = self.frame_count - (prev + 1) if self.frame_count else 0
        if bad_run and missing > 0:
            # Failures up to the end are a file cut short (truncated), not corrupt frames.
            self.truncated = missing
            _warn(f"{self.path}: file ends {missing} frames before its stated length (truncated)")
        if yielded == 0:
            raise InputError(f"{self.path}: no decodable video frames")

    def close(self) -> None:
        self._cap.release()


class ImageSource(FrameSource):
    """A still image or a folder of images (sorted by name). Unreadable images in a folder are
    skipped and counted; a single unreadable image is an error."""

    kind = "images"

    def __init__(self, path: str, *, fps: float = 0.0, max_pixels: int | None = None):
        from receiver.io.files import check_regular
        from receiver.io.imagefile import DEFAULT_MAX_PIXELS

        super().__init__(path)
        self.max_pixels = max_pixels or DEFAULT_MAX_PIXELS
        if os.path.isdir(path):
            # only regular files: a FIFO or device named *.png would block imread forever
            every = sorted(p for p in glob.glob(os.path.join(path, "*")) if os.path.isfile(p))
            files = [p for p in every if p.lower().endswith(IMAGE_EXTS)]
            unread = [p for p in every if p.lower().endswith(UNREAD_PHOTO_EXTS)]
            if unread:
                kinds = "/".join(sorted({os.path.splitext(p)[1].upper().lstrip(".") for p in unread}))
                what = f"{len(unread)} {kinds} photo(s) are not read: {CONVERT_HINT}"
                if not files:
                    raise InputError(f"{path}: no images in folder ({what})")
                _warn(f"{path}: {what}")
            if not files:
                raise InputError(f"{path}: no images in folder")
        else:
            check_regular(path, "image")
            files = [path]
        self.files = files
        self.fps = fps
        self.is_still = True
        # The frame size is the first readable image's: unreadable ones before it are skipped
        # and counted, not a reason to refuse the folder.
        self._first, self._first_index = None, len(files)
        for i, p in enumerate(files):
            img = self._read(p)
            if img is not None:
                self._first, self._first_index = img, i
                self.size = (img.shape[1], img.shape[0])
                break
            if len(files) == 1:
                raise InputError(f"{path}: {self._why}")
        else:
            raise InputError(f"{path}: no readable image in {len(files)} files (first: {self._why})")

    def _read(self, path: str):
        """The gray image, or None (the reason in `_why`, said on stderr for a folder's file)."""
        from receiver.io.imagefile import read_gray
        img, self._why = read_gray(path, self.max_pixels)
        if img is None and len(self.files) > 1:
            _warn(f"{path}: {self._why}: skipped")
        return img

    def photos(self) -> Iterator[Frame]:
        """Every readable image as a Frame of its own size (`Frame.index` is its place in
        `files`): photos are independent observations, each fitted to the camera on its own
        (`occloc run`). Unreadable images are skipped, counted and named on stderr."""
        for i, path in enumerate(self.files):
            gray = self._image(i, path)
            if gray is None:
                self.skipped += 1   # said on stderr when it was read
                continue
            yield Frame(i, i / self.fps if self.fps > 0 else 0.0, gray)

    def _image(self, i: int, path: str):
        """Image i of the folder, or None: the first readable one was read (and kept) when the
        folder was opened, the unreadable ones before it were named on stderr then."""
        if i < self._first_index:
            return None
        if i == self._first_index and self._first is not None:
            gray, self._first = self._first, None
            return gray
        return self._read(path)

    def __iter__(self) -> Iterator[Frame]:
        for i, path in enumerate(self.files):
            gray = self._image(i, path)
            if gray is None:
                self.skipped += 1
                continue
            if self.size is None:
                self.size = (gray.shape[1], gray.shape[0])
            elif (gray.shape[1], gray.shape[0]) != self.size:
                # The camera was fitted to the first image's size: another size would be read
                # with the wrong intrinsics (wrong distances), so it is skipped, and said.
                self.skipped += 1
                _warn(f"{path}: {gray.shape[1]}x{gray.shape[0]}, not the {self.size[0]}x{self.size[1]} "
                      f"of the folder's first image: skipped (run images of another size separately)")
                continue
            yield Frame(i, i / self.fps if self.fps > 0 else 0.0, gray)


# A raw frame's row stride is judged from the autocorrelation of its bytes: an image is much more
# like itself one row down than at any other nearby shift. Another lag must beat the stated
# stride by this factor (and the frame must have some structure) before the size is doubted.
STRIDE_DOUBT_RATIO = 1.5
STRIDE_MIN_STD = 2.0  # gray levels: flatter frames cannot tell
# Rows of a large frame the stride is judged from (many more than the two-row lag range).
STRIDE_SAMPLE_ROWS = 64


def likely_row_stride(data: np.ndarray, stride: int) -> int | None:
    """The row stride (bytes) the frame's bytes suggest, when it clearly differs from `stride`
    (the one --size and --pix-fmt give); None when they agree or the frame cannot tell.
    Vertical edges line up one row down only at the true stride, so the normalised
    autocorrelation (FFT) of the byte stream's differences is compared over lags from half to
    twice the stated stride. Only a middle band of rows is looked at (`STRIDE_SAMPLE_ROWS`): the
    lags are at most twice a row, and the cost stays that of a small frame however large it is."""
    keep = max(STRIDE_SAMPLE_ROWS * stride, 1 << 16)
    if data.size > keep:
        start = (data.size - keep) // 2
        data = data[start:start + keep]
    x = np.diff(data.astype(np.float64))
    sd = float(x.std())
    if sd < STRIDE_MIN_STD or x.size < 4 * stride:
        return None
    x /= sd
    n = 1 << int(np.ceil(np.log2(x.size + 2 * stride + 1)))
    f = np.fft.rfft(x, n)
    ac = np.fft.irfft(f * np.conj(f), n)[:2 * stride + 1] / np.arange(x.size, x.size - 2 * stride - 1, -1)
    lo = max(stride // 2, 2)
    best = lo + int(np.argmax(ac[lo:]))
    if abs(best - stride) <= 1 or ac[best] <= STRIDE_DOUBT_RATIO * max(float(ac[stride]), 0.02):
        return None
    return best


class RawPipeSource(FrameSource):
    """Raw frames (gray or bgr24, `size` = (W, H)) from a binary stream (standard input)."""

    kind = "stdin"

    def __init__(self, stream, size: tuple[int, int] | None, pix_fmt: str | None, *, fps: float = 0.0,
                 max_pixels: int | None = None):
        from receiver.io.imagefile import DEFAULT_MAX_PIXELS

        super().__init__("-")
        if size is None:
            raise InputError("reading frames from stdin needs --size WxH (and --pix-fmt gray|bgr24)")
        if size[0] * size[1] > (max_pixels or DEFAULT_MAX_PIXELS):
            raise InputError(f"--size {size[0]}x{size[1]} is over the {max_pixels or DEFAULT_MAX_PIXELS:,} "
                             f"pixel limit (--max-pixels)")
        pix_fmt = pix_fmt or "gray"
        if pix_fmt not in PIX_FMTS:
            raise InputError(f"--pix-fmt must be one of {', '.join(PIX_FMTS)}, not {pix_fmt!r}")
        self.size = size
        self.pix_fmt = pix_fmt
        self.fps = fps
        self._stream = stream
        # A real file descriptor is read with os.read: no buffered-reader lock, so a reader
        # thread still blocked in it at interpreter shutdown cannot abort the process
        # ("Fatal Python error: _enter_buffered_busy").
        try:
            self._fd = stream.fileno()
        except (AttributeError, OSError, ValueError):
            self._fd = None
        self.frame_bytes = size[0] * size[1] * PIX_FMTS[pix_fmt]

    def _read(self, n: int) -> bytes:
        if self._fd is not None:
            try:
                return os.read(self._fd, min(n, 1 << 20))
            except OSError as e:
                raise InputError(f"stdin: {e.strerror or e}") from None
        return self._stream.read(n)

    def _read_exact(self, n: int):
        """Up to `n` bytes (fewer at the end of input), read into one buffer: a frame costs
        its own size once, as a frame decoded from a file does."""
        if self._fd is None:
            chunks, got = [], 0
            while got < n:
                b = self._read(n - got)
                if not b:
                    break
                chunks.append(b)
                got += len(b)
            return b"".join(chunks)
        buf = bytearray(n)
        view, got = memoryview(buf), 0
        raw = os.fdopen(self._fd, "rb", buffering=0, closefd=False)
        while got < n:
            try:
                k = raw.readinto(view[got:got + (1 << 20)])
            except OSError as e:
                raise InputError(f"stdin: {e.strerror or e}") from None
            if not k:
                break
            got += k
        view.release()
        if got < n:
            del buf[got:]
        return buf

    def __iter__(self) -> Iterator[Frame]:
        w, h = self.size
        index = 0
        while True:
            buf = self._read_exact(self.frame_bytes)
            if len(buf) < self.frame_bytes:
                if buf and index == 0:
                    raise InputError(
                        f"stdin: only {len(buf)} bytes, less than one {w}x{h} {self.pix_fmt} frame "
                        f"({self.frame_bytes} bytes): wrong --size or --pix-fmt?")
                if buf:
                    self.truncated = 1
                    self.truncated_bytes = len(buf)
                    _warn(f"stdin ended inside frame {index} ({len(buf)} of {self.frame_bytes} bytes): "
                          f"frame dropped (wrong --size or --pix-fmt?)")
                return
            arr = np.frombuffer(buf, np.uint8)
            if index == 0:
                stride = likely_row_stride(arr, w * PIX_FMTS[self.pix_fmt])
                if stride is not None:
                    _warn(f"stdin: the first frame's bytes repeat every {stride} bytes, not every "
                          f"{w * PIX_FMTS[self.pix_fmt]} (a {w}-px {self.pix_fmt} row): wrong --size or "
                          f"--pix-fmt? (a {self.frame_bytes // stride}-row frame of {stride} bytes per row "
                          f"would fit)")
            if self.pix_fmt == "gray":
                gray = arr.reshape(h, w)
            else:
                gray = cv2.cvtColor(arr.reshape(h, w, 3), cv2.COLOR_BGR2GRAY)
            yield Frame(index, index / self.fps if self.fps > 0 else 0.0, gray)
            index += 1


class V4l2Source(FrameSource):
    """A V4L2 camera. Settings order matters to drivers: FOURCC, then size, then fps, then
    exposure. Every set() is read back; a refused or altered setting is a warning on stderr.

    `camera`: CameraModel (size, fps, exposure_us) or None; `size` overrides its size.
    `capture_factory(path, api)` builds the capture (tests inject a fake)."""

    kind = "v4l2"

    def __init__(self, path: str, *, camera=None, size=None, capture_factory=cv2.VideoCapture,
                 warn: Callable[[str], None] = _warn):
        super().__init__(path)
        self._warn = warn
        if capture_factory is cv2.VideoCapture and not os.path.exists(path):
            raise InputError(f"no such camera device: {path}")
        cap = capture_factory(cv_path(path, "camera device"), cv2.CAP_V4L2)
        if cap is None or not cap.isOpened():
            raise InputError(f"{path}: cannot open camera device")
        self._cap = cap
        self.fourcc = self._set_fourcc()
        if self.fourcc in ("GREY", "YUYV"):
            # Raw luma: keep OpenCV from converting to BGR and back.
            self._set(cv2.CAP_PROP_CONVERT_RGB, 0, "CONVERT_RGB", quiet=True)
        if size is None and camera is not None:
            size = (camera.width, camera.height)
        if size is not None:
            self._set(cv2.CAP_PROP_FRAME_WIDTH, size[0], "width")
            self._set(cv2.CAP_PROP_FRAME_HEIGHT, size[1], "height")
        if camera is not None and camera.fps > 0:
            self._set(cv2.CAP_PROP_FPS, camera.fps, "fps")
        if camera is not None and camera.exposure_us > 0:
            # V4L2 manual exposure: AUTO_EXPOSURE 1 = manual; EXPOSURE in 100 us units.
            self._set(cv2.CAP_PROP_AUTO_EXPOSURE, 1, "auto exposure (1 = manual)")
            self._set(cv2.CAP_PROP_EXPOSURE, camera.exposure_us / 100.0, "exposure (100 us units)")
        self.size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        self.fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) or (camera.fps if camera else 0.0)

    def _set(self, prop, value, name: str, quiet: bool = False) -> bool:
        self._cap.set(prop, value)
        got = self._cap.get(prop)
        if abs(float(got) - float(value)) > 1e-6 * max(1.0, abs(float(value))):
            if not quiet:
                self._warn(f"{self.path}: camera refused {name} = {value:g} (reads back {got:g})")
            return False
        return True

    def _set_fourcc(self) -> str:
        for code in V4L2_FOURCCS:
            want = cv2.VideoWriter_fourcc(*code)
            self._cap.set(cv2.CAP_PROP_FOURCC, want)
            if int(self._cap.get(cv2.CAP_PROP_FOURCC)) == want:
                return code
        got = int(self._cap.get(cv2.CAP_PROP_FOURCC))
        name = "".join(chr((got >> (8 * i)) & 0xFF) for i in range(4))
        self._warn(f"{self.path}: camera refused GREY/YUYV/MJPG, using its format {name!r}")
        return name

    def __iter__(self) -> Iterator[Frame]:
        w, h = self.size
        index, last_t, bad_run = 0, None, 0
        period = 1.0 / self.fps if self.fps > 0 else 0.0
        while True:
            ok, img = self._cap.read()
            if not ok:
                bad_run += 1
                if bad_run >= MAX_CONSECUTIVE_BAD:
                    return
                continue
            t = float(self._cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
            gray = to_gray(img, w, h)
            if gray is None:
                self.skipped += 1
                bad_run += 1
                if bad_run >= MAX_CONSECUTIVE_BAD:
                    return
                continue
            bad_run = 0
            if last_t is not None and period > 0 and t - last_t > DROP_GAP_FACTOR * period:
                lost = int(round((t - last_t) / period)) - 1
                self.dropped += lost
                index += lost
            last_t = t
            yield Frame(index, t, gray)
            index += 1

    def close(self) -> None:
        self._cap.release()


class LatestFrameSource(FrameSource):
    """--realtime: a reader thread keeps only the newest frame of `inner`; frames overwritten
    before the consumer took them are counted in `dropped`. File sources are paced at their
    frame timestamps (a file stands in for a live camera); live sources are read as they come.
    `clock`/`sleep` are injectable."""

    def __init__(self, inner: FrameSource, *, pace: bool = False, clock=time.monotonic, sleep=time.sleep):
        super().__init__(inner.path)
        self.inner = inner
        self.kind = inner.kind
        self.size, self.fps = inner.size, inner.fps
        self.camera_path, self.map_path, self.truth_path = inner.camera_path, inner.map_path, inner.truth_path
        self.is_still = inner.is_still
        self._pace, self._clock, self._sleep = pace, clock, sleep
        self._cond = threading.Condition()
        self._latest: Frame | None = None
        self._done = False
        self._error: BaseException | None = None
        self._stop = False
        self._stop_event = threading.Event()
        self._thread: threading.Thread | None = None
        self._overwritten = 0

    def _wait(self, delay: float) -> None:
        if self._sleep is time.sleep:
            self._stop_event.wait(delay)  # a stop wakes the pacing wait at once
        else:
            self._sleep(delay)

    def _reader(self):
        try:
            t0 = None
            for frame in self.inner:
                if self._stop:
                    break
                if self._pace:
                    if t0 is None:
                        t0 = self._clock() - frame.t_s
                    delay = t0 + frame.t_s - self._clock()
                    if delay > 0:
                        self._wait(delay)
                if self._stop:
                    break
                with self._cond:
                    if self._latest is not None:
                        self._overwritten += 1
                    self._latest = frame
                    self._cond.notify()
        except BaseException as e:  # handed to the consumer thread
            self._error = e
        finally:
            with self._cond:
                self._done = True
                self._cond.notify()

    def __iter__(self) -> Iterator[Frame]:
        th = self._thread = threading.Thread(target=self._reader, daemon=True, name="occloc-reader")
        th.start()
        try:
            while True:
                with self._cond:
                    while self._latest is None and not self._done:
                        self._cond.wait()
                    frame, self._latest = self._latest, None
                    done = self._done
                if frame is not None:
                    self._sync()
                    yield frame
                elif done:
                    break
            if self._error is not None:
                raise self._error
        finally:
            self._stop_reader()
            self._sync()

    def _stop_reader(self) -> None:
        """Stop the reader thread and wait for it, so that the capture is never released while
        the thread is inside read(). A pipe reader blocked in os.read (no writer data) cannot be
        woken; it is a daemon without buffered-IO locks and is left behind after a short wait."""
        self._stop = True
        self._stop_event.set()
        th = self._thread
        if th is not None and th is not threading.current_thread():
            th.join(timeout=None if self.inner.kind in ("video", "recording", "images") else 1.0)

    def _sync(self):
        self.size = self.inner.size
        self.skipped = self.inner.skipped
        self.truncated, self.truncated_bytes = self.inner.truncated, self.inner.truncated_bytes
        self.dropped = self.inner.dropped + self._overwritten

    def close(self) -> None:
        self._stop_reader()
        th = self._thread
        if th is None or not th.is_alive():
            self.inner.close()


def find_recording_files(folder: str) -> dict[str, str | None]:
    """{'video', 'camera', 'map', 'truth'} paths in a recording folder (None when absent)."""
    videos = sorted(p for p in glob.glob(os.path.join(folder, "video.*")) if os.path.isfile(p))

    def opt(name):
        p = os.path.join(folder, name)
        return p if os.path.isfile(p) else None
    return {"video": videos[0] if videos else None, "camera": opt("camera.yaml"),
            "map": opt("map.json"), "truth": opt("truth.jsonl")}


def parse_size(text: str | None) -> tuple[int, int] | None:
    """'1280x720' -> (1280, 720); InputError on anything else."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if not m or int(m.group(1)) <= 0 or int(m.group(2)) <= 0:
        raise InputError(f"--size must look like 1280x720, not {text!r}")
    return int(m.group(1)), int(m.group(2))


def open_source(spec: str, *, size=None, pix_fmt: str | None = None, realtime: bool = False,
                camera=None, stdin=None, capture_factory=cv2.VideoCapture,
                threads: int | None = None, max_pixels: int | None = None) -> FrameSource:
    """Open the SOURCE argument of `occloc run` (see module docstring).

    size: (W, H) or 'WxH' for raw pipes / V4L2; pix_fmt: 'gray' | 'bgr24' for pipes;
    realtime: wrap in `LatestFrameSource`; camera: CameraModel for rates, size and exposure;
    stdin: binary stream for '-' (default sys.stdin.buffer); capture_factory: the
    cv2.VideoCapture constructor (tests pass a fake); threads: video decoding threads of a video
    file or recording (FFmpeg, CAP_PROP_N_THREADS; None: OpenCV's default, one per core);
    max_pixels: largest image or raw frame (W*H) accepted, checked before decoding (None:
    receiver.io.imagefile.DEFAULT_MAX_PIXELS)."""
    if isinstance(size, str):
        size = parse_size(size)
    fps = camera.fps if camera is not None else 0.0
    spec = str(spec)
    if spec == "-":
        if stdin is None and sys.stdin is None:
            raise InputError("standard input is closed: nothing to read frames from")
        src = RawPipeSource(stdin if stdin is not None else sys.stdin.buffer, size, pix_fmt, fps=fps,
                            max_pixels=max_pixels)
    elif V4L2_RE.match(spec):
        src = V4l2Source(spec, camera=camera, size=size, capture_factory=capture_factory)
    elif os.path.isdir(spec):
        files = find_recording_files(spec)
        if files["video"] is not None:
            src = VideoFileSource(files["video"], fps=fps, capture_factory=capture_factory, threads=threads)
            src.kind = "recording"
            src.camera_path, src.map_path, src.truth_path = files["camera"], files["map"], files["truth"]
        else:
            src = ImageSource(spec, fps=fps, max_pixels=max_pixels)
            src.camera_path, src.map_path = files["camera"], files["map"]
    elif not os.path.exists(spec):
        raise InputError(f"no such file or folder: {spec}")
    elif spec.lower().endswith(IMAGE_EXTS):
        src = ImageSource(spec, fps=fps, max_pixels=max_pixels)
    elif spec.lower().endswith(UNREAD_PHOTO_EXTS):
        ext = os.path.splitext(spec)[1].upper().lstrip(".")
        raise InputError(f"{spec}: {ext} photos are not read (OpenCV has no decoder for them): {CONVERT_HINT}")
    else:
        from receiver.io.files import check_regular
        check_regular(spec, "video")
        src = VideoFileSource(spec, fps=fps, capture_factory=capture_factory, threads=threads)
    if realtime:
        src = LatestFrameSource(src, pace=src.kind in ("video", "recording", "images"))
    return src


def default_source() -> str:
    import receiver
    path = Path(receiver.__file__).resolve().parent.parent / "recordings" / "indoor-walk"
    if not path.is_dir():
        from receiver.core.errors import InputError
        raise InputError(f"no SOURCE given and the default recording is missing: {path}")
    return str(path)
