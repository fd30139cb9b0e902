"""`occloc eval` in vehicle scenes: HV / FV metrics against hand-built run and truth lines with
known errors, FV matching by ID and by bearing, time to first distance, S2-PSK LED distances,
malformed vehicle objects, the vehicle plot and the CLI end to end."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from receiver.core.errors import InputError
from receiver.evaluate.metrics import evaluate, format_table, json_safe, match_fvs
from receiver.evaluate.plots import plot_eval
from receiver.io.truth import load_run, load_truth

ROOT = Path(__file__).resolve().parents[2]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _cam(x):
    return {"x": x, "y": 0.0, "z": 1.2, "yaw": 0.0, "pitch": 8.0, "roll": 0.0}


def _tfv(id_, d, angle, **kw):
    a = math.radians(angle)
    return {"id": id_, "x": d * math.cos(a), "y": d * math.sin(a), "distance_m": d, "angle_deg": angle,
            "world_x": 0.0, "world_y": 0.0, "yaw_deg": 0.0, **kw}


def _pair(id_, cx, cy, d, visible=True):
    """An S2-PSK truth entry with its two emitters 40 px apart."""
    return {"id": id_, "cx": cx + 20, "cy": cy, "distance_m": d, "visible": visible, "mode": "s2psk",
            "emitters": [{"cx": cx, "cy": cy, "visible": visible}, {"cx": cx + 40, "cy": cy, "visible": visible}]}


def _truth_frame(k):
    """Frame k (t = 0.1 k): HV at x = 10 k on the lane centre at 10 m/s; FVs
    A (ID 200, 20 m, 0 deg, always visible), B (ID 150, 40 m, -5 deg, no `visible` key: its taillight
    entry in `leds` is hidden in frame 0), C (ID 180, 80 m, +5 deg, visible from frame 2),
    D (ID 130, 60 m, 20 deg, visible from frame 3, never ranged by the run)."""
    leds = [_pair(5, 300.0, 300.0, 30.0), _pair(150, 600.0, 400.0, 40.0, visible=k >= 1)]
    return {"frame": k, "t": round(0.1 * k, 6), "camera": _cam(10.0 * k), "leds": leds,
            "vehicle": {"hv": {"x": 10.0 * k, "y": 0.0, "speed_mps": 10.0},
                        "fv": [_tfv(200, 20.0, 0.0, visible=True), _tfv(150, 40.0, -5.0),
                               _tfv(180, 80.0, 5.0, visible=k >= 2), _tfv(130, 60.0, 20.0, visible=k >= 3)]}}


TRUTH = [_truth_frame(k) for k in range(6)]  # frame 5 is not in the run: fine


def _rfv(id_, d, angle):
    return {"id": id_, "distance_m": d, "angle_deg": angle, "x": None, "y": None, "std_m": 0.5,
            "rel_speed_mps": -1.0, "ttc_s": None, "zone": "safe", "road_x": None, "road_y": None}


def _hv(k, dx, dy, raw=None, method=None):
    out = {"x": 10.0 * k + dx, "y": dy, "std_m": 0.3, "heading_deg": 0.0, "speed_mps": 10.5,
           "method": "kalman", "n_lights": 3, "raw": None}
    if raw is not None:
        out["raw"] = {"x": 10.0 * k + raw[0], "y": raw[1], "method": method}
    return out


def _rled(id_, cx, cy, d, kind, area=None, est=None):
    return {"track": 0, "id": id_, "mode": "s2psk", "cx": cx, "cy": cy, "area_px": area, "distance_m": d,
            "distance_estimator": est, "kind": kind}


RUN = [
    {"frame": 0, "t": 0.0, "latency_ms": 5.0, "position": None,
     "leds": [_rled(5, 301.0, 300.0, 31.5, "SL", est="baseline"),      # both emitters of SL 5: 5 %
              _rled(5, 339.0, 300.0, 31.5, "SL", est="baseline")],
     "vehicle": {"hv": _hv(0, 0.3, 0.4, raw=(1.2, 1.6), method="eq33"),  # 0.5 m (lat 0.4); raw 2.0
                 "hv_eq44": {"x": 0.0, "y": 1.0, "method": "eq44-47"},   # 1.0 m
                 "fv": [_rfv(None, 21.0, 0.5)]}},                        # A by bearing: 5 %, 0.5 deg
    {"frame": 1, "t": 0.1, "latency_ms": 5.0, "position": None,
     "leds": [_rled(150, 600.0, 401.0, 44.0, "FV", area=50.0, est="eq18")],  # FV taillight: 10 %
     "vehicle": {"hv": _hv(1, 0.0, -0.1, raw=(0.0, 0.2), method="eq33"),  # 0.1 (0.1); raw 0.2
                 "fv": [_rfv(200, 19.0, -0.2),                            # A by ID: 5 %, 0.2 deg
                        _rfv(None, 42.0, -4.0)]}},                        # B by bearing: 5 %, 1 deg
    {"frame": 2, "t": 0.2, "latency_ms": 5.0, "position": None, "leds": [],
     "vehicle": {"hv": None, "fv": []}},                                  # no HV fix this frame
    {"frame": 3, "t": 0.3, "latency_ms": 5.0, "position": None, "leds": [],
     "vehicle": {"hv": _hv(3, 0.6, 0.8, raw=(0.0, -3.0), method="eq44-47"),  # 1.0 (0.8); raw 3.0
                 "fv": [_rfv(180, 81.6, 5.3)]}},                          # C by ID: 2 %, 0.3 deg
    {"frame": 4, "t": 0.4, "latency_ms": 5.0, "position": None, "leds": [],
     "vehicle": {"hv": _hv(4, -0.3, 0.4),                                 # 0.5 (0.4); no raw
                 "fv": [_rfv(None, 30.0, 0.3),     # loses A to the closer bearing below
                        _rfv(None, 22.0, 0.1),     # A by bearing: 10 %, 0.1 deg
                        _rfv(None, 50.0, 10.0),    # nothing within 2 deg
                        _rfv(99, 50.0, 0.0)]}},    # an ID the truth lacks: unmatched
]


def _write(path: Path, objs) -> Path:
    path.write_text("".join(json.dumps(o) + "\n" for o in objs))
    return path


@pytest.fixture
def files(tmp_path):
    return _write(tmp_path / "run.jsonl", RUN), _write(tmp_path / "truth.jsonl", TRUTH)


def _metrics(run_path, truth_path, **kw):
    truth = load_truth(str(truth_path))
    return evaluate(load_run(str(run_path), truth), truth, **kw)


def test_hv_errors_filtered_raw_and_by_method(files):
    v = _metrics(*files)[0]["vehicle"]
    assert (v["frames_with_hv"], v["truth_frames_with_hv"]) == (4, 5)
    f, r = v["hv"]["filtered"], v["hv"]["raw"]
    assert f["frames"] == 4
    assert f["error_2d_m"]["p50"] == pytest.approx(0.5) and f["lateral_m"]["p50"] == pytest.approx(0.4)
    assert f["error_2d_m"]["p95"] == pytest.approx(0.5 + 0.85 * 0.5)  # over [.1 .5 .5 1.0]
    assert r["frames"] == 3 and r["error_2d_m"]["p50"] == pytest.approx(2.0)
    assert r["lateral_m"]["p50"] == pytest.approx(1.6)
    by = {k: (g["frames"], g["error_2d_m"]["p50"]) for k, g in v["hv_by_method"].items()}
    # raw fixes by their method, the hv_eq44 object joins its method's group
    assert by == {"eq33": (2, pytest.approx(1.1)), "eq44-47": (2, pytest.approx(2.0))}
    assert v["hv_extra"]["eq44"]["frames"] == 1
    assert v["hv_extra"]["eq44"]["error_2d_m"]["p50"] == pytest.approx(1.0)
    assert v["hv_speed_error_mps"]["p50"] == pytest.approx(0.5)
    assert v["hv_heading_error_deg"]["n"] == 0  # the truth gives no heading


def test_fv_matching_bands_bearing_and_time_to_first(files):
    v = _metrics(*files)[0]["vehicle"]
    assert (v["fv_run_entries"], v["fv_matched"], v["fv_matched_by_id"], v["fv_matched_by_bearing"],
            v["fv_unmatched"]) == (8, 5, 2, 3, 3)
    assert v["fv_visible_truth_frames"] == 5 + 4 + 3 + 2
    de = v["fv_distance_rel_error"]
    assert de["n"] == 5 and de["p50"] == pytest.approx(0.05)
    bands = {b["band_m"]: (b["n"], b["p50"], b["p95"]) for b in de["by_band_m"]}
    assert bands == {"0-25": (3, pytest.approx(0.05), pytest.approx(0.095)),
                     "25-50": (1, pytest.approx(0.05), pytest.approx(0.05)),
                     "50-100": (1, pytest.approx(0.02), pytest.approx(0.02)),
                     ">=100": (0, None, None)}
    be = v["fv_bearing_error_deg"]
    assert be["n"] == 5 and be["p50"] == pytest.approx(0.3)
    first = {f["fv"]: f for f in v["fv_time_to_first_distance"]}
    assert list(first) == ["130", "150", "180", "200"]
    assert (first["200"]["frames"], first["200"]["seconds"]) == (0, 0.0)
    # B has no `visible`: its taillight entry is hidden in frame 0, so it is first visible in frame 1
    assert (first["150"]["first_visible_frame"], first["150"]["frames"]) == (1, 0)
    assert first["180"]["first_visible_frame"] == 2 and first["180"]["first_distance_frame"] == 3
    assert first["180"]["frames"] == 1 and first["180"]["seconds"] == pytest.approx(0.1)
    assert first["130"]["first_visible_frame"] == 3 and first["130"]["frames"] is None


def test_match_fvs_id_first_then_bearing_one_to_one():
    truth = [{"id": 1, "angle_deg": 0.0, "visible": True}, {"id": 2, "angle_deg": 3.0, "visible": True},
             {"id": 3, "angle_deg": -3.0, "visible": False}]
    run = [{"id": None, "angle_deg": 0.1}, {"id": 1, "angle_deg": 10.0}, {"id": None, "angle_deg": 2.5},
           {"id": None, "angle_deg": 2.9}, {"id": None, "angle_deg": -3.0}, {"id": 3, "angle_deg": 50.0}]
    # entry 0 would take FV 1 by bearing, but entry 1 has its ID; 3 beats 2 to FV 2; FV 3 is hidden
    # from bearing matching yet taken by its ID
    assert match_fvs(run, truth, gate_deg=2.0) == [None, (0, "id"), None, (1, "bearing"), None, (2, "id")]
    assert match_fvs(run, truth, gate_deg=0.05)[3] is None
    assert match_fvs([{"id": None, "angle_deg": 179.0}], [{"id": None, "angle_deg": -179.5, "visible": True}],
                     gate_deg=2.0) == [(0, "bearing")]  # bearings wrap


def test_s2psk_led_distances_by_kind_and_estimator(files):
    de = _metrics(*files)[0]["distance_rel_error"]
    # each matched emitter of a pair is compared with its pair's truth distance
    assert de["n"] == 3
    assert {k: (s["n"], s["p50"]) for k, s in de["by_kind"].items()} == {
        "SL": (2, pytest.approx(0.05)), "FV": (1, pytest.approx(0.1))}
    assert {k: s["n"] for k, s in de["by_estimator"].items()} == {"baseline": 2, "eq18": 1}
    # only the sample with an area_px falls in an area bin
    assert sum(b["n"] for b in de["by_area_px"]) == 1


def test_no_vehicle_section_without_vehicle_objects(files, tmp_path):
    run, truth = files
    _write(run, [dict(fr, vehicle=None) for fr in RUN])
    m, series = _metrics(run, truth)
    assert m["vehicle"] is None and series["vehicle"] is None
    assert "HV frames" not in format_table(m) and "FV entries" not in format_table(m)
    run2 = _write(tmp_path / "novehicle.jsonl", [{k: v for k, v in fr.items() if k != "vehicle"} for fr in RUN])
    assert _metrics(run2, truth)[0]["vehicle"] is None
    # truth without vehicle keys: no vehicle metrics either
    _write(truth, [{k: v for k, v in fr.items() if k != "vehicle"} for fr in TRUTH])
    assert _metrics(*files)[0]["vehicle"] is None


def _line(k, **vehicle):
    return dict(RUN[k], vehicle=dict(RUN[k]["vehicle"], **vehicle))


@pytest.mark.parametrize("lines, message", [
    ([_line(0, hv=dict(RUN[0]["vehicle"]["hv"], x="a"))], "run.jsonl:1 vehicle.hv.x: expected a number"),
    ([RUN[0], _line(1, hv={"x": 1.0})], "run.jsonl:2 vehicle.hv.y"),
    ([_line(0, hv=dict(RUN[0]["vehicle"]["hv"], raw={"y": 0.0}))], "vehicle.hv.raw.x"),
    ([_line(0, hv=dict(RUN[0]["vehicle"]["hv"], method=3))], "vehicle.hv.method: expected a string"),
    ([_line(0, fv=[dict(_rfv(None, 1.0, 0.0), distance_m=float("nan"))])], "vehicle.fv[0].distance_m"),
    ([_line(0, fv=[dict(_rfv(None, 1.0, 0.0), id="7")])], "vehicle.fv[0].id: expected an integer"),
    ([_line(0, fv=[dict(_rfv(None, 1.0, 0.0), angle_deg=True)])], "vehicle.fv[0].angle_deg"),
    ([_line(0, fv={"id": 1})], "vehicle.fv: expected a list"),
    ([_line(0, hv_eq44={"x": "1", "y": 0.0})], "vehicle.hv_eq44.x"),
    ([dict(RUN[0], vehicle=[1, 2])], "run.jsonl:1 vehicle: expected an object"),
    ([dict(RUN[0], leds=[dict(RUN[0]["leds"][0], kind=5)])], "leds[0].kind"),
])
def test_malformed_run_vehicle_is_one_line_input_error(files, lines, message):
    run, truth = files
    _write(run, lines)  # json.dumps writes NaN as the bare token, which json.loads reads back as nan
    with pytest.raises(InputError) as e:
        _metrics(run, truth)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_malformed_truth_vehicle_is_one_line_input_error(files):
    run, truth = files
    bad = dict(TRUTH[0], vehicle={"hv": {"x": 0.0, "y": None}, "fv": []})
    _write(truth, [bad, *TRUTH[1:]])
    with pytest.raises(InputError) as e:
        _metrics(run, truth)
    assert "truth.jsonl:1 vehicle.hv.y" in str(e.value) and "\n" not in str(e.value)


def _png_ok(path: Path) -> bool:
    return path.is_file() and path.stat().st_size > 1000 and path.read_bytes()[:8] == PNG_SIGNATURE


def test_vehicle_plot_is_a_png(files, tmp_path):
    _, series = _metrics(*files)
    png = tmp_path / "vehicle.png"
    plot_eval(series, str(png))
    assert _png_ok(png)


def test_json_safe_replaces_nan():
    assert json_safe({"a": [float("nan"), np.float64(1.5), np.int64(2)], "b": math.inf}) == {"a": [None, 1.5, 2],
                                                                                             "b": None}


def _no_nan(token):
    raise AssertionError(f"{token} in JSON output")


def test_cli_end_to_end(files, tmp_path):
    run, truth = files
    png = tmp_path / "out.png"
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "eval", str(run), "--truth", str(truth),
                        "--json", "--plot", str(png)], check=False, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    m = json.loads(p.stdout, parse_constant=_no_nan)
    v = m["vehicle"]
    assert v["hv"]["filtered"]["error_2d_m"]["p50"] == pytest.approx(0.5)
    assert v["fv_distance_rel_error"]["by_band_m"][3]["p50"] is None
    assert _png_ok(png)
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "eval", str(run), "--truth", str(truth)],
                       check=False, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    rows = dict(line.split("  ", 1) for line in p.stdout.splitlines())
    rows = {k.strip(): v.strip() for k, v in rows.items()}
    assert rows["HV frames"] == "4 with a fix, 5 in truth"
    assert rows["HV filtered"] == "2D median 0.50 m  p95 0.93 m  lateral median 0.40 m  p95 0.74 m  (n=4)"
    assert rows["FV distance error"] == "median 5.000 %  p95 9.000 %  (n=5)"
    assert rows["FV 180 first distance"].startswith("1 frames (0.10 s)")
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "eval", str(run), "--truth", str(truth),
                        "--fv-gate-deg", "0"], check=False, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "fv-gate-deg" in p.stderr
