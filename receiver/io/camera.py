"""Camera file (`camera.yaml`, INTERFACES.md): `CameraModel`, reading with one-line errors, writing, and fitting
the camera to the frames' size (`fit_camera`).

Units: pixels for image quantities, metres for the world, microseconds for times.
World frame: x, y on the floor, z up (vehicle scenes: x along the road).
Everything that goes wrong while reading raises `InputError` with a one-line reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from receiver.core.errors import InputError


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and sensor timing of one camera.

    `K` is the 3x3 camera matrix (fx, fy, cx, cy in pixels), `dist` the 5 OpenCV distortion
    coefficients (k1 k2 p1 p2 k3). `pixel_size_um` is rho and `focal_length_mm` is f of
    thesis eq. 18; when either is missing, `focal_px` (= f/rho) falls back to fx.
    `row_readout_us` = 0 means a global shutter.
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    pixel_size_um: float | None = None
    focal_length_mm: float | None = None
    row_readout_us: float = 0.0
    exposure_us: float = 0.0
    fps: float = 0.0

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def focal_px(self) -> float:
        """f / rho in pixels (thesis eq. 18), from the physical values when both are known."""
        if self.focal_length_mm and self.pixel_size_um:
            return self.focal_length_mm * 1000.0 / self.pixel_size_um
        return math.sqrt(self.fx * self.fy)

    @property
    def rolling_shutter(self) -> bool:
        return self.row_readout_us > 0

    def scaled(self, width: int, height: int) -> "CameraModel":
        """The same camera delivering frames of another size (pixel binning / resize)."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        pix = self.pixel_size_um / sx if self.pixel_size_um else None
        row = self.row_readout_us / sy
        return CameraModel(width, height, K, self.dist.copy(), pix, self.focal_length_mm, row,
                           self.exposure_us, self.fps)


def _fs_real(fs: cv2.FileStorage, key: str, path: str, required: bool = False) -> float | None:
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        if required:
            raise InputError(f"{path}: missing key '{key}'")
        return None
    if not (node.isReal() or node.isInt()):
        raise InputError(f"{path}: '{key}' must be a number")
    return float(node.real())


def _fs_matrix(fs: cv2.FileStorage, key: str, path: str, shape: tuple[int, ...], required: bool):
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        if required:
            raise InputError(f"{path}: missing key '{key}'")
        return None
    try:
        m = node.mat()
    except cv2.error:  # rows x cols disagreeing with the data length
        m = None
    if m is None or m.size != int(np.prod(shape)):
        raise InputError(f"{path}: '{key}' must be a {'x'.join(map(str, shape))} !!opencv-matrix")
    return np.asarray(m, dtype=np.float64).reshape(shape)


# Physical ranges of every number of a camera file: the one place they are checked
# (`check_camera`). (low, high) inclusive; `ZERO_OK` keys may also be exactly 0
# (row_readout_us 0 = global shutter, fps 0 = unknown).
CAMERA_RANGES = {
    "image_width": (1, 100_000),
    "image_height": (1, 100_000),
    "pixel_size_um": (0.1, 100.0),
    "focal_length_mm": (0.1, 1000.0),
    "row_readout_us": (0.01, 10_000.0),
    "exposure_us": (0.0, 1e6),
    "fps": (0.1, 10_000.0),
    "focal_px": (1.0, 1e6),          # fx, fy of camera_matrix
    "principal_px": (-1e6, 1e6),     # cx, cy of camera_matrix
    "distortion": (-1000.0, 1000.0),  # each of k1 k2 p1 p2 k3
}
ZERO_OK = ("row_readout_us", "fps")


def _check_range(path: str, key: str, v) -> None:
    if v is None:
        return
    lo, hi = CAMERA_RANGES[key]
    v = float(v)
    if key in ZERO_OK and v == 0:
        return
    if not (math.isfinite(v) and lo <= v <= hi):
        extra = " (or 0)" if key in ZERO_OK else ""
        raise InputError(f"{path}: {key} must be within {lo:g}..{hi:g}{extra}, got {v:g}")


def check_camera(cam: CameraModel, path: str = "camera") -> CameraModel:
    """Every number of the camera within its physical range (CAMERA_RANGES); InputError otherwise."""
    _check_range(path, "image_width", cam.width)
    _check_range(path, "image_height", cam.height)
    for key in ("pixel_size_um", "focal_length_mm", "row_readout_us", "exposure_us", "fps"):
        _check_range(path, key, getattr(cam, key))
    K = np.asarray(cam.K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise InputError(f"{path}: camera_matrix must be a finite 3x3 matrix")
    _check_range(path, "focal_px", K[0, 0])
    _check_range(path, "focal_px", K[1, 1])
    _check_range(path, "principal_px", K[0, 2])
    _check_range(path, "principal_px", K[1, 2])
    d = np.asarray(cam.dist, dtype=np.float64).ravel()
    if d.size != 5:
        raise InputError(f"{path}: distortion_coefficients must hold 5 numbers")
    for v in d:
        _check_range(path, "distortion", v)
    return cam


def load_camera(path: str) -> CameraModel:
    """Read a camera file (OpenCV FileStorage YAML)."""
    from receiver.io.files import MAX_CAMERA_BYTES, check_nesting, check_regular, cv_path, read_bytes

    check_regular(path, "camera file")   # missing, or a folder, FIFO or device: said as such
    # cv2.FileStorage recurses per nesting level: 50,000 '[' are a SIGSEGV, not an error.
    text = read_bytes(path, "camera file", MAX_CAMERA_BYTES).decode("utf-8", "replace")
    if "\0" in text or "\ufffd" in text:
        raise InputError(f"{path}: not a readable OpenCV YAML camera file (binary data)")
    check_nesting(text, path, yaml=True)
    try:
        fs = cv2.FileStorage(cv_path(path, "camera file"), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:
        # OpenCV's parser raises cv2.error, or SystemError from the binding on binary garbage.
        raise InputError(f"{path}: not a readable OpenCV YAML camera file ({_cv_reason(e)})") from None
    if not fs.isOpened():
        raise InputError(f"{path}: not a readable OpenCV YAML camera file")
    try:
        w = _fs_real(fs, "image_width", path, required=True)
        h = _fs_real(fs, "image_height", path, required=True)
        K = _fs_matrix(fs, "camera_matrix", path, (3, 3), required=False)
        dist = _fs_matrix(fs, "distortion_coefficients", path, (5,), required=False)
        pix = _fs_real(fs, "pixel_size_um", path)
        flen = _fs_real(fs, "focal_length_mm", path)
        row = _fs_real(fs, "row_readout_us", path) or 0.0
        exp = _fs_real(fs, "exposure_us", path) or 0.0
        fps = _fs_real(fs, "fps", path) or 0.0
    except (cv2.error, SystemError) as e:  # e.g. a top level that is not a map: getNode asserts
        raise InputError(f"{path}: not a readable OpenCV YAML camera file ({_cv_reason(e)})") from None
    finally:
        fs.release()
    for key, v in (("image_width", w), ("image_height", h)):
        _check_range(path, key, v)
    if w <= 0 or h <= 0 or w != int(w) or h != int(h):
        raise InputError(f"{path}: image_width and image_height must be positive integers")
    if K is None:
        if not (pix and flen):
            raise InputError(f"{path}: needs camera_matrix, or focal_length_mm and pixel_size_um")
        f = flen * 1000.0 / pix
        K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]], dtype=np.float64)
    for key, v in (("pixel_size_um", pix), ("focal_length_mm", flen)):
        _check_range(path, key, v)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.all(np.isfinite(K))):
        raise InputError(f"{path}: camera_matrix must have positive fx, fy")
    if dist is None:
        dist = np.zeros(5)
    for name, v in (("pixel_size_um", pix), ("focal_length_mm", flen)):
        if v is not None and v <= 0:
            raise InputError(f"{path}: {name} must be positive")
    if row < 0 or exp < 0 or fps < 0:
        raise InputError(f"{path}: row_readout_us, exposure_us and fps must not be negative")
    if not all(math.isfinite(v) for v in (row, exp, fps)):
        raise InputError(f"{path}: row_readout_us, exposure_us and fps must be finite numbers")
    return check_camera(CameraModel(int(w), int(h), K, dist, pix, flen, row, exp, fps), path)


def save_camera(path: str, cam: CameraModel) -> None:
    """Write a camera file that `load_camera` (and any OpenCV tool) reads back."""
    with open(path, "w", encoding="utf-8") as f:
        f.write(camera_yaml(cam))


def camera_yaml(cam: CameraModel) -> str:
    """The text of the camera file of `cam` (OpenCV FileStorage YAML)."""
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", int(cam.width))
    fs.write("image_height", int(cam.height))
    fs.write("camera_matrix", np.asarray(cam.K, dtype=np.float64))
    fs.write("distortion_coefficients", np.asarray(cam.dist, dtype=np.float64).reshape(1, 5))
    for key in ("pixel_size_um", "focal_length_mm"):
        if getattr(cam, key) is not None:
            fs.write(key, float(getattr(cam, key)))
    fs.write("row_readout_us", float(cam.row_readout_us))
    fs.write("exposure_us", float(cam.exposure_us))
    fs.write("fps", float(cam.fps))
    return fs.releaseAndGetString()


def _cv_reason(e: Exception) -> str:
    cause = e.__cause__ or e.__context__
    text = str(cause if isinstance(e, SystemError) and cause else e).strip().splitlines()
    return text[-1].strip() if text else "OpenCV error"


# Relative aspect-ratio tolerance for scaling the camera file to the frame size.
ASPECT_TOL = 0.01


def fit_camera(cam, size: tuple[int, int]):
    """(camera for frames of `size`, rotate) where rotate means: turn frames 90 deg CCW first."""
    from receiver.core.errors import InputError
    w, h = size
    if (w, h) == (cam.width, cam.height):
        return cam, False
    if (w, h) == (cam.height, cam.width):
        return cam, True
    if abs((w / h) / (cam.width / cam.height) - 1.0) <= ASPECT_TOL:
        return cam.scaled(w, h), False
    raise InputError(f"frames are {w}x{h} but the camera file is {cam.width}x{cam.height} "
                     f"(different aspect ratio)")
