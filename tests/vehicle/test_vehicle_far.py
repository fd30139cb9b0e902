"""Forward vehicles at 50-60 m (the issue's 50-100 m band; the bundled recording has none beyond
50 m): a short render of the `vehicle` scene with its far-FV options, the whole receiver on it,
FV distances scored against the scene's truth (read only here)."""

from __future__ import annotations

import numpy as np
import pytest

N_FRAMES = 36        # 1.2 s: each pair forms and is ranged a few times (~3 s a seed on one core)


@pytest.fixture(scope="module", params=[3, 1])
def far_run(request):
    from receiver.core.records import Frame
    from receiver.locate.vehicle import VehicleLocator
    from receiver.pipeline import Receiver
    from tools.synth.render import render_frames
    from tools.synth.scenes import make_scene

    # FV1 56 m ahead in the host lane, FV2 53 m ahead in the right lane (no closing, no lane
    # change within 1.2 s).
    # Seed 1: one taillight of each car pairs up across the cars (read as a car at 35 m).
    seed = request.param
    scene = make_scene("vehicle", seed=seed, n_frames=N_FRAMES, fv1_gap_m=56.0, fv1_closing_m=0.0, fv2_gap_m=53.0)
    rx = Receiver(scene.camera, scene.led_map, vehicle=VehicleLocator(scene.camera, scene.led_map))
    out = []
    for k, (img, truth) in enumerate(render_frames(scene, seed=seed)):
        res = rx.process(Frame(k, truth["t"], img))
        out.append((res.vehicle, truth["vehicle"]["fv"]))
    return out


def test_far_forward_vehicles_ranged_within_two_percent(far_run):
    rel, bear = [], []
    for vehicle, truth_fv in far_run:
        for fv in (vehicle or {}).get("fv", []):
            tf = min(truth_fv, key=lambda t: abs(t["angle_deg"] - fv["angle_deg"]))
            assert abs(tf["angle_deg"] - fv["angle_deg"]) < 1.0, (fv, tf)   # no phantom FV
            rel.append(abs(fv["distance_m"] - tf["distance_m"]) / tf["distance_m"])
            bear.append(abs(fv["angle_deg"] - tf["angle_deg"]))
    assert min(t["distance_m"] for _, tv in far_run for t in tv) > 50.0
    # measured: seed 3 64 entries, median 0.34 %, max 1.1 %; seed 1 23, 0.48 %, 1.2 %
    assert len(rel) >= 20, len(rel)
    assert np.median(rel) <= 0.02 and max(rel) <= 0.06, (len(rel), np.median(rel), max(rel))
    assert np.median(bear) <= 0.1
