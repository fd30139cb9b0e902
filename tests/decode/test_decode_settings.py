"""The decode stage's user settings stay a dozen or so per record, and its internal constants
(`OokTuning`, the module constants of receiver.decode.s2psk / tone / frameclock and
receiver.pipeline.CLOCK_REFS) are no settings: a `--settings` file naming one fails with a
one-line error."""

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from receiver.core.errors import InputError
from receiver.core.settings import settings_from_json
from receiver.decode.settings import OOK_TUNING, OokSettings, PolicySettings, S2pskSettings, ToneSettings
from receiver.pipeline import ReceiverSettings

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")
RECORDS = (OokSettings, S2pskSettings, ToneSettings, PolicySettings)


@pytest.mark.parametrize("cls", RECORDS)
def test_a_dozen_user_settings_at_most(cls):
    assert len(dataclasses.fields(cls)) <= 12


def test_every_user_setting_is_documented():
    """Each field is named in its record's docstring (what it means, its unit and default)."""
    for cls in RECORDS:
        for f in dataclasses.fields(cls):
            assert f"{f.name} [" in cls.__doc__, (cls.__name__, f.name)


@pytest.mark.parametrize("cls, key", [(OokSettings, "align_min"), (OokSettings, "norm_chips"),
                                      (OokSettings, "trust_timed"), (OokSettings, "align_when_decoded"),
                                      (S2pskSettings, "sync_margin"), (S2pskSettings, "soft_position_dof"),
                                      (S2pskSettings, "phase_every"),
                                      (ToneSettings, "fmin_hz"), (PolicySettings, "frame_clock"),
                                      (PolicySettings, "clock_refs"), (ReceiverSettings, "frame_clock"),
                                      (ReceiverSettings, "s2psk_inverted")])
def test_an_internal_constant_or_deleted_flag_is_no_setting(cls, key):
    with pytest.raises(InputError) as e:
        settings_from_json(cls, {key: 1}, "s.json")
    assert str(e.value) == f"s.json: {cls.__name__} has no setting {key!r}"


def test_the_tuning_record_holds_what_left_the_settings():
    assert OOK_TUNING.align_min == 0.7 and OOK_TUNING.verify_frames == 16
    assert not set(f.name for f in dataclasses.fields(OOK_TUNING)) & set(f.name for f in dataclasses.fields(OokSettings))


def test_a_settings_file_naming_an_internal_constant_is_one_line(tmp_path):
    s = {"receiver": {"ook": dataclasses.asdict(ReceiverSettings().ook)}}
    s["receiver"]["ook"]["align_min"] = 0.7
    path = tmp_path / "s.json"
    path.write_text(json.dumps(s))
    out = tmp_path / "out.jsonl"
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "run", STATIC, "--max-frames", "2", "--settings", str(path),
                        "--out", str(out)], cwd=ROOT, stdin=subprocess.DEVNULL, capture_output=True, timeout=300,
                       env=dict(os.environ, PYTHONPATH=ROOT))
    err = p.stderr.decode()
    assert p.returncode == 2 and "Traceback" not in err, err
    assert err.strip() == f"occloc: {path}: receiver.ook: OokSettings has no setting 'align_min'", err
    assert not out.exists()
