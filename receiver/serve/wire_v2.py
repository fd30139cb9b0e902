"""Lighting-server datagram format v2: the device's decoded LED observations themselves, so the
server runs the very `receiver.locate.indoor.Positioner` a local run runs (ranging, centroid
solve, outline solve on the stripe edge points, Kalman filter) and its positions equal the
local run's.

Request (device -> server), one per frame:
    {"v": 2, "device": "phone-7", "seq": 12, "t": 0.400,
     "camera": {"width": 1280, "height": 720, "K": [fx, fy, cx, cy], "dist": [k1, k2, p1, p2, k3],
                "pixel_size_um": 1.12 | null, "focal_length_mm": 4.0 | null,
                "row_readout_us": 10.0, "exposure_us": 20.0},   (both optional, 0 = unknown)
     "obs": [{"id": 42, "cx": 612.3, "cy": 200.1, "area_px": 812.5, "border": false,
              "mode": "ook", "contour": ["f4:<b64>", "f4:<b64>"],
              "edge": ["f8:<b64>", "f4:<b64>", "f8:<b64>"]}]}
  * `device`, `seq`, `t`: as in v1 (`receiver.serve.wire`).
  * `camera`: the device's intrinsics (pixels) and, when known, its physical focal length and
    pixel pitch (thesis eq. 18); checked as a camera file is (`receiver.io.camera.check_camera`).
  * `obs` (at most `MAX_LEDS`): the frame's decoded, non-S2-PSK observations in the device's
    order (`receiver.core.records.LedObservation`): `id` 0..2^31-1, unique; centroid `cx`, `cy`
    and envelope `area_px` (px, px^2); `border` (the blob touches the image border); `mode`
    "ook", "tone" or null; `contour`: the envelope polygon's x and y columns (px), `edge`
    (optional): the stripe edge points' x, y columns (distorted px) and their 1-sigma (px).
    Each column is a packed array: "f4:" or "f8:" and the base64 of its little-endian float32 /
    float64 values (float32 where that holds the value exactly: lossless either way).
  * Pixel numbers lie within +-`MAX_ABS_PX`; areas and sigmas are positive; all finite.

Reply: as v1's, with `"v": 2` and `ranges`: one entry per `obs`, `[distance_m, estimator]`
(metres rounded to 10 um, the estimator's name) or null when the LED was not ranged, which the
device writes into its own frame line. No `solve_R_cw`: the server ranges, not the device.
"""

from __future__ import annotations

import base64
import binascii
import math
from dataclasses import dataclass

import numpy as np

from receiver.serve.wire import (MAX_ABS_T_S, MAX_DATAGRAM_BYTES_V2, MAX_DEVICE_CHARS, MAX_LED_ID,  # noqa: F401
                                 MAX_LEDS, MAX_SEQ, PROTOCOL_VERSION, ProtocolError, _get, _in_range, _int,
                                 _number, decode_request, parse_object)

VERSION = 2
# Pixel coordinates beyond this are no image point of any real sensor.
MAX_ABS_PX = 1e5
# Points of one observation's contour or edges at most (bounds the work of one LED).
MAX_POINTS = 4096
MODES = ("ook", "tone", None)
# Parsed cameras remembered (`_camera`).
CAMERA_CACHE = 256
CAMERA_KEYS = ("width", "height", "K", "dist", "pixel_size_um", "focal_length_mm", "row_readout_us", "exposure_us")


@dataclass(frozen=True)
class RequestV2:
    """A validated v2 request: `camera` a receiver.io.camera.CameraModel, `camera_key` its
    identity (a device whose camera changes gets a new positioner), `leds` the observations."""

    device: str
    seq: int
    t: float
    camera: object
    camera_key: tuple
    leds: list


# ---------------------------------------------------------------- packed arrays

def pack_column(a) -> str:
    """One float column as "f4:<b64>" when float32 holds every value exactly, else "f8:<b64>"."""
    a = np.ascontiguousarray(a, dtype=np.float64).ravel()
    f4 = a.astype("<f4")
    if np.array_equal(f4.astype(np.float64), a):
        return "f4:" + base64.b64encode(f4.tobytes()).decode("ascii")
    return "f8:" + base64.b64encode(a.astype("<f8").tobytes()).decode("ascii")


def unpack_column(s, where: str, max_n: int = MAX_POINTS) -> np.ndarray:
    """The float64 values of a packed column; ProtocolError when it is not one."""
    if not isinstance(s, str):
        raise ProtocolError("bad_type", f"{where} must be a packed array string")
    kind, _, b64 = s.partition(":")
    size = {"f4": 4, "f8": 8}.get(kind)
    if size is None:
        raise ProtocolError("bad_value", f"{where} must start with f4: or f8:")
    if len(b64) > 4 * ((max_n * size + 2) // 3):
        raise ProtocolError("bad_value", f"{where}: more than {max_n} values")
    try:
        raw = base64.b64decode(b64, validate=True)
    except (binascii.Error, ValueError):
        raise ProtocolError("bad_value", f"{where} is not base64") from None
    if len(raw) % size:
        raise ProtocolError("bad_value", f"{where}: {len(raw)} bytes is no whole number of values")
    return np.frombuffer(raw, dtype="<f4" if size == 4 else "<f8").astype(np.float64)


def _columns(value, n_cols: int, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n_cols:
        raise ProtocolError("bad_type", f"{where} must be a list of {n_cols} packed columns")
    cols = [unpack_column(c, f"{where}[{k}]") for k, c in enumerate(value)]
    if any(len(c) != len(cols[0]) for c in cols):
        raise ProtocolError("bad_value", f"{where}: columns of different lengths")
    out = np.stack(cols, axis=1) if cols[0].size else np.zeros((0, n_cols))
    if not np.all(np.isfinite(out)) or np.any(np.abs(out[:, :2]) > MAX_ABS_PX):
        raise ProtocolError("bad_value", f"{where}: values must be finite, within {MAX_ABS_PX:g} px")
    return out


# ---------------------------------------------------------------- request

def camera_fields(cam) -> dict:
    """The `camera` object of a request for a receiver.io.camera.CameraModel."""
    return {"width": int(cam.width), "height": int(cam.height),
            "K": [float(cam.K[0, 0]), float(cam.K[1, 1]), float(cam.K[0, 2]), float(cam.K[1, 2])],
            "dist": [float(x) for x in np.asarray(cam.dist, dtype=np.float64).ravel()],
            "pixel_size_um": None if cam.pixel_size_um is None else float(cam.pixel_size_um),
            "focal_length_mm": None if cam.focal_length_mm is None else float(cam.focal_length_mm),
            "row_readout_us": float(cam.row_readout_us or 0.0), "exposure_us": float(cam.exposure_us or 0.0)}


def _parse_camera(obj):
    from receiver.core.errors import InputError
    from receiver.io.camera import CameraModel, check_camera

    if not isinstance(obj, dict):
        raise ProtocolError("bad_type", "camera must be an object")
    w = _int(_get(obj, "width", "camera."), "camera.width", 1, 1 << 16)
    h = _int(_get(obj, "height", "camera."), "camera.height", 1, 1 << 16)
    K, dist = _get(obj, "K", "camera."), _get(obj, "dist", "camera.")
    if not (isinstance(K, list) and len(K) == 4 and isinstance(dist, list) and len(dist) == 5):
        raise ProtocolError("bad_type", "camera.K must hold 4 numbers, camera.dist 5")
    k = [_number(v, "camera.K") for v in K]
    d = [_number(v, "camera.dist") for v in dist]
    phys = [None if obj.get(key) is None else _number(obj[key], "camera." + key)
            for key in ("pixel_size_um", "focal_length_mm")]
    # the rolling shutter's row time: the outline fit takes the camera's turn while rows are read
    times = [0.0 if obj.get(key) is None else _number(obj[key], "camera." + key) for key in ("row_readout_us", "exposure_us")]
    if not all(0.0 <= v <= 1e6 for v in times):
        raise ProtocolError("bad_value", "camera.row_readout_us and camera.exposure_us must be within 0..1e6 us")
    cam = CameraModel(w, h, np.array([[k[0], 0.0, k[2]], [0.0, k[1], k[3]], [0.0, 0.0, 1.0]]),
                      np.array(d), pixel_size_um=phys[0], focal_length_mm=phys[1], row_readout_us=times[0],
                      exposure_us=times[1])
    try:
        check_camera(cam, "camera")
    except InputError as e:
        raise ProtocolError("bad_value", str(e)) from None
    return cam, (w, h, tuple(k), tuple(d), tuple(phys), tuple(times))


def _camera(obj):
    """`_parse_camera`, remembered for the last `CAMERA_CACHE` distinct cameras that passed (a
    device sends the same camera with every frame): keyed by the repr of its raw fields, which
    tells 1 from 1.0 and true, and 0.0 from -0.0."""
    if type(obj) is not dict:
        return _parse_camera(obj)
    raw = repr(tuple(obj.get(k) for k in CAMERA_KEYS))
    got = _cameras.get(raw)
    if got is None:
        got = _parse_camera(obj)
        if len(_cameras) >= CAMERA_CACHE:
            del _cameras[next(iter(_cameras))]
        _cameras[raw] = got
    return got


_cameras: dict = {}


def _parse_obs(item, i: int):
    from receiver.core.records import LedObservation

    where = f"obs[{i}]."
    if not isinstance(item, dict):
        raise ProtocolError("bad_type", f"obs[{i}] must be an object")
    led_id = _int(_get(item, "id", where), where + "id", 0, MAX_LED_ID)
    cx, cy = (_in_range(_get(item, k, where), where + k, -MAX_ABS_PX, MAX_ABS_PX) for k in ("cx", "cy"))
    area = _in_range(_get(item, "area_px", where), where + "area_px", 1e-9, MAX_ABS_PX ** 2)
    border = item.get("border", False)
    if type(border) is not bool:
        raise ProtocolError("bad_type", where + "border must be true or false")
    mode = item.get("mode")
    if mode not in MODES:
        raise ProtocolError("bad_value", where + "mode must be ook, tone or null")
    contour = _columns(_get(item, "contour", where), 2, where + "contour")
    edge = None
    if item.get("edge") is not None:
        e = _columns(item["edge"], 3, where + "edge")
        if np.any(e[:, 2] <= 0):
            raise ProtocolError("bad_value", where + "edge sigmas must be positive")
        edge = (np.ascontiguousarray(e[:, :2]), np.ascontiguousarray(e[:, 2]))
    return LedObservation(track=i, cx=cx, cy=cy, area_px=area, contour=np.ascontiguousarray(contour),
                          border=border, id=led_id, mode=mode, edge_px=edge)


def parse_any(data: bytes, fast=None):
    """A v1 `receiver.serve.wire.Request` or a v2 `RequestV2` of one datagram; ProtocolError
    otherwise. `fast`: v1's compiled check (`receiver.serve.wire.parse_request`)."""
    obj = decode_request(data, (PROTOCOL_VERSION, VERSION))
    return parse_object(obj, fast) if obj["v"] == PROTOCOL_VERSION else parse_v2(obj)


def parse_v2(obj: dict) -> RequestV2:
    """Validate a decoded v2 request object (`v` already read); raises ProtocolError. The common
    well-formed request is taken by `_parse_v2_fast`; anything it does not take is checked here
    field by field (and its fault named)."""
    got = _parse_v2_fast(obj)
    return got if got is not None else _parse_v2_checked(obj)


def _parse_v2_checked(obj: dict) -> RequestV2:
    """`parse_v2`, every field checked on its own with the reason for a refusal."""
    device = _get(obj, "device", "")
    if not isinstance(device, str):
        raise ProtocolError("bad_type", "device must be a string")
    if not 1 <= len(device) <= MAX_DEVICE_CHARS:
        raise ProtocolError("bad_value", f"device must have 1..{MAX_DEVICE_CHARS} characters")
    seq = None
    try:
        seq = _int(_get(obj, "seq", ""), "seq", 0, MAX_SEQ)
        t = _in_range(_get(obj, "t", ""), "t", -MAX_ABS_T_S, MAX_ABS_T_S, " s")
        cam, key = _camera(_get(obj, "camera", ""))
        obs = _get(obj, "obs", "")
        if not isinstance(obs, list):
            raise ProtocolError("bad_type", "obs must be a list")
        if len(obs) > MAX_LEDS:
            raise ProtocolError("too_many_leds", f"{len(obs)} LEDs > {MAX_LEDS}")
        leds = [_parse_obs(item, i) for i, item in enumerate(obs)]
        if len({o.id for o in leds}) != len(leds):
            raise ProtocolError("bad_value", "an LED id is listed twice")
    except ProtocolError as e:
        e.device, e.seq = device, seq
        raise
    return RequestV2(device, seq, t, cam, key, leds)


_F4, _F8 = np.dtype("<f4"), np.dtype("<f8")
_COLUMN_KINDS = {"f4:": (_F4, 4), "f8:": (_F8, 8)}


def _fast_column(s):
    """A packed column's little-endian values (not converted), or None when it is not one in
    the common form (`unpack_column` then names the fault)."""
    if type(s) is not str:
        return None
    kind = _COLUMN_KINDS.get(s[:3])
    if kind is None or len(s) - 3 > 4 * ((MAX_POINTS * kind[1] + 2) // 3):
        return None
    try:
        raw = binascii.a2b_base64(s[3:], strict_mode=True)
    except (binascii.Error, ValueError):
        return None
    if len(raw) % kind[1]:
        return None
    return np.frombuffer(raw, dtype=kind[0])


def _fast_points(value, n_cols: int, px_cols: list, other_cols: list):
    """A (n, n_cols) float64 array of a well-formed list of packed columns of one length, or
    None. Its pixel columns are appended to `px_cols` and the others to `other_cols`, which the
    caller checks for all observations at once."""
    if type(value) is not list or len(value) != n_cols:
        return None
    cols = [_fast_column(c) for c in value]
    if any(c is None or len(c) != len(cols[0]) for c in cols):
        return None
    out = np.empty((len(cols[0]), n_cols))
    for k, c in enumerate(cols):
        out[:, k] = c
    px_cols.append(out[:, :2])
    if n_cols > 2:
        other_cols.append(out[:, 2])
    return out


def _parse_v2_fast(obj: dict):
    """`parse_v2` of the common well-formed request, with plain type and range tests (a chained
    range test is False for NaN and infinities) and one finiteness and range check of all the
    datagram's points; None for anything else (`_parse_v2_checked` then checks it and names its
    fault). Takes only what `_parse_v2_checked` takes, and gives the same request (tested)."""
    from receiver.core.records import LedObservation

    device, seq, t, obs = obj.get("device"), obj.get("seq"), obj.get("t"), obj.get("obs")
    if not (type(device) is str and 1 <= len(device) <= MAX_DEVICE_CHARS and type(seq) is int
            and 0 <= seq <= MAX_SEQ and type(t) is float and -MAX_ABS_T_S <= t <= MAX_ABS_T_S
            and type(obs) is list and len(obs) <= MAX_LEDS):
        return None
    try:
        cam, key = _camera(obj.get("camera"))
    except ProtocolError:
        return None
    leds, ids, px_cols, sigma_cols = [], set(), [], []
    for i, item in enumerate(obs):
        if type(item) is not dict:
            return None
        led_id, cx, cy, area = item.get("id"), item.get("cx"), item.get("cy"), item.get("area_px")
        border, mode, edge = item.get("border", False), item.get("mode"), item.get("edge")
        if not (type(led_id) is int and 0 <= led_id <= MAX_LED_ID and led_id not in ids
                and type(cx) is float and -MAX_ABS_PX <= cx <= MAX_ABS_PX
                and type(cy) is float and -MAX_ABS_PX <= cy <= MAX_ABS_PX
                and type(area) is float and 1e-9 <= area <= MAX_ABS_PX ** 2
                and type(border) is bool and mode in MODES):
            return None
        contour = _fast_points(item.get("contour"), 2, px_cols, sigma_cols)
        if contour is None:
            return None
        if edge is not None:
            e = _fast_points(edge, 3, px_cols, sigma_cols)
            if e is None:
                return None
            edge = (np.ascontiguousarray(e[:, :2]), np.ascontiguousarray(e[:, 2]))
        ids.add(led_id)
        leds.append(LedObservation(track=i, cx=cx, cy=cy, area_px=area, contour=contour, border=border,
                                   id=led_id, mode=mode, edge_px=edge))
    if px_cols:
        px = np.concatenate(px_cols)
        if not np.all(np.abs(px) <= MAX_ABS_PX):          # False for NaN and infinities too
            return None
    if sigma_cols:
        sig = np.concatenate(sigma_cols)
        if not np.all(sig > 0) or not np.all(np.isfinite(sig)):
            return None
    return RequestV2(device, seq, t, cam, key, leds)


def sendable(leds) -> list:
    """The observations a v2 request carries: decoded, not S2-PSK (the indoor positioner's
    inputs), the first MAX_LEDS."""
    return [o for o in leds if o.id is not None and o.mode != "s2psk" and o.mode in MODES][:MAX_LEDS]


def make_request_v2(device: str, seq: int, t_s: float, camera: dict, leds, with_edges=None) -> dict:
    """A v2 request of `sendable` observations. `camera`: `camera_fields`' object. `with_edges`:
    per observation, whether its edge points are sent (default all)."""
    obs = []
    for k, o in enumerate(leds):
        contour = np.asarray(o.contour, dtype=np.float64).reshape(-1, 2) if o.contour is not None \
            else np.zeros((0, 2))
        item = {"id": int(o.id), "cx": float(o.cx), "cy": float(o.cy), "area_px": float(o.area_px),
                "border": bool(o.border), "mode": o.mode,
                "contour": [pack_column(contour[:, 0]), pack_column(contour[:, 1])]}
        if o.edge_px is not None and (with_edges is None or with_edges[k]):
            pts = np.asarray(o.edge_px[0], dtype=np.float64).reshape(-1, 2)
            item["edge"] = [pack_column(pts[:, 0]), pack_column(pts[:, 1]), pack_column(o.edge_px[1])]
        obs.append(item)
    return {"v": VERSION, "device": device, "seq": int(seq), "t": float(t_s), "camera": camera, "obs": obs}


def ranges_of(result_leds, sent) -> list:
    """The reply's `ranges`: [distance_m, estimator] or None for each sent observation (by its
    `track`, its index in the request) from a LocateResult's annotated observations."""
    out: list = [None] * len(sent)
    for o in result_leds:
        if o.distance_m is not None and 0 <= o.track < len(out) and math.isfinite(o.distance_m):
            out[o.track] = [o.distance_m, o.distance_estimator or ""]
    return out
