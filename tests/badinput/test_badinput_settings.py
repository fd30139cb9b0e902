"""`occloc run --settings FILE`: every number is range-checked when the file is read (one helper,
receiver.core.settings.settings_from_json): finite, at most MAX_SETTING_MAGNITUDE in size, not
negative where the default is not, and within a field's `knob` bounds where a zero or a huge
value breaks the stage (a division by zero, a C integer overflow, a morphology kernel of 10^9
rows, an empty downsampled image)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from receiver.core.errors import InputError
from receiver.core.settings import settings_from_json, settings_json
from receiver.decode.settings import OokSettings, OokTuning
from receiver.locate.settings import PositionerSettings, VehicleSettings
from receiver.pipeline import ReceiverSettings
from receiver.vision.settings import DetectSettings, PairSettings, TrackSettings

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")


@pytest.mark.parametrize("cls", [ReceiverSettings, PositionerSettings, VehicleSettings])
def test_defaults_pass_their_own_checks(cls):
    assert settings_from_json(cls, settings_json(cls())) == cls()


@pytest.mark.parametrize("cls, key, value, words", [
    (DetectSettings, "max_detect_px", 0, "must be at least 10000, not 0"),
    (DetectSettings, "stripe_gap_px", 10 ** 9, "must be 0..32768"),
    (DetectSettings, "stripe_check_rows", 10 ** 9, "must be 0..32768"),
    (OokSettings, "pieces_jitter_us", 1e6, "must be 0..100000, not 1000000.0"),
    (PairSettings, "max_area_ratio", 0.0, "must be at least 1"),
    (TrackSettings, "max_missed", -1, "must not be negative"),
    (PairSettings, "shake_radius_px", 1e9, "must be 0..32768"),
    (PositionerSettings, "accel_psd", 1e300, "at most 1e+09 in size"),
    (PositionerSettings, "edge_sigma_px", 1e300, "at most 1e+09 in size"),
    (TrackSettings, "gate_px", 1e9, "must be 0..32768"),
    (PositionerSettings, "pixel_sigma_px", 0.0, "must be over 0"),
    (PositionerSettings, "tilt_sigma_deg", 0.0, "must be over 0"),
    (PositionerSettings, "tilt_sigma_deg", 1e9, "must be"),
])
def test_out_of_range_setting_is_one_line(cls, key, value, words):
    with pytest.raises(InputError) as e:
        settings_from_json(cls, {key: value}, "s.json")
    assert str(e.value).startswith(f"s.json.{key}: ") and words in str(e.value), str(e.value)


@pytest.mark.parametrize("cls, key, value", [(DetectSettings, "stripe_check_rows", 0), (DetectSettings, "max_detect_px", 10000),
                                             (DetectSettings, "stripe_gap_px", 0), (OokSettings, "pieces_jitter_us", 1e5),
                                             (PairSettings, "max_area_ratio", 1.0),
                                             (PositionerSettings, "pixel_sigma_px", 1e-3),
                                             (PositionerSettings, "tilt_sigma_deg", 180.0)])
def test_edge_of_the_range_is_accepted(cls, key, value):
    assert getattr(settings_from_json(cls, {key: value}), key) == value


def test_run_with_a_zero_max_detect_px_settings_file(tmp_path):
    """A ZeroDivisionError traceback in the detector before the check."""
    s = {"receiver": {"detect": dataclasses.asdict(DetectSettings(max_detect_px=1_200_000))}}
    s["receiver"]["detect"]["max_detect_px"] = 0
    path = tmp_path / "s.json"
    path.write_text(json.dumps(s))
    p = subprocess.run([sys.executable, "-m", "receiver.cli", "run", STATIC, "--max-frames", "2", "--settings", str(path)],
                       cwd=ROOT, stdin=subprocess.DEVNULL, capture_output=True, timeout=300,
                       env=dict(os.environ, PYTHONPATH=ROOT))
    err = p.stderr.decode()
    assert p.returncode == 2 and "Traceback" not in err, err
    assert err.strip() == f"occloc: {path}: receiver.detect.max_detect_px: must be at least 10000, not 0", err
    assert p.stdout == b""


@pytest.mark.parametrize("kw", [{"confirm_misfit_wrong": 0.0}, {"confirm_misfit_right": 1.0},
                                {"confirm_misfit_right": 0.5, "confirm_misfit_wrong": 0.4}])
def test_confirmation_misfit_shares_out_of_order_are_refused(kw):
    """The confirmation's likelihood ratio takes log(right / wrong) and log((1 - right) / (1 - wrong)):
    shares of 0 or 1, or a right share not below the wrong one, are refused when the internal
    constants are made (they are no settings: a settings file cannot name them)."""
    with pytest.raises(ValueError, match="confirm_misfit_right"):
        OokTuning(**kw)
    with pytest.raises(InputError) as e:
        settings_from_json(OokSettings, kw, "s.json")
    assert str(e.value).startswith("s.json: OokSettings has no setting 'confirm_misfit_"), str(e.value)
