"""The S2-PSK resolvable ID rate (receiver.evaluate.metrics.s2psk_resolvable, `occloc eval`):
hand-built truth and run lines with known answers."""

from __future__ import annotations

import contextlib
import io
import json

from receiver.cli import main as cli
from receiver.evaluate.metrics import s2psk_qualifying, s2psk_resolvable
from receiver.io.truth import run_frame, truth_frame

FPS = 30.0


def _light(id_, cx, cy, *, sep=8.0, area=2.0, visible=(True, True), occluded=(0.0, 0.0)):
    ems = [{"cx": cx - sep / 2, "cy": cy, "area_px": area, "visible": visible[0], "occluded_frac": occluded[0]},
           {"cx": cx + sep / 2, "cy": cy, "area_px": area, "visible": visible[1], "occluded_frac": occluded[1]}]
    return {"id": id_, "cx": cx, "cy": cy, "distance_m": 80.0, "visible": all(visible), "area_px": area,
            "mode": "s2psk", "emitters": ems}


def _truth(n, lights_of):
    """{frame: record} of n frames at 30 fps; lights_of(k) -> truth LED dicts of frame k."""
    cam = {"x": 0.0, "y": 0.0, "z": 1.2, "yaw": 0.0, "pitch": 0.0, "roll": 0.0}
    return dict(truth_frame({"frame": k, "t": k / FPS, "camera": cam, "leds": lights_of(k)}) for k in range(n))


def _run(n, leds_of):
    return [run_frame({"frame": k, "t": k / FPS, "leds": leds_of(k)}) for k in range(n)]


def _led(cx, cy, id_, kind="SL"):
    return {"track": 0, "id": id_, "mode": "s2psk" if id_ is not None else None, "cx": cx, "cy": cy,
            "area_px": 2.0, "distance_m": None, **({"kind": kind} if id_ is not None else {})}


def test_a_light_qualifies_after_one_whole_packet_in_view():
    # 2.4 s = 72 frame intervals at 30 fps: frame 72 is the first whose preceding packet
    # (frames 0..72) was all in view
    truth = _truth(100, lambda k: [_light(5, 300.0, 200.0), _light(200, 600.0, 300.0, sep=3.0)])
    q = s2psk_qualifying(truth, list(range(100)))
    assert all(5 not in q[k] for k in range(72)) and all(5 in q[k] for k in range(72, 100))
    assert all(200 not in q[k] for k in range(100))  # emitters 3 px apart: never resolvable


def test_a_gap_restarts_the_packet():
    def lights(k):
        if k == 50:
            return [_light(5, 300.0, 200.0, area=0.6)]  # below 1 px^2 in one frame
        if k == 60:
            return [_light(5, 300.0, 200.0, visible=(True, False))]
        if k == 70:
            return [_light(5, 300.0, 200.0, occluded=(0.0, 0.3))]  # occluded counts as not visible
        if k == 80:
            return []  # not listed
        return [_light(5, 300.0, 200.0)]
    truth = _truth(200, lights)
    q = s2psk_qualifying(truth, list(range(200)))
    first = min(k for k in range(200) if 5 in q[k])
    assert first == 81 + 72


def test_right_qualifying_and_wrong_by_kind():
    def lights(k):
        return [_light(5, 300.0, 200.0), _light(0x90, 600.0, 300.0, sep=20.0)]

    def leds(k):
        out = []
        if k >= 80:  # the SL's left emitter carries its ID from frame 80 (72..79 undecoded)
            out.append(_led(296.0, 200.0, 5))
        out.append(_led(604.0, 200.0 + 100.0, None))  # nothing decoded on the FV's... (undecoded)
        if k == 90:
            out.append(_led(590.0, 300.0, 0x91, kind="FV"))  # a wrong ID on the FV's left emitter
        if k == 95:
            out.append(_led(10.0, 10.0, 77))  # decoded, unmatched, an ID of no light in view
        return out
    truth = _truth(100, lights)
    r = s2psk_resolvable(_run(100, leds), truth)
    assert r["SL"]["qualifying"] == 28 and r["SL"]["right"] == 20 and r["SL"]["right_any"] == 20
    assert r["FV"]["qualifying"] == 28 and r["FV"]["right"] == 0
    assert r["wrong_ids"] == 2
    # per light-frame: two emitters both right count once
    r2 = s2psk_resolvable(_run(100, lambda k: [_led(296.0, 200.0, 5), _led(304.0, 200.0, 5)]), truth)
    assert r2["SL"]["right"] == 28 and r2["SL"]["rate"] == 1.0 and r2["wrong_ids"] == 0


def test_occloc_eval_shows_the_metric(tmp_path):
    truth_lines = [{"frame": k, "t": k / FPS, "camera": {"x": 0, "y": 0, "z": 1, "yaw": 0, "pitch": 0, "roll": 0},
                    "leds": [_light(5, 300.0, 200.0)]} for k in range(80)]
    run_lines = [{"frame": k, "t": k / FPS, "leds": [_led(296.0, 200.0, 5 if k >= 76 else None)]}
                 for k in range(80)]
    (tmp_path / "truth.jsonl").write_text("".join(json.dumps(o) + "\n" for o in truth_lines))
    (tmp_path / "run.jsonl").write_text("".join(json.dumps(o) + "\n" for o in run_lines))
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli(["eval", str(tmp_path / "run.jsonl"), "--truth", str(tmp_path / "truth.jsonl"), "--json"]) == 0
    m = json.loads(buf.getvalue())["s2psk_resolvable"]
    assert (m["SL"]["right"], m["SL"]["qualifying"], m["wrong_ids"]) == (4, 8, 0)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli(["eval", str(tmp_path / "run.jsonl"), "--truth", str(tmp_path / "truth.jsonl")]) == 0
    assert "ID rate SL 50.00 % (4/8, 4 right in all); FV - (0/0, 0 right in all); wrong 0" in buf.getvalue()
