"""The decode stage's user settings are about a dozen in all, each named with its unit, and its
internal constants (`OokTuning`, the module constants of receiver.decode.s2psk / tone / policy /
frameclock and receiver.pipeline.CLOCK_REFS) are no settings: a `--settings` file naming one, or
a setting's name without its unit, fails with a one-line error."""

import dataclasses
import json

import pytest

from receiver.core.errors import InputError
from receiver.core.settings import settings_from_json
from receiver.decode.settings import OOK_TUNING, OokSettings, PolicySettings, S2pskSettings, ToneSettings
from receiver.pipeline import ReceiverSettings

RECORDS = (OokSettings, S2pskSettings, ToneSettings, PolicySettings)


def test_about_a_dozen_user_settings_in_the_stage():
    assert sum(len(dataclasses.fields(cls)) for cls in RECORDS) <= 14


def test_a_number_setting_names_its_unit():
    """A number's name ends in its unit (_s, _us, _frames, _chips, _steps, _per_frame) or is a
    margin in noise sds (_z); flags and choices carry none."""
    import typing
    units = ("_s", "_us", "_frames", "_chips", "_steps", "_per_frame", "_z")
    numbers = 0
    for cls in RECORDS:
        for name, tp in typing.get_type_hints(cls).items():
            if {int, float} & set(typing.get_args(tp) or (tp,)):
                numbers += 1
                assert name.endswith(units), (cls.__name__, name)
    assert numbers >= 8


def test_every_user_setting_is_documented():
    """Each field is named in its record's docstring (what it means, its unit and default)."""
    for cls in RECORDS:
        for f in dataclasses.fields(cls):
            assert f"{f.name} [" in cls.__doc__, (cls.__name__, f.name)


@pytest.mark.parametrize("cls, key", [(OokSettings, "align_min"), (OokSettings, "norm_chips"),
                                      (OokSettings, "trust_timed"), (OokSettings, "align_when_decoded"),
                                      (S2pskSettings, "sync_margin"), (S2pskSettings, "soft_position_dof"),
                                      (OokSettings, "verify_min"), (OokSettings, "pieces_min_z"),
                                      (OokSettings, "decay"),
                                      (S2pskSettings, "phase_every"), (S2pskSettings, "decoder"),
                                      (ToneSettings, "fmin_hz"), (ToneSettings, "spacing_hz"),
                                      (ToneSettings, "min_quality"), (ToneSettings, "memory"),
                                      (PolicySettings, "frame_clock"), (PolicySettings, "clock_refs"),
                                      (PolicySettings, "tone_confirm_frames"), (PolicySettings, "redecode_every"),
                                      (ReceiverSettings, "frame_clock"), (ReceiverSettings, "s2psk_inverted")])
def test_an_internal_constant_or_deleted_flag_is_no_setting(cls, key):
    with pytest.raises(InputError) as e:
        settings_from_json(cls, {key: 1}, "s.json")
    assert str(e.value) == f"s.json: {cls.__name__} has no setting {key!r}"


def test_the_tuning_record_holds_what_left_the_settings():
    assert OOK_TUNING.align_min == 0.7 and OOK_TUNING.verify_frames == 16
    assert OOK_TUNING.verify_min == 0.9 and OOK_TUNING.pieces_min_z == 3.0
    assert not set(f.name for f in dataclasses.fields(OOK_TUNING)) & set(f.name for f in dataclasses.fields(OokSettings))


@pytest.mark.parametrize("cls", [OokSettings, ToneSettings])
def test_a_decay_above_one_is_refused(cls):
    """A decay over 1 per frame would weigh old frames above new ones: one-line error."""
    assert settings_from_json(cls, {"decay_per_frame": 1.0}, "s.json").decay_per_frame == 1.0
    with pytest.raises(InputError) as e:
        settings_from_json(cls, {"decay_per_frame": 1.5}, "s.json")
    assert str(e.value) == "s.json.decay_per_frame: must be 0..1, not 1.5"
