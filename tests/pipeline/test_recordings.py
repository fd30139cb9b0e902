"""Acceptance on the bundled recordings: the receiver reads the encoded video exactly as
`occloc run` does; truth.jsonl is read only here, by the test, to score what came out."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.pipeline import Receiver
from receiver.io.sources import open_source

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"
GATE_PX = 15.0


def _score(name: str, max_frames: int | None = None) -> dict:
    folder = RECORDINGS / name
    truth = [json.loads(line) for line in (folder / "truth.jsonl").open()]
    rx = Receiver(load_camera(str(folder / "camera.yaml")), load_map(str(folder / "map.json")))
    s = dict(wrong=0, right_after3=0, total_after3=0, entered=0, within3=0, frames=0)
    first_seen: dict[int, int] = {}
    first_decoded: dict[int, int] = {}
    for frame in open_source(str(folder)):
        if max_frames is not None and frame.index >= max_frames:
            break
        res = rx.process(frame)
        t = truth[frame.index]
        visible = [d for d in t["leds"] if d.get("visible", True)]
        for d in visible:
            first_seen.setdefault(d["id"], frame.index)
        first = {tr.track_id: tr.first_frame for tr in rx.tracker.tracks}
        for p in (rx.pairer.pairs if rx.pairer is not None else ()):  # S2-PSK emitters: their founding tracks'
            first.update(zip(p.ids, (p.a.first_frame, p.b.first_frame)))
        for o in res.leds:
            if o.id is not None and all(o.id != d["id"] for d in t["leds"]):
                s["wrong"] += 1  # an ID that is nowhere in this frame's scene
            if not visible:
                continue
            # S2-PSK pairs are seen as two blobs: match each to its own emitter's centroid.
            points = [(e, d) for d in visible for e in d.get("emitters", [d])]
            e, d = min(points, key=lambda p: (o.cx - p[0]["cx"]) ** 2 + (o.cy - p[0]["cy"]) ** 2)
            if np.hypot(o.cx - e["cx"], o.cy - e["cy"]) > GATE_PX:
                continue
            if o.id is not None and o.id != d["id"]:
                s["wrong"] += 1
            if o.id == d["id"]:
                first_decoded.setdefault(d["id"], frame.index)
            if frame.index - first.get(o.track, frame.index) >= 3:
                s["total_after3"] += 1
                s["right_after3"] += o.id == d["id"]
        s["frames"] += 1
    # IDs that entered the view after the first frame (those in view at frame 0 start together).
    for led_id, k in first_seen.items():
        if k > 0 and k + 3 < s["frames"]:
            s["entered"] += 1
            s["within3"] += first_decoded.get(led_id, 10 ** 9) - k <= 3
    s["in_view_at_start"] = sum(1 for k in first_seen.values() if k == 0)
    s["decoded_at_start"] = sum(1 for i, k in first_seen.items() if k == 0 and first_decoded.get(i, 99) <= 3)
    return s


def score_resolvable(folder, max_frames: int | None = None, receiver=None) -> dict:
    """`occloc eval`'s S2-PSK resolvable ID rate (receiver.evaluate.metrics.s2psk_resolvable)
    of the receiver on a recording folder (its video, camera, map and truth.jsonl): the frames go
    through `frame_record` and the truth lines through `truth_frame`, as `occloc run` and
    `occloc eval` read them. Returns the metric's dict (SL / FV right, qualifying; wrong_ids)."""
    from receiver.evaluate.metrics import s2psk_packet_s, s2psk_resolvable
    from receiver.io.output import frame_record
    from receiver.io.truth import run_frame, truth_frame

    folder = Path(folder)
    led_map = load_map(str(folder / "map.json"))
    rx = receiver or Receiver(load_camera(str(folder / "camera.yaml")), led_map)
    truth = dict(truth_frame(json.loads(line)) for line in (folder / "truth.jsonl").open() if line.strip())
    run = []
    for frame in open_source(str(folder)):
        if max_frames is not None and frame.index >= max_frames:
            break
        run.append(run_frame(frame_record(rx.process(frame))))
    return s2psk_resolvable(run, truth, packet_s=s2psk_packet_s(led_map) or 2.4)


@pytest.fixture(scope="module")
def walk():
    return _score("indoor-walk")


def test_walk_never_a_wrong_id(walk):
    assert walk["frames"] == 54 and walk["wrong"] == 0


def test_walk_ids_after_the_first_three_frames_of_a_track(walk):
    assert walk["total_after3"] > 200
    assert walk["right_after3"] / walk["total_after3"] >= 0.95


def test_walk_ook_ids_within_three_frames_of_entering_view(walk):
    assert walk["in_view_at_start"] >= 3 and walk["decoded_at_start"] == walk["in_view_at_start"]
    assert walk["entered"] >= 3 and walk["within3"] == walk["entered"]


@pytest.mark.parametrize("name", ["indoor-static", "vehicle"])
def test_other_recordings_never_a_wrong_id(name):
    s = _score(name)
    assert s["frames"] > 0 and s["wrong"] == 0
