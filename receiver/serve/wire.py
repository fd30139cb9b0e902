"""Lighting-server datagram format v1, shared by the server and the client: limits, request
parsing with a reason for every rejection (`parse_request` -> `Request` or `ProtocolError`),
request building (`make_request`) and strict JSON encoding (`encode`). Format: README
"Lighting server".
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np


PROTOCOL_VERSION = 1
# One request must fit here: 64 LEDs with full-precision numbers, 10-digit IDs and pixel
# centroids take about 11 kB (8 kB with the IDs and no centroids `make_request` writes).
MAX_DATAGRAM_BYTES = 16384
# A v2 request carries outlines (`receiver.serve.wire_v2`): up to the largest UDP payload (IPv4).
# The walk recording's busiest frame (17 LEDs, 1,487 edge points) takes about 45 kB.
MAX_DATAGRAM_BYTES_V2 = 65507
MAX_LEDS = 64
MAX_DEVICE_CHARS = 64
MAX_SEQ = 2 ** 53          # exact in any JSON implementation's doubles
MAX_LED_ID = 2 ** 31 - 1
# |u|, |v| limit of normalized image points: 100 is 89.4 degrees off the optical axis.
MAX_ABS_UV = 100.0
# Physical ranges of the other numbers (beyond them the solver's arithmetic overflows or the
# value means nothing): a range 1 mm..10 km, its 1-sigma 1 um..1 km, the image-point 1-sigma
# 1e-9..1 normalized units (1 = 45 degrees), the frame time |t| <= 1e9 s (31 years).
DISTANCE_RANGE_M = (1e-3, 1e4)
SIGMA_M_RANGE = (1e-6, 1e3)
SIGMA_UV_RANGE = (1e-9, 1.0)
MAX_ABS_T_S = 1e9
# Counted reasons for dropping a request, in the order the summary lists them.
REASONS = ("oversized", "bad_json", "not_object", "bad_version", "missing_field", "bad_type",
           "bad_value", "too_many_leds", "too_many_devices", "too_many_devices_per_source", "old_seq",
           "seq_jump", "bad_mac", "wrong_source", "rate_limited", "internal_error")


class ProtocolError(Exception):
    """A request that is dropped: `reason` (one of REASONS), `detail` (one line), and the
    request's `device` / `seq` when they could be read."""

    def __init__(self, reason: str, detail: str = "", device: str | None = None, seq: int | None = None):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail, self.device, self.seq = reason, detail, device, seq

    def reply(self) -> dict:
        out = {"v": PROTOCOL_VERSION, "error": self.reason}
        if self.detail:
            out["detail"] = self.detail
        if self.device is not None:
            out["device"] = self.device
        if self.seq is not None:
            out["seq"] = self.seq
        return out


@dataclass(frozen=True)
class Request:
    """A validated request. uv (N, 2) normalized image points; d, sigma_d (N,) metres, NaN where
    the LED has no range; t seconds (device clock); sigma_uv normalized units."""

    device: str
    seq: int
    t: float
    sigma_uv: float
    ids: tuple[int, ...]
    uv: np.ndarray
    d: np.ndarray
    sigma_d: np.ndarray


# ---------------------------------------------------------------- validation

def _reject_constant(name: str):
    raise ValueError(f"{name} is not JSON")


def _get(obj: dict, key: str, where: str):
    if key not in obj:
        raise ProtocolError("missing_field", f"{where}{key} is missing")
    return obj[key]


def _int(v, where: str, lo: int, hi: int) -> int:
    if type(v) is not int:
        raise ProtocolError("bad_type", f"{where} must be an integer")
    if not lo <= v <= hi:
        raise ProtocolError("bad_value", f"{where} must be in {lo}..{hi}")
    return v


def _number(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ProtocolError("bad_type", f"{where} must be a number")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise ProtocolError("bad_value", f"{where} must be finite")
    return f


def _in_range(v, where: str, lo: float, hi: float, unit: str = "") -> float:
    """A number in lo..hi (`positive` named in the reason when it is not)."""
    f = _number(v, where)
    if f <= 0 < lo:
        raise ProtocolError("bad_value", f"{where} must be positive")
    if not lo <= f <= hi:
        raise ProtocolError("bad_value", f"{where} must be in {lo:g}..{hi:g}{unit}")
    return f


def _range_or_none(v, where: str, lo: float, hi: float) -> float:
    """A number in lo..hi metres, or NaN for null."""
    if v is None:
        return math.nan
    return _in_range(v, where, lo, hi, " m")


# One decoder / encoder for every datagram (json.loads / json.dumps with options build a new one
# per call, scanner and all): the same parsing and output.
_DECODER = json.JSONDecoder(parse_constant=_reject_constant)
_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def decode_request(data: bytes, versions=(PROTOCOL_VERSION,)) -> dict:
    """The request object of a datagram of one of `versions` (1, and 2: `receiver.serve.wire_v2`),
    each version within its size limit; ProtocolError otherwise."""
    if len(data) > MAX_DATAGRAM_BYTES_V2:
        raise ProtocolError("oversized", f"{len(data)} bytes > {MAX_DATAGRAM_BYTES_V2}")
    try:
        obj = _DECODER.decode(data.decode("utf-8"))
    except (ValueError, RecursionError) as e:
        raise ProtocolError("bad_json", str(e).splitlines()[0][:80] if str(e) else "") from None
    if not isinstance(obj, dict):
        raise ProtocolError("not_object", "the datagram must be a JSON object")
    v = obj.get("v")
    if type(v) is not int or v not in versions:
        raise ProtocolError("bad_version", "v must be " + " or ".join(map(str, versions)))
    if v == PROTOCOL_VERSION and len(data) > MAX_DATAGRAM_BYTES:
        raise ProtocolError("oversized", f"{len(data)} bytes > {MAX_DATAGRAM_BYTES}")
    return obj


def _parse_led(item, i: int) -> tuple[int, float, float, float, float]:
    """(id, u, v, d, sigma_d) of leds[i]; d and sigma_d NaN when the LED has no range."""
    where = f"leds[{i}]."
    if not isinstance(item, dict):
        raise ProtocolError("bad_type", f"leds[{i}] must be an object")
    led_id = _int(_get(item, "id", where), where + "id", 0, MAX_LED_ID)
    u, v = (_number(_get(item, k, where), where + k) for k in ("u", "v"))
    if abs(u) > MAX_ABS_UV or abs(v) > MAX_ABS_UV:
        raise ProtocolError("bad_value", f"{where}u/v beyond {MAX_ABS_UV:g}")
    d = _range_or_none(item.get("distance_m"), where + "distance_m", *DISTANCE_RANGE_M)
    sd = _range_or_none(item.get("sigma_m"), where + "sigma_m", *SIGMA_M_RANGE)
    if math.isnan(d) != math.isnan(sd):
        raise ProtocolError("bad_value", f"{where}distance_m and sigma_m: both numbers or both null")
    for k in ("cx", "cy"):
        if k in item:
            _number(item[k], where + k)
    return led_id, u, v, d, sd


def _parse_led_fast(item) -> tuple | None:
    """`_parse_led` of the common case -- an object with an int id, float u / v and a float range
    with its sigma, no centroid -- checked with plain comparisons (a chained range test is False
    for NaN and infinities); None for anything else, which `_parse_led` then checks (and names
    the fault of)."""
    if type(item) is not dict or "cx" in item or "cy" in item:
        return None
    led_id, u, v = item.get("id"), item.get("u"), item.get("v")
    d, sd = item.get("distance_m"), item.get("sigma_m")
    if (type(led_id) is int and 0 <= led_id <= MAX_LED_ID and type(u) is float and type(v) is float
            and -MAX_ABS_UV <= u <= MAX_ABS_UV and -MAX_ABS_UV <= v <= MAX_ABS_UV
            and type(d) is float and DISTANCE_RANGE_M[0] <= d <= DISTANCE_RANGE_M[1]
            and type(sd) is float and SIGMA_M_RANGE[0] <= sd <= SIGMA_M_RANGE[1]):
        return led_id, u, v, d, sd
    return None


def _parse_body(obj: dict, device: str, seq: int) -> Request:
    t = _in_range(_get(obj, "t", ""), "t", -MAX_ABS_T_S, MAX_ABS_T_S, " s")
    sigma_uv = _in_range(_get(obj, "sigma_uv", ""), "sigma_uv", *SIGMA_UV_RANGE)
    leds = _get(obj, "leds", "")
    if not isinstance(leds, list):
        raise ProtocolError("bad_type", "leds must be a list")
    if len(leds) > MAX_LEDS:
        raise ProtocolError("too_many_leds", f"{len(leds)} LEDs > {MAX_LEDS}")
    if "camera" in obj and not isinstance(obj["camera"], dict):
        raise ProtocolError("bad_type", "camera must be an object")
    rows = [_parse_led_fast(item) or _parse_led(item, i) for i, item in enumerate(leds)]
    ids = tuple(r[0] for r in rows)
    if len(set(ids)) != len(ids):
        raise ProtocolError("bad_value", "an LED id is listed twice")
    arr = np.array([r[1:] for r in rows], dtype=np.float64).reshape(-1, 4)
    return Request(device, seq, t, sigma_uv, ids, arr[:, :2], arr[:, 2].copy(), arr[:, 3].copy())


def parse_request(data: bytes, fast=None) -> Request:
    """Validate one v1 datagram (module docstring); raises ProtocolError. `fast`: the compiled
    check of the common form (`receiver.serve._wire`), tried first; what it does not take is
    checked here. (`receiver.serve.wire_v2.parse_any` takes either version.)"""
    return parse_object(decode_request(data), fast)


def parse_object(obj: dict, fast=None) -> Request:
    """`parse_request` of a decoded v1 request object."""
    if fast is not None:
        got = fast.parse(obj)
        if got is not None:
            device, seq, t, sigma_uv, ids, arr = got
            return Request(device, seq, t, sigma_uv, ids, arr[:, :2], arr[:, 2].copy(), arr[:, 3].copy())
    device = _get(obj, "device", "")
    if not isinstance(device, str):
        raise ProtocolError("bad_type", "device must be a string")
    if not 1 <= len(device) <= MAX_DEVICE_CHARS:
        raise ProtocolError("bad_value", f"device must have 1..{MAX_DEVICE_CHARS} characters")
    try:
        seq = _int(_get(obj, "seq", ""), "seq", 0, MAX_SEQ)
    except ProtocolError as e:
        e.device = device
        raise
    try:
        return _parse_body(obj, device, seq)
    except ProtocolError as e:
        e.device, e.seq = device, seq
        raise


def make_request(device: str, seq: int, t_s: float, sigma_uv: float, ids, uv: np.ndarray,
                 d: np.ndarray, sigma_d: np.ndarray) -> dict:
    """A v1 request. ids (N,) LED IDs; uv (N, 2) undistorted normalized image points; d, sigma_d
    (N,) ranges and their 1-sigma in metres -- a range outside DISTANCE_RANGE_M or with a sigma
    outside SIGMA_M_RANGE (NaN, infinite, non-positive ...) is sent as null, which the server
    accepts (the request's other LEDs still count), where the value would be refused."""
    leds = []
    for i, led_id in enumerate(ids):
        di, si = float(d[i]), float(sigma_d[i])
        has_d = (DISTANCE_RANGE_M[0] <= di <= DISTANCE_RANGE_M[1]
                 and SIGMA_M_RANGE[0] <= si <= SIGMA_M_RANGE[1])
        leds.append({"id": int(led_id), "u": float(uv[i][0]), "v": float(uv[i][1]),
                     "distance_m": di if has_d else None, "sigma_m": si if has_d else None})
    return {"v": PROTOCOL_VERSION, "device": device, "seq": int(seq), "t": float(t_s),
            "sigma_uv": float(sigma_uv), "leds": leds}


def encode(msg: dict) -> bytes:
    """A request or reply as a compact UTF-8 JSON datagram. Strict JSON: a NaN or infinity
    anywhere raises ValueError (never `NaN` / `Infinity` tokens on the wire)."""
    return _ENCODER.encode(msg).encode("utf-8")


def all_finite(obj) -> bool:
    """True when every number in a JSON-like value (dicts, lists, tuples) is finite."""
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(all_finite(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(all_finite(v) for v in obj)
    return True
