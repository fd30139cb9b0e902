"""`frame_line`: one strict JSON object per frame, the INTERFACES.md fields with their decimals,
numpy values converted, NaN and infinities as null (json itself is the oracle)."""

import json
import math

import numpy as np

from receiver.core.records import FrameResult, LedObservation
from receiver.io import output


def _led(track, **kw):
    args = dict(track=track, cx=612.3456, cy=np.float64(200.1049), area_px=1520.04, contour=np.zeros((0, 2)),
                border=False, id=42, mode="ook")
    args.update(kw)
    return LedObservation(**args)


def test_line_is_strict_json_with_the_contract_fields():
    res = FrameResult(12, 0.4000004, 1.23456, [_led(3, distance_m=2.98123456, distance_estimator="outline"),
                                               _led(4, id=None, mode=None, border=True)],
                      {"x": 2.01, "cov": np.eye(2) * 0.5, "n": np.int64(3)}, None, {"detect": 0.1234567})
    line = output.frame_line(res, profile=True)
    assert "\n" not in line and "NaN" not in line
    d = json.loads(line)
    assert d["frame"] == 12 and d["t"] == 0.4 and d["latency_ms"] == 1.235
    a, b = d["leds"]
    assert a == {"track": 3, "id": 42, "mode": "ook", "cx": 612.35, "cy": 200.1, "area_px": 1520.0,
                 "distance_m": 2.9812, "border": False, "distance_estimator": "outline"}
    assert b["id"] is None and b["distance_m"] is None and b["border"] is True and "distance_estimator" not in b
    assert d["position"] == {"x": 2.01, "cov": [[0.5, 0.0], [0.0, 0.5]], "n": 3}
    assert d["vehicle"] is None and d["stage_ms"] == {"detect": 0.123}
    assert "stage_ms" not in json.loads(output.frame_line(res))


def test_non_finite_values_become_null():
    res = FrameResult(0, 0.0, 1.0, [_led(1, cx=math.nan, distance_m=math.inf, distance_estimator="eq18")],
                      {"x": float("nan"), "m": np.array([1.0, np.inf])}, {"fv": [{"d": -math.inf}]})
    line = output.frame_line(res)
    d = json.loads(line, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert d["leds"][0]["cx"] is None and d["leds"][0]["distance_m"] is None
    assert d["position"] == {"x": None, "m": [1.0, None]} and d["vehicle"] == {"fv": [{"d": None}]}
