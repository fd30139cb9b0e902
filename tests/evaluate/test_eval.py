"""`occloc eval`: metrics against hand-built run/truth files with known errors, the CLI, and
the real bundled walk."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.core.errors import InputError
from receiver.evaluate.metrics import evaluate, match_leds
from receiver.io.truth import load_run, load_truth
from receiver.evaluate.plots import FIG_DPI, PANEL_SIZE_IN, plot_eval

ROOT = Path(__file__).resolve().parents[2]
WALK = ROOT / "recordings" / "indoor-walk"


def _led(id_, cx, cy, d, visible=True, **kw):
    return {"id": id_, "cx": cx, "cy": cy, "distance_m": d, "visible": visible, **kw}


def _cam(x, y, z):
    return {"x": x, "y": y, "z": z, "yaw": 0.0, "pitch": 90.0, "roll": 0.0}


TRUTH = [
    {"frame": 0, "t": 0.0, "camera": _cam(0.0, 0.0, 1.0), "leds": [
        _led(1, 100.0, 100.0, 2.0),
        _led(2, 200.0, 100.0, 4.0),
        _led(3, 300.0, 100.0, 3.0, visible=False),  # clipped: not a match target
        # S2-PSK pair: its two emitters are the targets, the pair centre is not.
        _led(9, 520.0, 500.0, 10.0, mode="s2psk", emitters=[
            {"cx": 500.0, "cy": 500.0, "visible": True}, {"cx": 540.0, "cy": 500.0, "visible": True}]),
    ]},
    {"frame": 1, "t": 0.1, "camera": _cam(1.0, 0.0, 1.0), "leds": [_led(1, 100.0, 100.0, 2.0)]},
    {"frame": 2, "t": 0.2, "camera": _cam(2.0, 0.0, 1.0), "leds": []},
    {"frame": 3, "t": 0.3, "camera": _cam(3.0, 0.0, 1.0), "leds": []},  # not in the run: fine
]


def _rl(id_, cx, cy, area=None, d=None, est=None):
    out = {"track": 0, "id": id_, "mode": "ook", "cx": cx, "cy": cy, "area_px": area, "distance_m": d}
    if est:
        out["distance_estimator"] = est
    return out


RUN = [
    {"frame": 0, "t": 0.0, "latency_ms": 10.0, "vehicle": None, "leds": [
        _rl(1, 101.0, 100.0, area=500.0, d=2.02, est="eq18"),    # right, 1 % distance error
        _rl(7, 205.0, 100.0, area=2000.0, d=4.2, est="eq18"),    # wrong ID (truth 2), 5 %
        _rl(3, 300.0, 100.0, area=900.0, d=3.0),                 # truth LED hidden: unmatched
        _rl(9, 540.0, 501.0, area=100.0, d=9.0, est="oblique"),  # right (emitter B), 10 %
        _rl(None, 700.0, 700.0)],                                # nothing there: unmatched
     "position": {"x": 0.03, "y": 0.04, "z": 1.0, "method": "m", "n_leds": 3,
                  "raw": {"x": 0.0, "y": 0.0, "z": 1.1}}},
    {"frame": 1, "t": 0.1, "latency_ms": 20.0, "vehicle": None, "leds": [
        _rl(None, 100.0, 103.0),                     # loses truth LED 1 to the closer blob
        _rl(1, 100.0, 101.0),                        # right, no distance
        _rl(1, 100.0, 116.0)],                       # 16 px: outside the 15 px gate
     "position": None},
    {"frame": 2, "t": 0.2, "latency_ms": 30.0, "vehicle": None, "leds": [],
     "position": {"x": 2.0, "y": 0.0, "z": 1.2, "method": "m", "n_leds": 3}},
]


def _write(path: Path, objs) -> Path:
    path.write_text("".join(json.dumps(o) + "\n" for o in objs))
    return path


@pytest.fixture
def files(tmp_path):
    return _write(tmp_path / "run.jsonl", RUN), _write(tmp_path / "truth.jsonl", TRUTH)


EXPECTED = {
    "frames": 3, "frames_with_position": 2, "gate_px": 15.0,
    "led_frames": 8, "visible_truth_led_frames": 5, "matched_led_frames": 4, "unmatched_led_frames": 4,
    "ids_correct": 3, "wrong_ids": 1, "undecoded": 0, "id_rate": 0.75,
}


def _metrics(run_path, truth_path, **kw):
    truth = load_truth(str(truth_path))
    return evaluate(load_run(str(run_path), truth), truth, **kw)


def test_metrics_on_known_errors(files):
    m, series = _metrics(*files)
    assert {k: m[k] for k in EXPECTED} == EXPECTED
    de = m["distance_rel_error"]
    assert de["n"] == 3
    assert de["p50"] == pytest.approx(0.05)
    assert de["p95"] == pytest.approx(0.05 + 0.9 * 0.05)  # linear interpolation over [.01 .05 .1]
    bins = {b["area_px"]: (b["n"], b["p50"]) for b in de["by_area_px"]}
    assert bins.keys() == {"<400", "400-1600", "1600-6400", ">=6400"}
    assert bins["<400"] == (1, pytest.approx(0.1))
    assert bins["400-1600"] == (1, pytest.approx(0.01))
    assert bins["1600-6400"] == (1, pytest.approx(0.05))
    assert bins[">=6400"] == (0, None)
    by_est = {k: (v["n"], v["p50"]) for k, v in de["by_estimator"].items()}
    assert by_est == {"eq18": (2, pytest.approx(0.03)), "oblique": (1, pytest.approx(0.1))}
    pf, pr = m["position_error_m"]["filtered"], m["position_error_m"]["raw"]
    assert pf["n"] == 2 and pf["p50"] == pytest.approx(0.125) and pf["p95"] == pytest.approx(0.1925)
    assert pr["n"] == 1 and pr["p50"] == pytest.approx(0.1)
    assert m["latency_ms"] == {"n": 3, "p50": pytest.approx(20.0), "p99": pytest.approx(29.8)}
    np.testing.assert_allclose(series["filtered_err_m"], [0.05, np.nan, 0.2])
    np.testing.assert_allclose(series["t_s"], [0.0, 0.1, 0.2])


def test_gate_is_a_parameter(files):
    # every matched blob in the fixture is 1 px off except the wrong-ID one (5 px)
    m, _ = _metrics(*files, gate_px=3.0)
    assert (m["matched_led_frames"], m["ids_correct"], m["wrong_ids"], m["id_rate"]) == (3, 3, 0, 1.0)
    m, _ = _metrics(*files, gate_px=0.5)
    assert m["matched_led_frames"] == 0 and m["id_rate"] is None
    assert m["distance_rel_error"]["n"] == 0 and m["distance_rel_error"]["p50"] is None


def test_match_is_one_to_one_and_gated():
    run = np.array([[0.0, 3.0], [0.0, 1.0], [50.0, 0.0], [0.0, 20.0]])
    truth = np.array([[0.0, 0.0], [50.0, 14.0]])
    assert match_leds(run, truth, gate_px=15.0) == [None, 0, 1, None]
    assert match_leds(run, truth, gate_px=2.0) == [None, 0, None, None]
    assert match_leds(run[:0], truth) == [] and match_leds(run, truth[:0]) == [None] * 4


@pytest.mark.parametrize("mutate, message", [
    (lambda run, truth: run.write_text("{not json\n"), "run.jsonl:1: malformed JSON"),
    (lambda run, truth: run.write_text(""), "has no frames"),
    (lambda run, truth: run.write_text('[1, 2]\n'), "expected a JSON object"),
    (lambda run, truth: _write(run, [dict(RUN[0], frame=7)]), "frame 7 is not in the truth"),
    (lambda run, truth: _write(run, [RUN[0], RUN[0]]), "duplicate frame 0"),
    (lambda run, truth: _write(run, [dict(RUN[2], position={"x": 1, "y": "a", "z": 0})]), "position.y"),
    (lambda run, truth: _write(run, [dict(RUN[2], leds=[{"cx": 1}])]), "leds[0].cy"),
    (lambda run, truth: _write(truth, [{"frame": 0, "leds": []}]), "camera"),
    (lambda run, truth: truth.unlink(), "cannot read truth file"),
])
def test_bad_input_is_one_line_input_error(files, mutate, message):
    run, truth = files
    mutate(run, truth)
    with pytest.raises(InputError) as e:
        _metrics(run, truth)
    assert message in str(e.value) and "\n" not in str(e.value)


def _occloc(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "receiver.cli", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def test_cli_json_table_and_png(files, tmp_path):
    run, truth = files
    png = tmp_path / "out.png"
    p = _occloc("eval", run, "--truth", truth, "--plot", png, "--json")
    assert p.returncode == 0, p.stderr
    m = json.loads(p.stdout)
    assert {k: m[k] for k in EXPECTED} == EXPECTED
    img = cv2.imread(str(png))
    assert img is not None
    # three panels (distances exist) side by side
    assert img.shape[1] == round(3 * PANEL_SIZE_IN[0] * FIG_DPI)
    p = _occloc("eval", run, "--truth", truth)
    assert p.returncode == 0
    assert "ID rate" in p.stdout and "75.00 % (3/4)" in p.stdout and "wrong IDs            1" in p.stdout


def test_cli_bad_file_exits_2_with_one_line(files, tmp_path):
    run, truth = files
    run.write_text('{"frame": 0, "leds": [}\n')
    p = _occloc("eval", run, "--truth", truth)
    assert p.returncode == 2 and p.stdout == ""
    err = p.stderr.strip()
    assert err.startswith("occloc: ") and "\n" not in err and "Traceback" not in err


def test_plot_without_distances_has_two_panels(files, tmp_path):
    m, series = _metrics(*files)
    series = dict(series, dist_area_px=np.zeros(0), dist_rel_err=np.zeros(0))
    png = tmp_path / "two.png"
    plot_eval(series, str(png))
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] == round(2 * PANEL_SIZE_IN[0] * FIG_DPI)


def test_real_walk_first_frames(tmp_path):
    out = tmp_path / "run.jsonl"
    p = _occloc("run", WALK, "--out", out, "--max-frames", 10, timeout=120)
    assert p.returncode == 0, p.stderr
    p = _occloc("eval", out, "--truth", WALK / "truth.jsonl", "--json")
    assert p.returncode == 0, p.stderr
    m = json.loads(p.stdout)
    assert m["frames"] == 10 and m["matched_led_frames"] >= 30
    assert m["id_rate"] == 1.0 and m["wrong_ids"] == 0
