"""Guards of what matters: pipeline-level tests through the public entry points only
(`Receiver(camera, led_map)` with its defaults, `occloc run`, `occloc eval --json`), each failing
when the property it names is lost.

- The OOK frame clock (receiver.decode.frameclock): on recordings/indoor-static it lifts the
  right LED-frames after a track's 3rd frame to 103 of 216 (68 without it); a frame clock that
  stops placing frames brings the count back towards 68 and the test fails.
- The measured ID results are regression thresholds: indoor-static >= 103/216 and
  vehicle >= 1840/4634 right LED-frames after a track's 3rd frame, 0 wrong (scored by
  tests/pipeline/test_recordings.py's `_score`, the acceptance scorer); indoor-static's distance error
  median <= 1.0 % (`occloc eval --json`: `distance_rel_error.p50`; every decoded LED of that
  recording is over 400 px, so the overall median is the "LEDs > 400 px" figure)."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from receiver.cli import main as cli
from tests.pipeline.test_recordings import RECORDINGS, _score, score_resolvable

# Measured: right LED-frames after a track's 3rd frame / all of them.
STATIC_RIGHT_AFTER3, STATIC_TOTAL_AFTER3 = 103, 216
STATIC_RIGHT_WITHOUT_FRAME_CLOCK = 68
# vehicle: every live S2-PSK pair reports both emitters every frame (receiver.vision.pairing
# `Pairer.emitters`), dark ones too, so there are more LED-frames than blobs; not one that has had
# no blob of its own for `jumper_unseen_frames` (hidden).
VEHICLE_RIGHT_AFTER3, VEHICLE_TOTAL_AFTER3 = 1838, 4632
# `occloc eval`'s S2-PSK resolvable ID rate on recordings/vehicle (right / qualifying light-frames).
VEHICLE_RESOLVABLE = {"SL": (652, 658), "FV": (156, 156)}
STATIC_DISTANCE_MEDIAN_MAX = 0.010     # measured by occloc eval: 0.79 %


@pytest.fixture(scope="module")
def static():
    return _score("indoor-static")


def test_frame_clock_lifts_indoor_static(static):
    """Small lights whose successive frames barely overlap are assembled by the frame clock:
    without it (68 right) the track-after-3rd-frame count is far below 103."""
    assert static["total_after3"] == STATIC_TOTAL_AFTER3, static
    assert static["right_after3"] > STATIC_RIGHT_WITHOUT_FRAME_CLOCK + 20, (
        f"{static['right_after3']}/{static['total_after3']} right after a track's 3rd frame: the "
        f"OOK frame clock places no frames (measured: {STATIC_RIGHT_WITHOUT_FRAME_CLOCK} without it, "
        f"{STATIC_RIGHT_AFTER3} with it)")


def test_indoor_static_ids_no_worse_than_measured(static):
    assert static["wrong"] == 0, static
    assert static["right_after3"] >= STATIC_RIGHT_AFTER3, (
        f"indoor-static: {static['right_after3']}/{static['total_after3']} right LED-frames after a "
        f"track's 3rd frame, measured {STATIC_RIGHT_AFTER3}/{STATIC_TOTAL_AFTER3}")


def test_vehicle_ids_no_worse_than_measured():
    s = _score("vehicle")
    assert s["wrong"] == 0, s
    assert s["total_after3"] == VEHICLE_TOTAL_AFTER3, s
    assert s["right_after3"] >= VEHICLE_RIGHT_AFTER3, (
        f"vehicle: {s['right_after3']}/{s['total_after3']} right LED-frames after a track's 3rd "
        f"frame, measured {VEHICLE_RIGHT_AFTER3}/{VEHICLE_TOTAL_AFTER3}")


def test_vehicle_resolvable_id_rate_no_worse_than_measured():
    r = score_resolvable(RECORDINGS / "vehicle")
    assert r["wrong_ids"] == 0, r
    for kind, (right, qualifying) in VEHICLE_RESOLVABLE.items():
        assert r[kind]["qualifying"] == qualifying, r
        assert r[kind]["right"] >= right, (kind, r[kind])


def _run_eval(name: str, tmp_path) -> dict:
    folder = RECORDINGS / name
    out = tmp_path / "run.jsonl"
    with contextlib.redirect_stderr(io.StringIO()):
        assert cli(["run", str(folder), "--out", str(out)]) == 0
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli(["eval", str(out), "--truth", str(folder / "truth.jsonl"), "--json"]) == 0
    return json.loads(buf.getvalue())


def test_indoor_static_distance_error_median(tmp_path):
    m = _run_eval("indoor-static", tmp_path)
    d = m["distance_rel_error"]
    small = [b for b in d["by_area_px"] if b["area_px"] == "<400"]
    assert all(b["n"] == 0 for b in small), small       # the median below is over LEDs > 400 px
    assert d["n"] >= 100, d
    assert d["p50"] <= STATIC_DISTANCE_MEDIAN_MAX, (
        f"indoor-static distance error median {100 * d['p50']:.2f} % > "
        f"{100 * STATIC_DISTANCE_MEDIAN_MAX:.1f} % (measured: 0.79 %)")
    assert m["wrong_ids"] == 0
