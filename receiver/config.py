"""Camera file (`camera.yaml`) and LED map (`map.json`) per INTERFACES.md.

Units: pixels for image quantities, metres for the world, microseconds for times.
World frame: x, y on the floor, z up (vehicle scenes: x along the road).
Everything that goes wrong while reading raises `InputError` with a one-line reason.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import cv2
import numpy as np

from receiver.errors import InputError

LED_MODES = ("ook", "s2psk", "tone")
SHAPES = ("circle", "square", "rect")


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


def load_camera(path: str) -> CameraModel:
    """Read a camera file (OpenCV FileStorage YAML)."""
    if not os.path.isfile(path):
        raise InputError(f"camera file not found: {path}")
    try:
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
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
    finally:
        fs.release()
    if w <= 0 or h <= 0 or w != int(w) or h != int(h):
        raise InputError(f"{path}: image_width and image_height must be positive integers")
    if K is None:
        if not (pix and flen):
            raise InputError(f"{path}: needs camera_matrix, or focal_length_mm and pixel_size_um")
        f = flen * 1000.0 / pix
        K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]], dtype=np.float64)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.all(np.isfinite(K))):
        raise InputError(f"{path}: camera_matrix must have positive fx, fy")
    if dist is None:
        dist = np.zeros(5)
    for name, v in (("pixel_size_um", pix), ("focal_length_mm", flen)):
        if v is not None and v <= 0:
            raise InputError(f"{path}: {name} must be positive")
    if row < 0 or exp < 0 or fps < 0:
        raise InputError(f"{path}: row_readout_us, exposure_us and fps must not be negative")
    return CameraModel(int(w), int(h), K, dist, pix, flen, row, exp, fps)


def save_camera(path: str, cam: CameraModel) -> None:
    """Write a camera file that `load_camera` (and any OpenCV tool) reads back."""
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
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
    fs.release()


def _cv_reason(e: Exception) -> str:
    cause = e.__cause__ or e.__context__
    text = str(cause if isinstance(e, SystemError) and cause else e).strip().splitlines()
    return text[-1].strip() if text else "OpenCV error"


@dataclass(frozen=True)
class Led:
    """One light of the map. Position in metres (world frame); `size` per `shape`:
    circle -> [diameter], square/rect -> [width, length]. `rate_hz` is the OOK chip rate or
    the S2-PSK clock, `freq_hz` the tone frequency. S2-PSK pairs may give `emitters`
    ([[x, y, z], [x, y, z]]) or `baseline_m`."""

    id: int
    mode: str
    x: float
    y: float
    z: float
    shape: str | None = None
    size: tuple[float, ...] | None = None
    rate_hz: float | None = None
    freq_hz: float | None = None
    symbol_clocks: int | None = None
    baseline_m: float | None = None
    emitters: tuple[tuple[float, float, float], ...] | None = None

    @property
    def xyz(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z], dtype=np.float64)

    @property
    def area_m2(self) -> float | None:
        """Physical emitting area A_LED of thesis eq. 18 (one emitter), or None if unknown."""
        return shape_area_m2(self.shape, self.size)


def shape_area_m2(shape: str | None, size) -> float | None:
    if shape is None or not size:
        return None
    if shape == "circle":
        return math.pi * (size[0] / 2) ** 2
    if shape == "square":
        return size[0] * (size[1] if len(size) > 1 else size[0])
    return size[0] * size[1]


@dataclass(frozen=True)
class LedMap:
    """The LED map. `leds` is keyed by ID. With `addressing == 'xy'`, IDs not listed are
    resolved from their bits (PROTOCOL.md section 2: high byte x, low byte y, decimetres)."""

    units: str = "m"
    addressing: str = "map"
    leds: dict[int, Led] = field(default_factory=dict)
    ceiling_z: float | None = None
    default_shape: str | None = None
    default_size: tuple[float, ...] | None = None
    default_rate_hz: float | None = None
    taillight: dict | None = None
    # Handedness of the map's x, y, z (z up): "right" (seen from above, y is x turned 90 degrees
    # counter-clockwise), "left" (clockwise: a map surveyed in a mirrored frame), or None when
    # the map does not say (positioning then tells it from the images, receiver.locate).
    handedness: str | None = None

    def lookup(self, led_id: int) -> Led | None:
        """The LED with this ID, or None when the map does not know it."""
        led = self.leds.get(led_id)
        if led is not None or self.addressing != "xy" or not 0 <= led_id <= 0xFFFF:
            return led
        return Led(id=led_id, mode="ook", x=(led_id >> 8) / 10.0, y=(led_id & 0xFF) / 10.0,
                   z=float(self.ceiling_z), shape=self.default_shape, size=self.default_size,
                   rate_hz=self.default_rate_hz)

    def by_mode(self, mode: str) -> list[Led]:
        return [led for led in self.leds.values() if led.mode == mode]

    def to_json(self) -> dict:
        """The map as INTERFACES.md writes it."""
        out: dict = {"units": self.units, "addressing": self.addressing}
        if self.addressing == "xy":
            out.update(ceiling_z=self.ceiling_z, shape=self.default_shape,
                       size=list(self.default_size or []), rate_hz=self.default_rate_hz)
        if self.taillight is not None:
            out["taillight"] = self.taillight
        if self.handedness is not None:
            out["handedness"] = self.handedness
        leds = []
        for led in self.leds.values():
            d = {"id": led.id, "mode": led.mode, "x": led.x, "y": led.y, "z": led.z}
            for key in ("shape", "rate_hz", "freq_hz", "symbol_clocks", "baseline_m"):
                if getattr(led, key) is not None:
                    d[key] = getattr(led, key)
            if led.size is not None:
                d["size"] = list(led.size)
            if led.emitters is not None:
                d["emitters"] = [list(e) for e in led.emitters]
            leds.append(d)
        out["leds"] = leds
        return out


def _num(d: dict, key: str, where: str, required: bool = False, positive: bool = False):
    v = d.get(key)
    if v is None:
        if required:
            raise InputError(f"{where}: missing '{key}'")
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a finite number")
    if positive and v <= 0:
        raise InputError(f"{where}: '{key}' must be positive")
    return float(v)


def _shape(d: dict, where: str):
    shape, size = d.get("shape"), d.get("size")
    if shape is None and size is None:
        return None, None
    if shape not in SHAPES:
        raise InputError(f"{where}: 'shape' must be one of {', '.join(SHAPES)}")
    if (not isinstance(size, list) or not 1 <= len(size) <= 2
            or not all(isinstance(s, (int, float)) and not isinstance(s, bool) and s > 0 for s in size)):
        raise InputError(f"{where}: 'size' must be a list of 1 or 2 positive numbers (metres)")
    if shape == "rect" and len(size) != 2:
        raise InputError(f"{where}: a rect needs 'size': [width, length]")
    return shape, tuple(float(s) for s in size)


def _led(d, i: int, path: str) -> Led:
    where = f"{path}: leds[{i}]"
    if not isinstance(d, dict):
        raise InputError(f"{where} must be an object")
    led_id = d.get("id")
    if isinstance(led_id, bool) or not isinstance(led_id, int) or led_id < 0:
        raise InputError(f"{where}: 'id' must be a non-negative integer")
    mode = d.get("mode", "ook")
    if mode not in LED_MODES:
        raise InputError(f"{where}: 'mode' must be one of {', '.join(LED_MODES)}")
    x, y, z = (_num(d, k, where, required=True) for k in ("x", "y", "z"))
    shape, size = _shape(d, where)
    freq = _num(d, "freq_hz", where, positive=True)
    if mode == "tone" and freq is None:
        raise InputError(f"{where}: tone LEDs need 'freq_hz'")
    symclk = d.get("symbol_clocks")
    if symclk is not None and (isinstance(symclk, bool) or not isinstance(symclk, int) or symclk <= 0):
        raise InputError(f"{where}: 'symbol_clocks' must be a positive integer")
    emitters = d.get("emitters")
    if emitters is not None:
        try:
            emitters = tuple(tuple(float(c) for c in e) for e in emitters)
        except (TypeError, ValueError):
            emitters = None
        if emitters is None or len(emitters) != 2 or any(len(e) != 3 for e in emitters):
            raise InputError(f"{where}: 'emitters' must be two [x, y, z] points")
    return Led(id=led_id, mode=mode, x=x, y=y, z=z, shape=shape, size=size,
               rate_hz=_num(d, "rate_hz", where, positive=True), freq_hz=freq,
               symbol_clocks=symclk, baseline_m=_num(d, "baseline_m", where, positive=True),
               emitters=emitters)


def parse_map(obj, path: str = "map.json") -> LedMap:
    """Validate a decoded map.json object."""
    if not isinstance(obj, dict):
        raise InputError(f"{path}: the map must be a JSON object")
    units = obj.get("units", "m")
    if units != "m":
        raise InputError(f"{path}: only 'units': 'm' is supported")
    addressing = obj.get("addressing", "map")
    if addressing not in ("map", "xy"):
        raise InputError(f"{path}: 'addressing' must be 'map' or 'xy'")
    raw = obj.get("leds", [])
    if not isinstance(raw, list):
        raise InputError(f"{path}: 'leds' must be a list")
    leds: dict[int, Led] = {}
    for i, d in enumerate(raw):
        led = _led(d, i, path)
        if led.id in leds:
            raise InputError(f"{path}: LED id {led.id} listed twice")
        leds[led.id] = led
    ceiling = _num(obj, "ceiling_z", path, required=addressing == "xy")
    shape, size = _shape(obj, path)
    taillight = obj.get("taillight")
    if taillight is not None:
        if not isinstance(taillight, dict):
            raise InputError(f"{path}: 'taillight' must be an object")
        _shape(taillight, f"{path}: taillight")
        _num(taillight, "baseline_m", f"{path}: taillight", positive=True)
    if not leds and addressing == "map":
        raise InputError(f"{path}: the map lists no LEDs")
    handedness = obj.get("handedness")
    if handedness not in (None, "right", "left"):
        raise InputError(f"{path}: 'handedness' must be 'right' or 'left'")
    return LedMap(units=units, addressing=addressing, leds=leds, ceiling_z=ceiling,
                  default_shape=shape, default_size=size,
                  default_rate_hz=_num(obj, "rate_hz", path, positive=True), taillight=taillight,
                  handedness=handedness)


def load_map(path: str) -> LedMap:
    """Read and validate a map.json file."""
    if not os.path.isfile(path):
        raise InputError(f"map file not found: {path}")
    try:
        with open(path, encoding="utf-8") as f:
            obj = json.load(f)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: not valid JSON ({e.__class__.__name__}: {str(e).splitlines()[0]})") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    return parse_map(obj, path)


def save_map(path: str, led_map: LedMap) -> None:
    with open(path, "w", encoding="utf-8") as f:
        json.dump(led_map.to_json(), f, indent=1)
        f.write("\n")
