"""Truth (`truth.jsonl`) and run (`occloc run` JSON Lines) files, read for evaluation with
one-line errors for malformed lines.
"""

from __future__ import annotations

import json
import math

import numpy as np

from receiver.core.errors import InputError
POSITION_KEYS = ("x", "y", "z")


# ---------------------------------------------------------------- reading


def read_jsonl(path: str, what: str) -> list[tuple[int, dict]]:
    """(line number, object) for every non-empty line of a JSON Lines file."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.readlines()
    except OSError as e:
        raise InputError(f"cannot read {what} file {path}: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise InputError(f"{what} file {path} is not UTF-8 text") from None
    out = []
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as e:
            raise InputError(f"{path}:{n}: malformed JSON ({e.msg})") from None
        if not isinstance(obj, dict):
            raise InputError(f"{path}:{n}: expected a JSON object per line")
        out.append((n, obj))
    if not out:
        raise InputError(f"{what} file {path} has no frames")
    return out


def _number(v, where: str, *, allow_none: bool = True):
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where}: expected a number, got {json.dumps(v)[:40]}")
    return float(v)


def _frame_index(obj: dict, where: str) -> int:
    f = obj.get("frame")
    if isinstance(f, bool) or not isinstance(f, int) or f < 0:
        raise InputError(f"{where}: missing or bad 'frame'")
    return f


def _xyz(obj, where: str) -> np.ndarray:
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected an object with x, y, z")
    return np.array([_number(obj.get(k), f"{where}.{k}", allow_none=False) for k in POSITION_KEYS])


def _leds(obj: dict, where: str) -> list:
    leds = obj.get("leds", [])
    if not isinstance(leds, list) or not all(isinstance(d, dict) for d in leds):
        raise InputError(f"{where}: 'leds' must be a list of objects")
    return leds


def load_truth(path: str) -> dict[int, dict]:
    """frame -> {"xyz": (3,) camera position in m, "targets": list of (cx, cy, id, distance_m)}.

    Only visible LEDs become match targets; an S2-PSK entry with `emitters` gives one target
    per visible emitter, both carrying the entry's ID and distance.
    """
    truth = {}
    for n, obj in read_jsonl(path, "truth"):
        where = f"{path}:{n}"
        frame = _frame_index(obj, where)
        if frame in truth:
            raise InputError(f"{where}: duplicate frame {frame}")
        xyz = _xyz(obj.get("camera"), f"{where} camera")
        targets = []
        for i, led in enumerate(_leds(obj, where)):
            w = f"{where} leds[{i}]"
            led_id = led.get("id")
            dist = _number(led.get("distance_m"), f"{w}.distance_m")
            emitters = led.get("emitters")
            points = emitters if isinstance(emitters, list) and emitters else [led]
            for p in points:
                if not isinstance(p, dict) or not p.get("visible", True):
                    continue
                targets.append((_number(p.get("cx"), f"{w}.cx", allow_none=False),
                                _number(p.get("cy"), f"{w}.cy", allow_none=False), led_id, dist))
        truth[frame] = {"xyz": xyz, "targets": targets}
    return truth


def load_run(path: str, truth: dict[int, dict]) -> list[dict]:
    """The run's frames, each checked against the truth's frame numbers."""
    frames, seen = [], set()
    for n, obj in read_jsonl(path, "run"):
        where = f"{path}:{n}"
        frame = _frame_index(obj, where)
        if frame in seen:
            raise InputError(f"{where}: duplicate frame {frame}")
        if frame not in truth:
            raise InputError(f"{where}: frame {frame} is not in the truth file (wrong truth for this run?)")
        seen.add(frame)
        leds = []
        for i, led in enumerate(_leds(obj, where)):
            w = f"{where} leds[{i}]"
            led_id = led.get("id")
            if led_id is not None and (isinstance(led_id, bool) or not isinstance(led_id, int)):
                raise InputError(f"{w}: 'id' must be an integer or null")
            leds.append({"cx": _number(led.get("cx"), f"{w}.cx", allow_none=False),
                         "cy": _number(led.get("cy"), f"{w}.cy", allow_none=False),
                         "id": led_id,
                         "area_px": _number(led.get("area_px"), f"{w}.area_px"),
                         "distance_m": _number(led.get("distance_m"), f"{w}.distance_m"),
                         "estimator": str(led.get("distance_estimator") or "unnamed")})
        pos = obj.get("position")
        filt = raw = None
        if pos is not None:
            filt = _xyz(pos, f"{where} position")
            if pos.get("raw") is not None:
                raw = _xyz(pos["raw"], f"{where} position.raw")
        frames.append({"frame": frame, "t": _number(obj.get("t"), f"{where}.t"),
                       "latency_ms": _number(obj.get("latency_ms"), f"{where}.latency_ms"),
                       "leds": leds, "filtered": filt, "raw": raw})
    return frames
