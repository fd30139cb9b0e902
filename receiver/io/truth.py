"""Truth (`truth.jsonl`) and run (`occloc run` JSON Lines) files, read for evaluation with
one-line errors for malformed lines.

Vehicle scenes add a `vehicle` object to both (INTERFACES.md). Read here into plain dicts:

* truth `vehicle`: `{"hv": {"x", "y", "speed_mps", "heading_deg"} | None,
  "fv": [{"id", "x", "y", "distance_m", "angle_deg", "visible", "rel_speed_mps"}]}`; hv in road
  coordinates (m), fv relative to the camera (x ahead, y to the left, m; angle in degrees).
  Optional numbers are None when absent; an fv's missing `angle_deg`/`distance_m` is derived
  from its x, y; a missing `visible` falls back to the visibility of the truth LED entry with the
  same ID (the taillight pair), and to True without one.
* run `vehicle`: `{"hv": fix | None, "fv": [...], "extra": {name: fix}}` where a fix is
  `{"x", "y", "std_m", "heading_deg", "speed_mps", "method", "n_lights", "raw": {"x", "y",
  "method"} | None}`; `extra` holds any further `hv_<name>` objects of the line (a second
  locator such as eqs. 44-47 reported beside the main one), read like `hv`.
"""

from __future__ import annotations

import json
import math

import numpy as np

from receiver.core.errors import InputError
from receiver.io.files import read_jsonl
POSITION_KEYS = ("x", "y", "z")


# ---------------------------------------------------------------- reading


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


def _int_or_none(v, where: str):
    if v is not None and (isinstance(v, bool) or not isinstance(v, int)):
        raise InputError(f"{where}: expected an integer or null, got {json.dumps(v)[:40]}")
    return v


def _str_or_none(v, where: str):
    if v is not None and not isinstance(v, str):
        raise InputError(f"{where}: expected a string or null, got {json.dumps(v)[:40]}")
    return v


def _object(v, where: str, *, allow_none: bool = True):
    if v is None and allow_none:
        return None
    if not isinstance(v, dict):
        raise InputError(f"{where}: expected an object, got {json.dumps(v)[:40]}")
    return v


def _object_list(v, where: str) -> list:
    if v is None:
        return []
    if not isinstance(v, list) or not all(isinstance(d, dict) for d in v):
        raise InputError(f"{where}: expected a list of objects")
    return v


def _bearing_and_range(x, y, angle, dist):
    """Fill a missing bearing (deg) or range (m) from the relative x, y when both are known."""
    if x is not None and y is not None:
        if angle is None:
            angle = math.degrees(math.atan2(y, x))
        if dist is None:
            dist = math.hypot(x, y)
    return angle, dist


def _truth_vehicle(v, leds: list, where: str):
    v = _object(v, where)
    if v is None:
        return None
    hv = _object(v.get("hv"), f"{where}.hv")
    if hv is not None:
        hv = {"x": _number(hv.get("x"), f"{where}.hv.x", allow_none=False),
              "y": _number(hv.get("y"), f"{where}.hv.y", allow_none=False),
              "speed_mps": _number(hv.get("speed_mps"), f"{where}.hv.speed_mps"),
              "heading_deg": _number(hv.get("heading_deg"), f"{where}.hv.heading_deg")}
    led_visible = {}
    for led in leds:
        ems = led.get("emitters") if isinstance(led.get("emitters"), list) else []
        seen = bool(led.get("visible", True)) or any(isinstance(e, dict) and e.get("visible", True) for e in ems)
        led_visible[led.get("id")] = led_visible.get(led.get("id"), False) or seen
    fvs = []
    for i, fv in enumerate(_object_list(v.get("fv"), f"{where}.fv")):
        w = f"{where}.fv[{i}]"
        out = {"id": _int_or_none(fv.get("id"), f"{w}.id")}
        for k in ("x", "y", "distance_m", "angle_deg", "rel_speed_mps"):
            out[k] = _number(fv.get(k), f"{w}.{k}")
        out["angle_deg"], out["distance_m"] = _bearing_and_range(out["x"], out["y"], out["angle_deg"],
                                                                 out["distance_m"])
        vis = fv.get("visible")
        if vis is None:
            vis = led_visible.get(out["id"], True) if out["id"] is not None else True
        elif not isinstance(vis, bool):
            raise InputError(f"{w}.visible: expected true or false, got {json.dumps(vis)[:40]}")
        out["visible"] = vis
        fvs.append(out)
    return {"hv": hv, "fv": fvs}


HV_NUMBERS = ("std_m", "heading_deg", "speed_mps")


def _run_fix(v, where: str):
    v = _object(v, where)
    if v is None:
        return None
    fix = {"x": _number(v.get("x"), f"{where}.x", allow_none=False),
           "y": _number(v.get("y"), f"{where}.y", allow_none=False),
           **{k: _number(v.get(k), f"{where}.{k}") for k in HV_NUMBERS},
           "method": _str_or_none(v.get("method"), f"{where}.method"),
           "n_lights": _int_or_none(v.get("n_lights"), f"{where}.n_lights")}
    raw = _object(v.get("raw"), f"{where}.raw")
    if raw is not None:
        raw = {"x": _number(raw.get("x"), f"{where}.raw.x", allow_none=False),
               "y": _number(raw.get("y"), f"{where}.raw.y", allow_none=False),
               "method": _str_or_none(raw.get("method"), f"{where}.raw.method")}
    fix["raw"] = raw
    return fix


FV_NUMBERS = ("distance_m", "angle_deg", "x", "y", "std_m", "rel_speed_mps", "ttc_s", "road_x", "road_y")


def _run_vehicle(v, where: str):
    v = _object(v, where)
    if v is None:
        return None
    fvs = []
    for i, fv in enumerate(_object_list(v.get("fv"), f"{where}.fv")):
        w = f"{where}.fv[{i}]"
        out = {"id": _int_or_none(fv.get("id"), f"{w}.id"),
               **{k: _number(fv.get(k), f"{w}.{k}") for k in FV_NUMBERS},
               "zone": _str_or_none(fv.get("zone"), f"{w}.zone")}
        # The bearing is what FVs without a decoded ID are matched by; derive it when only x, y came.
        out["angle_deg"], _ = _bearing_and_range(out["x"], out["y"], out["angle_deg"], 0.0)
        fvs.append(out)
    extra = {k[3:]: _run_fix(v[k], f"{where}.{k}") for k in sorted(v)
             if k.startswith("hv_") and len(k) > 3 and v[k] is not None}
    return {"hv": _run_fix(v.get("hv"), f"{where}.hv"), "fv": fvs, "extra": extra}


def load_truth(path: str) -> dict[int, dict]:
    """frame -> {"xyz": (3,) camera position in m, "targets": list of (cx, cy, id, distance_m),
    "t": time in s or None, "vehicle": see the module docstring, None without one,
    "s2psk": list of (id, emitters) per truth S2-PSK light with two emitters, each emitter
    (cx, cy, area_px, visible) with an occluded emitter (`occluded_frac` above 1 %) not visible}.

    Only visible LEDs become match targets; an S2-PSK entry with `emitters` gives one target
    per visible emitter, both carrying the entry's ID and distance.
    """
    truth = {}
    for n, obj in read_jsonl(path, "truth"):
        where = f"{path}:{n}"
        frame, rec = truth_frame(obj, where)
        if frame in truth:
            raise InputError(f"{where}: duplicate frame {frame}")
        truth[frame] = rec
    return truth


# An emitter hidden by more than this fraction is not visible (tools.synth.render.OCCLUDED_MAX).
OCCLUDED_MAX = 0.01


def truth_frame(obj: dict, where: str = "truth") -> tuple[int, dict]:
    """(frame index, record of `load_truth`) of one truth object (a truth.jsonl line)."""
    frame = _frame_index(obj, where)
    xyz = _xyz(obj.get("camera"), f"{where} camera")
    targets, s2psk = [], []
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
        if led.get("mode") == "s2psk" and isinstance(emitters, list) and len(emitters) == 2 \
                and all(isinstance(e, dict) for e in emitters):
            ems = []
            for e in emitters:
                occ = _number(e.get("occluded_frac"), f"{w}.emitters.occluded_frac") or 0.0
                ems.append((_number(e.get("cx"), f"{w}.emitters.cx", allow_none=False),
                            _number(e.get("cy"), f"{w}.emitters.cy", allow_none=False),
                            _number(e.get("area_px"), f"{w}.emitters.area_px") or 0.0,
                            bool(e.get("visible", True)) and occ <= OCCLUDED_MAX))
            s2psk.append((led_id, tuple(ems)))
    return frame, {"xyz": xyz, "targets": targets, "t": _number(obj.get("t"), f"{where}.t"),
                   "vehicle": _truth_vehicle(obj.get("vehicle"), _leds(obj, where), f"{where} vehicle"),
                   "s2psk": s2psk}


def load_run(path: str, truth: dict[int, dict]) -> list[dict]:
    """The run's frames, each checked against the truth's frame numbers; "vehicle" is None or
    the object of the module docstring."""
    frames, seen = [], set()
    for n, obj in read_jsonl(path, "run"):
        where = f"{path}:{n}"
        fr = run_frame(obj, where)
        frame = fr["frame"]
        if frame in seen:
            raise InputError(f"{where}: duplicate frame {frame}")
        if frame not in truth:
            raise InputError(f"{where}: frame {frame} is not in the truth file (wrong truth for this run?)")
        if not isinstance(obj.get("leds", []), list):
            raise InputError(f"{where}: 'leds' must be a list of objects")
        seen.add(frame)
        frames.append(fr)
    check_same_recording(frames, truth, path)
    return frames


def run_frame(obj: dict, where: str = "run") -> dict:
    """One run object (an `occloc run` line, receiver.io.output.frame_record) as `load_run` reads it."""
    frame = _frame_index(obj, where)
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
                     "estimator": str(led.get("distance_estimator") or "unnamed"),
                     "kind": _str_or_none(led.get("kind"), f"{w}.kind")})
    pos = obj.get("position")
    filt = raw = None
    if pos is not None:
        filt = _xyz(pos, f"{where} position")
        if pos.get("raw") is not None:
            raw = _xyz(pos["raw"], f"{where} position.raw")
    return {"frame": frame, "t": _number(obj.get("t"), f"{where}.t"),
            "latency_ms": _number(obj.get("latency_ms"), f"{where}.latency_ms"),
            "leds": leds, "filtered": filt, "raw": raw,
            "vehicle": _run_vehicle(obj.get("vehicle"), f"{where} vehicle")}


# A run "belongs" to a truth file when at least this share of its decoded IDs (over all frames)
# are IDs the truth shows; wrong decodes are rare (a few per thousand), another recording's
# truth shares almost no random 16-bit ID.
MIN_SHARED_ID_FRACTION = 0.5
MIN_IDS_TO_JUDGE = 3


def check_same_recording(frames: list[dict], truth: dict[int, dict], path: str) -> None:
    """InputError when the run evidently comes from another recording than the truth: its frame
    times disagree with the truth's, or most of its decoded LED IDs never occur in the truth."""
    for f in frames:
        tt = truth[f["frame"]].get("t")
        if f["t"] is not None and tt is not None and abs(f["t"] - tt) > 0.5:
            raise InputError(f"{path}: frame {f['frame']} is at t={f['t']:g} s in the run but "
                             f"{tt:g} s in the truth (wrong truth for this run?)")
    truth_ids = {tgt[2] for v in truth.values() for tgt in v["targets"]}
    truth_ids |= {fv.get("id") for v in truth.values() if v.get("vehicle") for fv in v["vehicle"]["fv"]}
    run_ids = [led["id"] for f in frames for led in f["leds"] if led["id"] is not None]
    if len(set(run_ids)) >= MIN_IDS_TO_JUDGE:
        shared = sum(i in truth_ids for i in run_ids) / len(run_ids)
        if shared < MIN_SHARED_ID_FRACTION:
            raise InputError(f"{path}: only {100 * shared:.0f}% of the run's decoded IDs occur in the "
                             f"truth file (wrong truth for this run?)")
