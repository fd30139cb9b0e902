"""`occloc run --settings FILE` naming a field that is an internal constant (not a setting) stops
with one line naming the record and the field, exit 2, and writes no output."""

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from receiver.pipeline import ReceiverSettings

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.parametrize("recording, section, record, key, value", [
    ("indoor-static", "ook", "OokSettings", "align_min", 0.7),
    ("vehicle", "pair", "PairSettings", "flux_floor", 2.0),
])
def test_a_settings_file_naming_an_internal_constant_is_one_line(tmp_path, recording, section, record, key, value):
    s = {"receiver": {section: dataclasses.asdict(getattr(ReceiverSettings(), section))}}
    s["receiver"][section][key] = value
    path = tmp_path / "s.json"
    path.write_text(json.dumps(s))
    out = tmp_path / "out.jsonl"
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "run", os.path.join(ROOT, "recordings", recording),
                        "--max-frames", "2", "--settings", str(path), "--out", str(out)], cwd=ROOT,
                       stdin=subprocess.DEVNULL, capture_output=True, timeout=300, env=dict(os.environ, PYTHONPATH=ROOT))
    err = p.stderr.decode()
    assert p.returncode == 2 and "Traceback" not in err, err
    assert err.strip() == f"occloc: {path}: receiver.{section}: {record} has no setting '{key}'", err
    assert not out.exists()
