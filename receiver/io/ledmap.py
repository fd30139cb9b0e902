"""LED map (`map.json`, INTERFACES.md "LED map"): `Led`, `LedMap`, parsing with one-line
errors (`parse_map`, `load_map`) and writing (`save_map`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from receiver.core.errors import InputError

LED_MODES = ("ook", "s2psk", "tone")
SHAPES = ("circle", "square", "rect")

# Physical ranges of every number of a map file, the one place they are checked.
# Coordinates (x, y, z, ceiling_z, emitters): finite, |v| < MAX_COORD_M. Rates per mode from
# PROTOCOL.md: OOK chip rate 1-50 kHz (section 2); S2-PSK clock 1 Hz-10 kHz (section 3 names
# 125/200 Hz and fixes no range; the camera frame rate bounds what is usable); tone 10 Hz-100 kHz
# (section 4: typically 1-10 kHz).
MAX_COORD_M = 1e6
SIZE_RANGE_M = (1e-4, 100.0)
BASELINE_RANGE_M = (1e-4, 1000.0)
RATE_RANGE_HZ = {"ook": (1000.0, 50_000.0), "s2psk": (1.0, 10_000.0), "tone": (1.0, 100_000.0)}
FREQ_RANGE_HZ = (10.0, 100_000.0)
MAX_ID = 0xFFFF
MAX_SYMBOL_CLOCKS = 1 << 16


@dataclass(frozen=True)
class Led:
    """One light of the map. Position in metres (world frame); `size` per `shape`:
    circle -> [diameter], square/rect -> [width, length]. `rate_hz` is the OOK chip rate or
    the S2-PSK clock, `freq_hz` the tone frequency. S2-PSK pairs may give `emitters`
    ([[x, y, z], [x, y, z]]) or `baseline_m`. `normal`: the unit vector the emitting face
    points along (map frame), None = facing down [0, 0, -1] (INTERFACES.md)."""

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
    normal: tuple[float, float, float] | None = None

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
            if led.normal is not None:
                d["normal"] = list(led.normal)
            leds.append(d)
        out["leds"] = leds
        return out


def _num(d: dict, key: str, where: str, required: bool = False, positive: bool = False,
         lo: float | None = None, hi: float | None = None):
    v = d.get(key)
    if v is None:
        if required:
            raise InputError(f"{where}: missing '{key}'")
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{where}: '{key}' must be a finite number")
    try:
        v = float(v)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a finite number")
    if positive and v <= 0:
        raise InputError(f"{where}: '{key}' must be positive")
    if lo is not None and not lo <= v <= hi:
        raise InputError(f"{where}: '{key}' must be within {lo:g}..{hi:g}, got {v:g}")
    return v


def _coord(d: dict, key: str, where: str, required: bool = False):
    return _num(d, key, where, required=required, lo=-MAX_COORD_M, hi=MAX_COORD_M)


def _vector(v, n: int, lo: float, hi: float):
    """A tuple of n finite floats within lo..hi from a JSON list, or None."""
    if not isinstance(v, list) or len(v) != n:
        return None
    out = []
    for c in v:
        if isinstance(c, bool) or not isinstance(c, (int, float)):
            return None
        try:
            c = float(c)
        except OverflowError:
            return None
        if not (math.isfinite(c) and lo <= c <= hi):
            return None
        out.append(c)
    return tuple(out)


def _shape(d: dict, where: str):
    shape, size = d.get("shape"), d.get("size")
    if shape is None and size is None:
        return None, None
    if shape not in SHAPES:
        raise InputError(f"{where}: 'shape' must be one of {', '.join(SHAPES)}")
    if (not isinstance(size, list) or not 1 <= len(size) <= 2
            or _vector(size, len(size), *SIZE_RANGE_M) is None):
        raise InputError(f"{where}: 'size' must be a list of 1 or 2 numbers within "
                         f"{SIZE_RANGE_M[0]:g}..{SIZE_RANGE_M[1]:g} (metres)")
    if shape == "rect" and len(size) != 2:
        raise InputError(f"{where}: a rect needs 'size': [width, length]")
    return shape, tuple(float(s) for s in size)


def _led(d, i: int, path: str) -> Led:
    where = f"{path}: leds[{i}]"
    if not isinstance(d, dict):
        raise InputError(f"{where} must be an object")
    led_id = d.get("id")
    if isinstance(led_id, bool) or not isinstance(led_id, int) or not 0 <= led_id <= MAX_ID:
        raise InputError(f"{where}: 'id' must be an integer 0..{MAX_ID}")
    mode = d.get("mode", "ook")
    if mode not in LED_MODES:
        raise InputError(f"{where}: 'mode' must be one of {', '.join(LED_MODES)}")
    x, y, z = (_coord(d, k, where, required=True) for k in ("x", "y", "z"))
    shape, size = _shape(d, where)
    freq = _num(d, "freq_hz", where, positive=True, lo=FREQ_RANGE_HZ[0], hi=FREQ_RANGE_HZ[1])
    rate = _num(d, "rate_hz", where, positive=True, lo=RATE_RANGE_HZ[mode][0], hi=RATE_RANGE_HZ[mode][1])
    if mode == "tone" and freq is None:
        raise InputError(f"{where}: tone LEDs need 'freq_hz'")
    symclk = d.get("symbol_clocks")
    if symclk is not None and (isinstance(symclk, bool) or not isinstance(symclk, int)
                               or not 0 < symclk <= MAX_SYMBOL_CLOCKS):
        raise InputError(f"{where}: 'symbol_clocks' must be an integer 1..{MAX_SYMBOL_CLOCKS}")
    emitters = d.get("emitters")
    if emitters is not None:
        if isinstance(emitters, list) and len(emitters) == 2:
            emitters = tuple(_vector(e, 3, -MAX_COORD_M, MAX_COORD_M) for e in emitters)
        else:
            emitters = None
        if emitters is None or any(e is None for e in emitters):
            raise InputError(f"{where}: 'emitters' must be two [x, y, z] points (finite metres)")
    normal = d.get("normal")
    if normal is not None:
        normal = _vector(normal, 3, -MAX_COORD_M, MAX_COORD_M) or ()
        norm = math.sqrt(sum(c * c for c in normal)) if len(normal) == 3 and all(
            math.isfinite(c) for c in normal) else 0.0
        if not norm > 1e-9:
            raise InputError(f"{where}: 'normal' must be a non-zero [nx, ny, nz] vector")
        if abs(norm - 1.0) > 1e-9:  # a unit vector is kept as written (round trips exactly)
            normal = tuple(c / norm for c in normal)
    return Led(id=led_id, mode=mode, x=x, y=y, z=z, shape=shape, size=size,
               rate_hz=rate, freq_hz=freq,
               symbol_clocks=symclk, baseline_m=_num(d, "baseline_m", where, positive=True,
                                                     lo=BASELINE_RANGE_M[0], hi=BASELINE_RANGE_M[1]),
               emitters=emitters, normal=normal)


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
    ceiling = _coord(obj, "ceiling_z", path, required=addressing == "xy")
    shape, size = _shape(obj, path)
    taillight = obj.get("taillight")
    if taillight is not None:
        if not isinstance(taillight, dict):
            raise InputError(f"{path}: 'taillight' must be an object")
        _shape(taillight, f"{path}: taillight")
        _num(taillight, "baseline_m", f"{path}: taillight", positive=True,
             lo=BASELINE_RANGE_M[0], hi=BASELINE_RANGE_M[1])
    if not leds and addressing == "map":
        raise InputError(f"{path}: the map lists no LEDs")
    handedness = obj.get("handedness")
    if handedness not in (None, "right", "left"):
        raise InputError(f"{path}: 'handedness' must be 'right' or 'left'")
    return LedMap(units=units, addressing=addressing, leds=leds, ceiling_z=ceiling,
                  default_shape=shape, default_size=size,
                  default_rate_hz=_num(obj, "rate_hz", path, positive=True, lo=RATE_RANGE_HZ["ook"][0],
                                       hi=RATE_RANGE_HZ["ook"][1]), taillight=taillight,
                  handedness=handedness)


def load_map(path: str) -> LedMap:
    """Read and validate a map.json file."""
    from receiver.io.files import check_regular, load_json

    check_regular(path, "map file")   # missing, or a folder, FIFO or device: said as such
    # size and nesting guard, NaN/Infinity and huge integers refused (receiver.io.files)
    return parse_map(load_json(path, "map file"), path)


def save_map(path: str, led_map: LedMap) -> None:
    """Write the map (a temporary file renamed into place; NaN/Infinity never written)."""
    from receiver.io.files import AtomicWriter, dumps

    w = AtomicWriter(path)
    try:
        w.write(dumps(led_map.to_json(), indent=1) + "\n")
        w.commit()
    except BaseException:
        w.discard()
        raise
