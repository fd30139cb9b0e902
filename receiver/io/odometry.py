"""Odometry input (`occloc run --odometry FILE`, INTERFACES.md): JSON Lines
`{"t": 1.25, "speed_mps": 13.9}`, `t` in seconds on the video's time axis, strictly increasing,
as an OBD-II logger writes. Thesis eq. 48 uses the host vehicle's speed V_HV.

`load_odometry(path)` checks every line (one-line `InputError` naming the line) and returns an
`Odometry`, whose call `odo(t_s)` gives the speed at a frame time by linear interpolation, or
None outside the logged span (no extrapolation).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.core.errors import InputError

MAX_ODOMETRY_BYTES = 64 * 1024 * 1024
MAX_SPEED_MPS = 150.0  # 540 km/h: beyond any road vehicle
MAX_GAP_S = 2.0  # no interpolation across a longer gap in the log


class Odometry:
    """`odo(t_s)`: the speed at t_s (module doc). `asked` / `answered` count the calls and those
    with a speed; `note()` says when a log answered none (a time axis other than the video's)."""

    def __init__(self, t_s: np.ndarray, speed_mps: np.ndarray):
        self.t_s, self.speed_mps = t_s, speed_mps
        self.asked = self.answered = 0

    def note(self) -> str | None:
        if self.asked and not self.answered:
            return (f"odometry covers none of the frames (log t {self.t_s[0]:g}..{self.t_s[-1]:g} s, "
                    f"on the video's time axis)")
        return None

    def __call__(self, t_s: float) -> float | None:
        self.asked += 1
        v = self._speed(t_s)
        self.answered += v is not None
        return v

    def _speed(self, t_s: float) -> float | None:
        t = self.t_s
        if t.size == 0 or not t[0] <= t_s <= t[-1]:
            return None
        i = int(np.searchsorted(t, t_s))
        if i == 0 or t[i] == t_s:
            return float(self.speed_mps[i])
        if t[i] - t[i - 1] > MAX_GAP_S:
            return None
        w = (t_s - t[i - 1]) / (t[i] - t[i - 1])
        return float((1 - w) * self.speed_mps[i - 1] + w * self.speed_mps[i])


def _number(obj: dict, key: str, where: str) -> float:
    v = obj.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a finite number")
    return float(v)


def load_odometry(path: str) -> Odometry:
    from receiver.io.files import read_jsonl

    ts, vs = [], []
    for n, obj in read_jsonl(path, "odometry", require=False, max_bytes=MAX_ODOMETRY_BYTES):
        where = f"{path} line {n}"
        t, v = _number(obj, "t", where), _number(obj, "speed_mps", where)
        if not 0.0 <= v <= MAX_SPEED_MPS:
            raise InputError(f"{where}: speed_mps {v:g} outside 0..{MAX_SPEED_MPS:g} m/s")
        if ts and t <= ts[-1]:
            raise InputError(f"{where}: t {t:g} is not after the previous line's {ts[-1]:g} (must increase)")
        ts.append(t)
        vs.append(v)
    if not ts:
        raise InputError(f"{path}: no odometry lines")
    return Odometry(np.array(ts), np.array(vs))
