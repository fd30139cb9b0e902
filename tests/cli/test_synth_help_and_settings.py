"""`occloc synth --help` names every scene and --set key with its unit; `occloc run --settings`
reads back what `--settings-out` wrote."""

from __future__ import annotations

import dataclasses
import inspect
import json
from pathlib import Path

import pytest

from receiver.cli import main as cli

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "recordings" / "indoor-static"


def test_synth_help_lists_every_scene_and_set_key_with_a_unit(capsys):
    from tools.synth.camera import make_camera
    from tools.synth.cli import unit_of
    from tools.synth.model import RenderParams
    from tools.synth.scenes import BUILDERS, SCENES

    with pytest.raises(SystemExit):
        cli(["synth", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    keys = set(inspect.signature(make_camera).parameters) | {f.name for f in dataclasses.fields(RenderParams)}
    for name in SCENES:
        assert f"scene {name}:" in text
        keys |= {k for k, p in inspect.signature(BUILDERS[name]).parameters.items() if p.kind is not p.VAR_KEYWORD} - {"rng", "cam"}
    for key in keys:
        assert unit_of(key), key
        assert f"{key}=" in text and f"[{unit_of(key)}]" in text, key
    assert "row_readout_us=15.0 [us]" in text and "speed0_kmh=40.0 [km/h]" in text


def _lines(path):
    return [{k: v for k, v in json.loads(l).items() if k != "latency_ms"} for l in path.read_text().splitlines()]


def test_run_reads_back_the_settings_it_wrote(tmp_path, capsys):
    s1, s2 = tmp_path / "s1.json", tmp_path / "s2.json"
    o1, o2 = tmp_path / "o1.jsonl", tmp_path / "o2.jsonl"
    assert cli(["run", str(STATIC), "--max-frames", "12", "--settings-out", str(s1), "--out", str(o1)]) == 0
    assert cli(["run", str(STATIC), "--max-frames", "12", "--settings", str(s1), "--settings-out", str(s2),
                "--out", str(o2)]) == 0
    assert json.loads(s1.read_text()) == json.loads(s2.read_text())
    assert _lines(o1) == _lines(o2)
    # a changed setting takes effect: the position filter off -> unfiltered positions
    obj = json.loads(s1.read_text())
    obj["locate"]["kalman"] = False
    s3 = tmp_path / "s3.json"
    s3.write_text(json.dumps(obj))
    assert cli(["run", str(STATIC), "--max-frames", "12", "--settings", str(s3), "--out", str(o2)]) == 0
    pos = [r["position"] for r in _lines(o2) if r["position"]]
    assert pos and all(p["filtered"] is False for p in pos)
    assert any(r["position"] and r["position"]["filtered"] for r in _lines(o1))


@pytest.mark.parametrize("text,msg", [('{"receiver": {"bogus": 1}}', "has no setting 'bogus'"),
                                      ('{"lights": {}}', "unknown stage 'lights'"),
                                      ('[1, 2]', "expected the JSON object"),
                                      ('{"locate": {"max_coast_s": "x"}}', "locate.max_coast_s: expected float"),
                                      ('{"receiver": {"detect": {"max_detect_px": -5}}}', "must not be negative"),
                                      ('{"receiver": {"detect": {"max_detect_px": 1e999}}}', "expected int"),
                                      ('{"locate": {"max_coast_s": NaN}}', "must be a finite number"),
                                      ('{"receiver": {"motion": {"history_frames": 0}}}',
                                       "history_frames must be at least 1"),
                                      ('{"receiver": {"motion": {"min_matches": 0}}}',
                                       "min_matches must be at least 1")])
def test_run_settings_errors_are_one_line(tmp_path, capsys, text, msg):
    f = tmp_path / "s.json"
    f.write_text(text)
    assert cli(["run", str(STATIC), "--settings", str(f), "--out", str(tmp_path / "o.jsonl")]) == 2
    err = capsys.readouterr().err
    assert msg in err and err.count("\n") == 1


@pytest.mark.parametrize("value", [0, 0.5, 1e-9])
def test_an_s2psk_history_shorter_than_a_packet_is_refused_before_any_work(value, tmp_path, capsys):
    """The S2-PSK decoder needs a whole packet of samples (2.4 s at the map's 200 Hz clock): a
    settings file with a shorter history is one line naming the file, not a traceback when the
    first pair is seen."""
    veh = ROOT / "recordings" / "vehicle"
    s = tmp_path / "s.json"
    s.write_text(json.dumps({"receiver": {"s2psk": {"history_s": value}}}))
    out = tmp_path / "run.jsonl"
    assert cli(["run", str(veh), "--max-frames", "40", "--settings", str(s), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"occloc: {s}: history_s must hold a whole packet (2.4 s)"), err
    assert not out.exists()
