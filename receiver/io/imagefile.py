"""One still image read safely: its size from the header before anything is decoded, a JPEG cut
short refused, and the decoder's own messages kept off the user's standard error.

* `header_size(data)`: (width, height) from the first bytes of a PNG, JPEG, BMP, TIFF or
  PGM/PPM file (None for another format or a header that makes no sense).
* `jpeg_complete(data)`: False when a JPEG has no end-of-image marker after its last scan
  (a file cut short: libjpeg would fill the missing rows with grey and only warn).
* `read_gray(path, max_pixels)`: (8-bit gray image, None) or (None, reason).
* `exif_exposure_us(path)`: the shutter time a photo's EXIF records, us (None without one).
* `to_camera_orientation(gray, width, height)`: a portrait photo turned back to a landscape
  camera's rows (and the other way round).
"""

from __future__ import annotations

import os
import struct
import tempfile

import cv2
import numpy as np

# Largest decoded image accepted by default, pixels: the largest phone sensors are 200 MP; a
# 32000x18000 PNG of 0.5 MB would otherwise take over a gigabyte to decode.
DEFAULT_MAX_PIXELS = 200_000_000

# Bytes read for the header: a JPEG's SOF can follow EXIF/ICC segments of some 100 kB.
_HEADER_BYTES = 1 << 20


def _jpeg_size(data: bytes):
    i, n = 2, len(data)
    while i + 9 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01,) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        seg = struct.unpack(">H", data[i + 2:i + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return w, h
        if marker == 0xDA:  # a scan before any frame header
            return None
        i += 2 + seg
    return None


def _tiff_size(data: bytes):
    end = "<" if data[:2] == b"II" else ">"
    try:
        (ifd,) = struct.unpack(end + "I", data[4:8])
        (count,) = struct.unpack(end + "H", data[ifd:ifd + 2])
        w = h = None
        for k in range(count):
            e = ifd + 2 + 12 * k
            tag, typ = struct.unpack(end + "HH", data[e:e + 4])
            if tag in (256, 257):
                value = (struct.unpack(end + "H", data[e + 8:e + 10])[0] if typ == 3
                         else struct.unpack(end + "I", data[e + 8:e + 12])[0])
                if tag == 256:
                    w = value
                else:
                    h = value
        return (w, h) if w and h else None
    except struct.error:
        return None


def _pnm_size(data: bytes):
    tokens, i, n = [], 2, min(len(data), 4096)
    while len(tokens) < 2 and i < n:
        c = data[i:i + 1]
        if c == b"#":
            while i < n and data[i:i + 1] not in (b"\n", b"\r"):
                i += 1
        elif c.isdigit():
            j = i
            while j < n and data[j:j + 1].isdigit():
                j += 1
            tokens.append(int(data[i:j]))
            i = j
            continue
        i += 1
    return tuple(tokens) if len(tokens) == 2 else None


def header_size(data: bytes):
    """(width, height) from an image file's first bytes, or None."""
    try:
        if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
            return struct.unpack(">II", data[16:24])
        if data[:2] == b"\xff\xd8":
            return _jpeg_size(data)
        if data[:2] == b"BM" and len(data) >= 26:
            w, h = struct.unpack("<ii", data[18:26])
            return abs(w), abs(h)
        if data[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff_size(data)
        if data[:2] in (b"P2", b"P3", b"P5", b"P6"):
            return _pnm_size(data)
    except struct.error:
        return None
    return None


def jpeg_complete(data: bytes) -> bool:
    """True unless `data` is a JPEG whose last scan (SOS) is not followed by an end-of-image
    marker. Inside entropy-coded data 0xFF is always stuffed, so an EOI after the last SOS is
    the real end; an embedded EXIF thumbnail's EOI comes before the main image's scan."""
    if data[:2] != b"\xff\xd8":
        return True
    sos = data.rfind(b"\xff\xda")
    return sos >= 0 and data.find(b"\xff\xd9", sos) >= 0


class _QuietStderr:
    """File descriptor 2 redirected to a temporary file while a decoder runs: libjpeg, libpng
    and libtiff print warnings there themselves. `text` holds what they said."""

    def __enter__(self):
        self.text = ""
        self._tmp = tempfile.TemporaryFile()
        try:
            self._saved = os.dup(2)
        except OSError:
            self._saved = None
            return self
        os.dup2(self._tmp.fileno(), 2)
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.dup2(self._saved, 2)
            os.close(self._saved)
        self._tmp.seek(0)
        self.text = self._tmp.read(4096).decode("utf-8", "replace").strip()
        self._tmp.close()
        return False


def read_gray(path: str, max_pixels: int = DEFAULT_MAX_PIXELS):
    """(gray uint8 image, None) or (None, why it was not read): the file's header is checked
    against `max_pixels` before any decoding, a JPEG cut short is refused, and what the decoder
    prints is returned as the reason instead of reaching the user's standard error."""
    try:
        with open(path, "rb") as f:
            head = f.read(_HEADER_BYTES)
            size = header_size(head)
            if size is not None and size[0] * size[1] > max_pixels:
                return None, (f"{size[0]}x{size[1]} is over the {max_pixels:,} pixel limit "
                              f"(--max-pixels)")
            data = head + f.read()
    except OSError as e:
        return None, e.strerror or str(e)
    if not data:
        return None, "empty file"
    if not jpeg_complete(data):
        return None, "JPEG cut short (no end-of-image marker)"
    with _QuietStderr() as quiet:
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        except cv2.error:
            img = None
    if img is None:
        return None, "not a readable image"
    if any(w in quiet.text for w in _DAMAGE_WORDS):
        return None, f"damaged ({quiet.text.splitlines()[0]})"
    return img, None


# What libjpeg says of a damaged file (it still returns an image, part of it made up). Other
# messages (libpng's note on an sRGB profile, say) leave the image whole and are dropped.
_DAMAGE_WORDS = ("Corrupt JPEG", "Premature end", "Bogus", "Invalid JPEG", "unknown JFIF")


# EXIF tags (the Exif sub-IFD's ExposureTime, s).
_EXIF_IFD, _EXPOSURE_TIME = 0x8769, 0x829A


def exif_exposure_us(path: str) -> float | None:
    """The exposure (shutter) time a photo records in its EXIF, us; None when it has none or
    the file is not a photo Pillow (matplotlib's image library) reads."""
    try:
        from PIL import Image
        with Image.open(path) as im:
            value = im.getexif().get_ifd(_EXIF_IFD).get(_EXPOSURE_TIME)
        us = float(value) * 1e6
    except Exception:   # no Pillow, no EXIF, a damaged header: the photo simply does not say
        return None
    return us if 0.0 < us < 1e8 else None


def to_camera_orientation(gray, width: int, height: int):
    """(`gray` in the orientation of a camera of `width` x `height`, turned?): a still whose long
    side is not the camera's is turned back, assuming portrait = sensor turned clockwise, so that
    image rows are sensor rows again."""
    h, w = gray.shape[:2]
    if w != h and width != height and (w > h) != (width > height):
        return cv2.rotate(gray, cv2.ROTATE_90_COUNTERCLOCKWISE), True
    return gray, False
