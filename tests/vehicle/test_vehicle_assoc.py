"""Map-aided association (receiver.locate.vehicle `_associate`): undecoded pairs on mapped
street-light heads, projected from the road filter's prediction, join the host solve; they are
never reported as IDs, ranges or cars. Scenes from test_vehicle's projection helpers."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tests.vehicle.test_vehicle import CAM, SETTINGS, camera_pose, make_map, sl_pairs
from receiver.io.ledmap import LedMap
from receiver.locate.vehicle import VehicleLocator


def _undecode(p):
    return dataclasses.replace(p, led_id=None, kind=None)


def _run(lmap, settings, n_frames=45, warm=20, seed=5):
    """Two decoded heads per frame for `warm` frames (the filter gets sure), then only the
    nearest decoded and every other head in view undecoded. Returns [(hv, ranges of the
    undecoded pairs, fv list, true C)] of the later frames."""
    rng = np.random.default_rng(seed)
    loc = VehicleLocator(CAM, lmap, settings)
    out = []
    for k in range(n_frames):
        R, C, psi = camera_pose(5.0 + 14.0 * k / 30.0, yaw_off=rng.normal(0, 0.1))
        pairs = sorted(sl_pairs(lmap, R, C, rng=rng, px_sigma=0.2, area_rel=0.03, max_range=70.0),
                       key=lambda p: -p.separation_px)
        if k < warm:
            loc.step(k / 30.0, pairs[:2])
            continue
        pairs = pairs[:1] + [_undecode(p) for p in pairs[1:]]
        res = loc.step(k / 30.0, pairs)
        out.append((res.vehicle["hv"], res.ranges[1:], res.vehicle["fv"], C, len(pairs) - 1))
    return out


def test_undecoded_pairs_on_mapped_heads_join_the_host_solve():
    lmap = make_map()
    rows = _run(lmap, SETTINGS)
    used = [r for r in rows if r[0] is not None and r[0]["n_assoc"] > 0]
    assert len(used) >= 0.8 * len(rows)
    for hv, ranges, fv, C, n_und in used:
        assert hv["method"] in ("pose+map", "kalman-coast") and hv["n_lights"] == 1 + hv["n_assoc"]
        assert math.hypot(hv["x"] - C[0], hv["y"] - C[1]) < 0.3
        assert all(r is None for r in ranges)        # no range, so no ID claimed, for them
        assert fv == []                              # nor a forward vehicle
    # Without the association, the same frames are single-light updates.
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(VehicleLocator, "_associate", lambda self, *args: {})
        rows_off = _run(lmap, SETTINGS)
    assert all(r[0] is None or r[0]["n_assoc"] == 0 for r in rows_off)
    assert sum(r[0] is not None and r[0]["method"] == "sl-1" for r in rows_off) >= 0.8 * len(rows_off)


def test_two_mapped_heads_in_the_gate_are_no_match():
    """A second mapped head 0.6 m beside every head: every undecoded pair has two heads in its
    gate, so none is associated (and the host is never placed from a guess)."""
    lmap = make_map()
    leds = dict(lmap.leds)
    for k, led in lmap.leds.items():
        em = tuple((x + 0.6, y, z) for x, y, z in led.emitters)
        leds[k + 60] = dataclasses.replace(led, id=k + 60, x=led.x + 0.6, emitters=em)
    twin = LedMap(addressing="map", leds=leds, taillight=lmap.taillight)
    rng = np.random.default_rng(2)
    loc = VehicleLocator(CAM, twin, SETTINGS)
    for k in range(40):
        R, C, psi = camera_pose(5.0 + 14.0 * k / 30.0)
        pairs = sorted(sl_pairs(lmap, R, C, rng=rng, px_sigma=0.2, area_rel=0.03, max_range=70.0),
                       key=lambda p: -p.separation_px)
        if k >= 20:
            pairs = pairs[:1] + [_undecode(p) for p in pairs[1:]]
        hv = loc.step(k / 30.0, pairs[:2] if k < 20 else pairs).vehicle["hv"]
        if k >= 20 and hv is not None:
            assert hv["n_assoc"] == 0
