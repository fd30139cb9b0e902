"""Trajectories out of `occloc run` JSON Lines (or a recording's truth.jsonl) in formats other
tools read (`occloc export`):

* `tum`: the TUM RGB-D trajectory format, one pose per line, ``t x y z qx qy qz qw`` (seconds,
  metres, the camera-to-world rotation as a unit quaternion, scalar last): what `evo_traj`,
  `evo_ape` and `evo_rpe` read (`evo_ape tum truth.tum run.tum`). A frame needs a position and
  an orientation (`R_wc`); the host vehicle's pose is its (x, y, 0) and its heading about z.
  Photos (all at t = 0) are numbered instead: their time is the frame number.
* `csv`: one row per frame with a header (`CSV_COLUMNS`), empty cells where a value is absent;
  for spreadsheets and pandas.
* `geojson`: an RFC 7946 FeatureCollection: a Point per located frame (properties: frame, t,
  file, z_m, method) and the LineString of the whole track, in WGS 84 longitude/latitude. The map
  frame has no place on the Earth of its own, so `origin` (latitude, longitude of the map's
  (0, 0), degrees) is required; x is taken as east and y as north (a local tangent plane, exact
  to well under a millimetre over the few hundred metres of a map).

Which trajectory: a truth file's camera (lines with `"camera"`), else the indoor position of a
run (`"position"`; with `raw` the frame's own fix instead of the filtered one), else the host
vehicle (`"vehicle"."hv"`).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from receiver.core.errors import InputError
from receiver.io.output import ZONE_ORDER

FORMATS = ("tum", "csv", "geojson")
# Extension of each format's file (what `occloc export --out` expects).
EXTENSIONS = {"tum": (".tum", ".txt"), "csv": (".csv",), "geojson": (".geojson", ".json")}
CSV_COLUMNS = ("frame", "t", "file", "x", "y", "z", "method", "n_leds", "std_x_m", "std_y_m", "std_z_m",
               "yaw_deg", "pitch_deg", "roll_deg", "no_fix", "hv_x", "hv_y", "hv_heading_deg", "hv_speed_mps",
               "fv_count", "fv_closest_id", "fv_closest_distance_m", "fv_min_ttc_s", "fv_worst_zone")
# WGS 84 ellipsoid: semi-major axis (m) and first eccentricity squared.
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
# Decimal places: 0.1 mm in the map frame, ~1 cm in degrees of latitude/longitude is 1e-7.
TUM_DECIMALS = 6
DEG_DECIMALS = 9


def quaternion_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    """(qx, qy, qz, qw) of a rotation matrix (scipy's `Rotation.from_matrix`), qw >= 0."""
    from scipy.spatial.transform import Rotation
    q = Rotation.from_matrix(np.asarray(R, float)).as_quat()
    if q[3] < 0:
        q = -q
    return tuple(float(v) for v in q)


def _truth_pose(obj: dict):
    from receiver.locate.pose import ypr_to_rotation
    cam = obj.get("camera")
    if not isinstance(cam, dict):
        return None
    R_wc = ypr_to_rotation(cam.get("yaw", 0.0), cam.get("pitch", 0.0), cam.get("roll", 0.0)).T
    return (cam["x"], cam["y"], cam["z"]), R_wc


def _run_pose(obj: dict, raw: bool):
    pos = obj.get("position")
    if not isinstance(pos, dict):
        return None
    p = pos.get("raw") if raw else pos
    if not isinstance(p, dict) or p.get("x") is None:
        return None
    R = pos.get("R_wc")
    return (p["x"], p["y"], p.get("z", 0.0)), (np.asarray(R, float) if R is not None else None)


def _hv_pose(obj: dict):
    hv = (obj.get("vehicle") or {}).get("hv")
    if not isinstance(hv, dict) or hv.get("x") is None:
        return None
    h = math.radians(hv.get("heading_deg") or 0.0)
    R = np.array([[math.cos(h), -math.sin(h), 0.0], [math.sin(h), math.cos(h), 0.0], [0.0, 0.0, 1.0]])
    return (hv["x"], hv["y"], 0.0), R


def trajectory_kind(lines: list[dict]) -> str:
    """'truth', 'position' or 'hv': what `poses` takes from these lines."""
    if any("camera" in o for o in lines):
        return "truth"
    if any(isinstance(o.get("position"), dict) for o in lines):
        return "position"
    if any(isinstance((o.get("vehicle") or {}).get("hv"), dict) for o in lines):
        return "hv"
    return "position"


def poses(lines: list[dict], *, raw: bool = False) -> list[tuple[dict, tuple, np.ndarray | None]]:
    """(line, (x, y, z) m, camera-to-world rotation or None) of every line with a pose."""
    kind = trajectory_kind(lines)
    out = []
    for o in lines:
        p = _truth_pose(o) if kind == "truth" else _run_pose(o, raw) if kind == "position" else _hv_pose(o)
        if p is not None and all(v is not None and math.isfinite(float(v)) for v in p[0]):
            out.append((o, p[0], p[1]))
    return out


def photo_times(lines: list[dict]) -> bool:
    """True when the lines are photos (each names its `file`) whose times do not increase (every
    photo has t = 0 unless the run was given --fps): their TUM time is then the frame number,
    since evo needs increasing times."""
    if not lines or not all(o.get("file") for o in lines):
        return False
    t = [float(o.get("t") or 0.0) for o in lines]
    return any(b <= a for a, b in zip(t, t[1:]))


def to_tum(lines: list[dict], *, raw: bool = False) -> tuple[str, int]:
    """(TUM text, poses left out for want of an orientation). Photos without increasing times
    (`photo_times`) get their frame number as time."""
    rows, missing = [], 0
    by_frame = photo_times(lines)
    for o, (x, y, z), R in poses(lines, raw=raw):
        if R is None:
            missing += 1
            continue
        q = quaternion_xyzw(R)
        t = float(o.get("frame") or 0) if by_frame else o.get("t") or 0.0
        rows.append(" ".join(f"{float(v):.{TUM_DECIMALS}f}" for v in (t, x, y, z))
                    + " " + " ".join(f"{v:.9f}" for v in q))
    return "".join(r + "\n" for r in rows), missing


def _fv_cells(veh: dict | None) -> list:
    fv = [f for f in ((veh or {}).get("fv") or []) if isinstance(f, dict)]
    if not fv:
        return [0 if veh else "", "", "", "", ""]
    ranged = [f for f in fv if f.get("distance_m") is not None]
    closest = min(ranged, key=lambda f: f["distance_m"]) if ranged else None
    ttcs = [f["ttc_s"] for f in fv if f.get("ttc_s") is not None]
    zones = [f.get("zone") for f in fv if f.get("zone") in ZONE_ORDER]
    return [len(fv), closest.get("id") if closest else "", closest["distance_m"] if closest else "",
            min(ttcs) if ttcs else "", max(zones, key=ZONE_ORDER.index) if zones else ""]


def to_csv(lines: list[dict], *, raw: bool = False) -> str:
    """One row per line (`CSV_COLUMNS`); a truth file gives its camera pose in x..roll_deg."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    truth = trajectory_kind(lines) == "truth"
    for o in lines:
        if truth:
            cam = o.get("camera") or {}
            row = [o.get("frame"), o.get("t"), "", cam.get("x"), cam.get("y"), cam.get("z"), "truth", "",
                   "", "", "", cam.get("yaw"), cam.get("pitch"), cam.get("roll"), "", "", "", "", "",
                   "", "", "", "", ""]
        else:
            pos = o.get("position") if isinstance(o.get("position"), dict) else {}
            p = (pos.get("raw") or {}) if raw and pos else pos
            std = pos.get("raw_std_m" if raw else "std_m") or ["", "", ""]
            veh = o.get("vehicle") if isinstance(o.get("vehicle"), dict) else None
            hv = (veh or {}).get("hv") or {}
            row = [o.get("frame"), o.get("t"), o.get("file", ""), p.get("x"), p.get("y"), p.get("z"),
                   pos.get("method"), pos.get("n_leds"), *std[:3], pos.get("yaw_deg"), pos.get("pitch_deg"),
                   pos.get("roll_deg"), o.get("no_fix"), hv.get("x"), hv.get("y"), hv.get("heading_deg"),
                   hv.get("speed_mps"), *_fv_cells(veh)]
        w.writerow(["" if v is None else v for v in row])
    return buf.getvalue()


def parse_origin(text: str | None) -> tuple[float, float]:
    """'LAT,LON' degrees -> (lat, lon); InputError on anything else."""
    if text is None:
        raise InputError("geojson needs --origin LAT,LON: where the map's (0, 0) lies on the Earth "
                         "(degrees; the map's x is taken as east, y as north)")
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--origin must look like 48.8584,2.2945 (latitude,longitude in degrees), not {text!r}") \
            from None
    if not (math.isfinite(lat) and math.isfinite(lon) and -90 < lat < 90 and -180 <= lon <= 180):
        raise InputError(f"--origin {text!r}: latitude must be within -90..90 and longitude -180..180 degrees")
    return lat, lon


def local_to_wgs84(x_east_m: float, y_north_m: float, origin: tuple[float, float]) -> tuple[float, float]:
    """(longitude, latitude) degrees of a point x m east and y m north of `origin` (lat, lon):
    the WGS 84 meridian and prime-vertical radii of curvature at the origin."""
    lat0 = math.radians(origin[0])
    s2 = math.sin(lat0) ** 2
    n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * s2)               # prime vertical
    m = WGS84_A_M * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * s2) ** 1.5  # meridian
    lat = origin[0] + math.degrees(y_north_m / m)
    lon = origin[1] + math.degrees(x_east_m / (n * math.cos(lat0)))
    return round(lon, DEG_DECIMALS), round(lat, DEG_DECIMALS)


def to_geojson(lines: list[dict], origin: tuple[float, float], *, raw: bool = False) -> dict:
    feats, track = [], []
    for o, (x, y, z), _ in poses(lines, raw=raw):
        lonlat = local_to_wgs84(float(x), float(y), origin)
        track.append(list(lonlat))
        props = {"frame": o.get("frame"), "t": o.get("t"), "z_m": z}
        if o.get("file"):
            props["file"] = o["file"]
        pos = o.get("position")
        if isinstance(pos, dict) and pos.get("method"):
            props["method"] = pos["method"]
        feats.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": list(lonlat)},
                      "properties": props})
    if len(track) >= 2:
        feats.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": track},
                      "properties": {"name": "track"}})
    return {"type": "FeatureCollection", "features": feats}
