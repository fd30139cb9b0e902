"""The S2-PSK pairing's user settings (`PairSettings`) stay a dozen; its internal constants
(`PairTuning`) are no settings: a `--settings` file naming one fails with a one-line error."""

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from receiver.core.errors import InputError
from receiver.core.settings import settings_from_json
from receiver.pipeline import ReceiverSettings
from receiver.vision.pairing import PairTuning
from receiver.vision.settings import PairSettings

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
VEHICLE = os.path.join(ROOT, "recordings", "vehicle")


def test_a_dozen_user_settings_at_most():
    assert len(dataclasses.fields(PairSettings)) <= 12


@pytest.mark.parametrize("key", ["flux_floor", "report_coast_frames"])
def test_an_internal_constant_is_no_setting(key):
    assert hasattr(PairTuning(), key)
    with pytest.raises(InputError) as e:
        settings_from_json(PairSettings, {key: 1}, "s.json")
    assert str(e.value) == f"s.json: PairSettings has no setting {key!r}"


def test_a_settings_file_naming_an_internal_constant_is_one_line(tmp_path):
    s = {"receiver": {"pair": dataclasses.asdict(ReceiverSettings().pair)}}
    s["receiver"]["pair"]["flux_floor"] = 2.0
    path = tmp_path / "s.json"
    path.write_text(json.dumps(s))
    out = tmp_path / "out.jsonl"
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "run", VEHICLE, "--max-frames", "2", "--settings", str(path),
                        "--out", str(out)], cwd=ROOT, stdin=subprocess.DEVNULL, capture_output=True, timeout=300,
                       env=dict(os.environ, PYTHONPATH=ROOT))
    err = p.stderr.decode()
    assert p.returncode == 2 and "Traceback" not in err, err
    assert err.strip() == f"occloc: {path}: receiver.pair: PairSettings has no setting 'flux_floor'", err
    assert not out.exists()
