"""The run summary reports the cars ahead (closest, lowest time to collision, zones) and the CSV
export carries each frame's worst zone."""

from __future__ import annotations

import csv
import io

from receiver.evaluate.export import to_csv
from receiver.io.output import RunSummary


class R:
    leds, position, latency_ms = [], None, 1.0

    def __init__(self, frame, fv):
        self.frame = frame
        self.vehicle = {"hv": None, "fv": fv}


FRAMES = [R(0, [{"id": 206, "distance_m": 20.0, "ttc_s": None, "zone": "safe"}]),
          R(1, [{"id": 206, "distance_m": 14.0, "ttc_s": 6.5, "zone": "min"},
                {"id": None, "distance_m": 40.0, "ttc_s": 3.0, "zone": "safe"}]),
          R(2, [{"id": 142, "distance_m": 9.0, "ttc_s": 1.5, "zone": "critical"}]),
          R(3, [])]


def test_summary_names_the_cars_ahead():
    s = RunSummary()
    for r in FRAMES:
        s.add(r)
    text = s.text()
    assert ("cars ahead (IDs 142, 206), closest 9.0 m (frame 2), lowest TTC 1.5 s (frame 2), "
            "frames by worst zone: safe 1, min 1, critical 1") in text


def test_no_cars_no_words():
    s = RunSummary()
    s.add(R(0, []))
    assert "cars ahead" not in s.text()


def test_csv_worst_zone_and_closest():
    lines = [{"frame": r.frame, "t": r.frame / 30, "position": None, "vehicle": r.vehicle} for r in FRAMES]
    rows = list(csv.DictReader(io.StringIO(to_csv(lines))))
    assert [r["fv_worst_zone"] for r in rows] == ["safe", "min", "critical", ""]
    assert rows[1]["fv_closest_id"] == "206" and rows[1]["fv_min_ttc_s"] == "3.0" and rows[3]["fv_count"] == "0"
