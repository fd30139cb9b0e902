"""`frame_line` builds its text directly (receiver.io.output._fast_line): the same characters as
json.dumps of `frame_record`, for every kind of value a frame carries, and the json.dumps
path where a value is not one it formats."""

import json
import math

import numpy as np
import pytest

from receiver.core.records import FrameResult, LedObservation
from receiver.io import output
from receiver.io.files import dumps


def _reference(res, profile=False):
    return dumps(output.frame_record(res, profile=profile), separators=(",", ":"), default=output._jsonable)


def _value(rng):
    """Numbers of every magnitude and the awkward ones (halfway, zero, -0, tiny, huge, NaN)."""
    r = rng.random()
    if r < 0.05:
        return float(rng.choice([0.0, -0.0, 1e-4, -1e-4, 9.9999e-5, 1e9, 1e9 - 1e-3, 0.125, 2.675, 1e-7, 1e20,
                                 float("nan"), float("inf"), 5e-5, 0.00015]))
    mag = 10.0 ** rng.integers(-8, 11)
    v = float(rng.normal() * mag)
    if r < 0.15:
        v = round(v, int(rng.integers(0, 7))) + float(rng.choice([0.0, 5e-3, 5e-5, 5e-7]))  # near halfway
    return v


def _led(rng, i):
    dist = None if rng.random() < 0.3 else _value(rng)
    return LedObservation(track=i, cx=_value(rng), cy=np.float64(_value(rng)), area_px=_value(rng),
                          contour=np.zeros((0, 2)), border=bool(rng.integers(2)),
                          id=None if rng.random() < 0.3 else int(rng.integers(1 << 16)),
                          mode=rng.choice([None, "ook", "tone", "s2psk"]), distance_m=dist,
                          distance_estimator=None if dist is None else rng.choice(["outline", "eq18", None]),
                          freq_hz=None if rng.random() < 0.7 else round(_value(rng), 1),
                          kind=None if rng.random() < 0.8 else rng.choice(["SL", "FV"]))


def test_fast_line_equals_json_dumps():
    rng = np.random.default_rng(3)
    fast = 0
    for k in range(3000):
        leds = [_led(rng, i) for i in range(int(rng.integers(0, 6)))]
        pos = None if rng.random() < 0.4 else {"x": round(_value(rng), 5), "cov": np.eye(2) * 0.5,
                                               "method": "outline", "n": np.int64(3)}
        veh = None if rng.random() < 0.8 else {"hv": None, "v": [_value(rng)]}
        res = FrameResult(k, _value(rng), _value(rng), leds, pos, veh,
                          {"detect": _value(rng), "locate": 0.25})
        for profile in (False, True):
            line = output.frame_line(res, profile=profile)
            assert line == _reference(res, profile)
            json.loads(line)
            fast += output._fast_line(res, profile) is not None
    assert fast > 2000  # most lines took the direct path


@pytest.mark.parametrize("v", [0.005, 2.675, 1234.5678949999, 1e-4, 99999999.995, -0.0, 1.0, 1e8 + 0.125])
def test_number_tokens_are_reprs_of_round(v):
    for nd in range(7):
        assert output._num_tok(v, nd) == repr(round(v, nd))
    assert output._num_tok(math.nan, 2) == "null"


def test_odd_values_fall_back():
    led = LedObservation(track=np.int64(1), cx=1.0, cy=2.0, area_px=3.0, contour=np.zeros((0, 2)), mode="o\"k")
    res = FrameResult(0, 0.0, 1.0, [led], {"x": float("nan")})
    assert output._fast_line(res, False) is None
    assert output.frame_line(res) == _reference(res)
