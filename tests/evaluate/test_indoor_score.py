"""tools.indoor_score: the figures of a hand-built run against its truth (IDs, wrong IDs,
positions only from one second on, position and distance errors), the scene list, the
markdown table and the command's refusal of an unknown scene."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from receiver.io.truth import load_run, load_truth
from tools.indoor_score import BY_NAME, SCENES, main, score, table


def _cam(x):
    return {"x": x, "y": 0.0, "z": 1.0, "yaw": 0.0, "pitch": 90.0, "roll": 0.0}


def _frames(n=40, fps=20.0):
    """Truth and run of `n` frames at `fps`: one visible LED (id 5, 2 m) per frame; the run
    decodes it from frame 2 on, with a wrong ID in frame 3, no ID in frames 0-1, distance
    2.02 m (1 %); positions in every frame but 25 and 30, off by 1 cm, except 10 cm in the
    first second (frames 0-19), which must not count."""
    truth, run = [], []
    for k in range(n):
        t = 0.5 + k / fps
        truth.append({"frame": k, "t": t, "camera": _cam(0.1 * k),
                      "leds": [{"id": 5, "cx": 300.0, "cy": 200.0, "distance_m": 2.0, "visible": True}]})
        led_id = None if k < 2 else (6 if k == 3 else 5)
        off = 0.10 if t < 1.5 else 0.01
        pos = None if k in (25, 30) else {"x": 0.1 * k + off, "y": 0.0, "z": 1.0, "method": "m", "n_leds": 1}
        run.append({"frame": k, "t": t, "latency_ms": 1.0, "vehicle": None, "position": pos,
                    "leds": [{"track": 0, "id": led_id, "mode": "ook", "cx": 301.0, "cy": 200.0,
                              "area_px": 900.0, "distance_m": 2.02}]})
    return truth, run


def _load(tmp_path: Path, truth, run):
    tp, rp = tmp_path / "truth.jsonl", tmp_path / "run.jsonl"
    tp.write_text("".join(json.dumps(o) + "\n" for o in truth))
    rp.write_text("".join(json.dumps(o) + "\n" for o in run))
    tr = load_truth(str(tp))
    return load_run(str(rp), tr), tr


def test_score_counts_ids_and_positions_after_the_first_second(tmp_path):
    run, truth = _load(tmp_path, *_frames())
    r = score(run, truth)
    assert r["matched"] == 40
    assert r["wrong_ids"] == 1
    assert r["ids_pct"] == pytest.approx(100.0 * 37 / 40)
    # frames 20..39 are from one second on; two of them have no position
    assert (r["position_frames"], r["scored_frames"]) == (18, 20)
    assert r["position_p50_cm"] == pytest.approx(1.0, abs=1e-6)
    assert r["position_p95_cm"] == pytest.approx(1.0, abs=1e-6)
    assert r["distance_p50_pct"] == pytest.approx(1.0, abs=1e-6)


def test_score_without_positions_or_ids(tmp_path):
    truth, run = _frames(n=30)
    for fr in run:
        fr["position"] = None
        fr["leds"] = []
    r = score(*_load(tmp_path, truth, run))
    assert r["ids_pct"] is None and r["matched"] == 0 and r["wrong_ids"] == 0
    assert r["position_frames"] == 0 and r["scored_frames"] == 10
    assert r["position_p50_cm"] is None and r["distance_p50_pct"] is None
    text = table([(SCENES[0], r)])
    assert "| - / - cm |" in text and "0/10" in text


def test_scenes_are_distinct_and_cover_the_issue_s_kinds():
    assert len(BY_NAME) == len(SCENES)
    rendered = [s for s in SCENES if s.synth is not None]
    specs = [json.dumps(s.spec(), sort_keys=True) for s in rendered]
    assert len(set(specs)) == len(specs)
    exposures = {s.sets.get("exposure_us") for s in rendered if s.sets.get("phone") == 1}
    assert {10.0, 30.0}.issubset(exposures) and any(e >= 50.0 for e in exposures)
    assert {s.sets.get("rate_hz") for s in rendered} >= {5000, 10000}


def test_unknown_scene_is_refused(capsys):
    with pytest.raises(SystemExit) as e:
        main(["no-such-scene"])
    assert e.value.code != 0
    assert "unknown scene no-such-scene" in capsys.readouterr().err


def test_a_missing_recording_is_one_line_and_exit_1(tmp_path, monkeypatch, capsys):
    import tools.indoor_score as tool

    monkeypatch.setattr(tool, "INDEPENDENT", tmp_path / "nowhere")
    assert main(["indep-grid-s31", "--work", str(tmp_path / "work")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("indoor_score: indep-grid-s31:") and "no such recording" in err[0]


def test_a_work_folder_it_did_not_render_is_never_deleted(tmp_path, capsys):
    """--work names the user's folder: a scene folder there without this tool's stamp is kept
    and refused in one line (exit 1), before anything is rendered; a file as --work likewise."""
    mine = tmp_path / "grid-ideal-10us"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    assert main(["grid-ideal-10us", "--work", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a render of tools.indoor_score" in err[0], err
    assert (mine / "notes.txt").read_text() == "mine"
    (tmp_path / "afile").write_text("x")
    assert main(["grid-ideal-10us", "--work", str(tmp_path / "afile")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("indoor_score: --work"), err
