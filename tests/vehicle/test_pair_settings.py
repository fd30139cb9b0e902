"""The S2-PSK pairing's user settings (`PairSettings`) stay a dozen; its internal constants
(`PairTuning`) are no settings: a `--settings` file naming one fails with a one-line error."""

import dataclasses
import json

import pytest

from receiver.core.errors import InputError
from receiver.core.settings import settings_from_json
from receiver.vision.pairing import PairTuning
from receiver.vision.settings import PairSettings


def test_a_dozen_user_settings_at_most():
    assert len(dataclasses.fields(PairSettings)) <= 12


@pytest.mark.parametrize("key", ["flux_floor", "report_coast_frames"])
def test_an_internal_constant_is_no_setting(key):
    assert hasattr(PairTuning(), key)
    with pytest.raises(InputError) as e:
        settings_from_json(PairSettings, {key: 1}, "s.json")
    assert str(e.value) == f"s.json: PairSettings has no setting {key!r}"
