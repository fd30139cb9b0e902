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


def test_compiled_association_equals_the_numpy_form(monkeypatch):
    """Every `_associate` call of both scenes above, run by the kernel and by the numpy form on
    the same inputs: the same matches (the twin-head map: the same refusals)."""
    import pytest

    import receiver.locate.vehicle_assoc as V
    kernel = V._ka
    if kernel is None:
        pytest.skip("compiled kernel not built (tests/engine/test_native.py fails then)")
    orig = VehicleLocator._associate
    seen = []

    def both(loc, t_s, pairs, R_prior):
        got = orig(loc, t_s, pairs, R_prior)
        monkeypatch.setattr(V, "_ka", None)
        try:
            ref = orig(loc, t_s, pairs, R_prior)
        finally:
            monkeypatch.setattr(V, "_ka", kernel)
        seen.append((got, ref))
        return got

    monkeypatch.setattr(VehicleLocator, "_associate", both)
    test_undecoded_pairs_on_mapped_heads_join_the_host_solve()
    test_two_mapped_heads_in_the_gate_are_no_match()
    assert sum(1 for got, _ in seen if got) >= 15       # matches were made and compared
    assert all(got == ref for got, ref in seen)


def test_compiled_association_rejects_mismatched_sizes():
    import pytest

    import receiver.locate.vehicle_assoc as V
    if V._ka is None:
        pytest.skip("compiled kernel not built (tests/engine/test_native.py fails then)")
    H, Bl, use, R, P = np.zeros((3, 3)), np.ones(3), bytes(3), np.eye(3), np.eye(2)
    und, sep, out = np.zeros((2, 2)), np.ones(2), np.empty(2, np.int_)
    assert V._ka.associate(H, Bl, use, R, 0.0, 0.0, 0.0, P, 1e-6, 1200.0, und, sep, 9.0, 0.3, out) == 0
    with pytest.raises(ValueError):
        V._ka.associate(H, np.ones(2), use, R, 0.0, 0.0, 0.0, P, 1e-6, 1200.0, und, sep, 9.0, 0.3, out)
    with pytest.raises(ValueError):
        V._ka.associate(H, Bl, use, R, 0.0, 0.0, 0.0, P, 1e-6, 1200.0, und, sep, 9.0, 0.3, np.empty(1, np.int_))
