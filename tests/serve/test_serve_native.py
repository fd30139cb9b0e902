"""The lighting server's compiled path (receiver.serve._warm via receiver.serve.fixes) against the
numpy reference (receiver.locate: solve_warm_batch, PoseFilter), and replies that do not depend
on how datagrams were batched: a fixed request stream replayed one datagram at a time and in
batches gives byte-identical replies."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from receiver.core import native
from receiver.io.ledmap import load_map
from receiver.locate.pose import WARM_MAX_CHI2_DOF, solve_warm_batch, warm_problem, ypr_to_rotation
from receiver.locate.ranging import R_LOOKING_UP
from receiver.serve.fixes import KERNEL, warm_fix
from receiver.serve.loadcore import DEFAULT_MAP, four_led_datagrams
from receiver.serve.server import LightingServer
from receiver.serve.wire import encode, make_request


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def walk_map():
    return load_map(str(DEFAULT_MAP))


@pytest.fixture
def kernel(monkeypatch):
    monkeypatch.delenv("OCCLOC_PURE", raising=False)
    k = native.load(KERNEL)
    assert k is not None, "receiver.serve._warm is not built (tools/dev reinstalls it)"
    return k


def _problems(walk_map, n_problems: int, seed: int):
    """Warm problems of cameras under the walk map's ceiling: 3-8 LEDs, with and without ranges
    and tilt prior, started 1-20 cm and a few degrees off the truth, some with outlier ranges."""
    rng = np.random.default_rng(seed)
    xyz = np.array([led.xyz for led in walk_map.leds.values()])
    out = []
    while len(out) < n_problems:
        C = np.array([rng.uniform(1, 7), rng.uniform(1, 7), rng.uniform(0.5, 1.8)])
        R = ypr_to_rotation(rng.uniform(-180, 180), rng.uniform(75, 90), rng.uniform(-8, 8))
        n = int(rng.integers(3, 9))
        L = xyz[np.argsort(np.linalg.norm(xyz[:, :2] - C[:2], axis=1))[:n]]
        Xc = (L - C) @ R.T
        uv = Xc[:, :2] / Xc[:, 2:] + rng.normal(0, 3e-4, (n, 2))
        d = np.linalg.norm(L - C, axis=1) + rng.normal(0, 2e-3, n)
        if rng.random() < 0.2:
            d[0] += 0.5                                   # an outlier range
        if rng.random() < 0.2:
            d[:] = np.nan                                 # angles only
        sigma_d = np.full(n, 2e-3)
        w = rng.normal(0, 0.05, 3)
        R0 = ypr_to_rotation(*np.degrees(w)) @ np.linalg.inv(ypr_to_rotation(0, 0, 0)) @ R
        C0 = C + rng.normal(0, 0.1, 3)
        tilt = R_LOOKING_UP if rng.random() < 0.8 else None
        q = warm_problem(L, uv, d, sigma_d, R0, C0, sigma_uv=3e-4, tilt_prior_R=tilt)
        if q is not None:
            out.append(q)
    return out


@pytest.mark.parametrize("loss", ["soft_l1", "linear", "cauchy", "huber"])
def test_warm_kernel_equals_the_numpy_solver(walk_map, kernel, loss):
    """Each frame's kernel fix is numpy's (solve_warm_batch of that frame alone) to rounding:
    the same kept / refused decision, centre, orientation, covariance and chi^2."""
    problems = _problems(walk_map, 60, seed=3)
    kept = 0
    for q in problems:
        a = solve_warm_batch([q], loss=loss, f_scale=3.0)[0]
        b = warm_fix(kernel, q, loss, 3.0)
        if a is None or b is None:
            # Only a frame on the edge of the chi^2 test may fall on either side.
            assert a is None and b is None or _near_edge(a or b), (a, b)
            continue
        kept += 1
        assert b.method == a.method and b.n_leds == a.n_leds and b.dof == a.dof
        np.testing.assert_allclose(b.C, a.C, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.R_cw, a.R_cw, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.cov, a.cov, rtol=1e-7, atol=1e-15)
        assert b.chi2 == pytest.approx(a.chi2, rel=1e-7, abs=1e-12)
    assert kept >= 30


def _near_edge(fix) -> bool:
    return abs(fix.chi2 - WARM_MAX_CHI2_DOF * max(fix.dof, 1)) <= 1e-6 * fix.chi2


def test_kernel_leaves_unknown_losses_to_numpy(walk_map, kernel):
    q = _problems(walk_map, 1, seed=4)[0]
    status = kernel.solve(q.L, q.uv, q.sigma_uv, q.d, q.sigma_d, q.up, q.up_sigma, q.R0, q.C0, "arctan", 3.0,
                          1e-6, 1e-8, 1e-9, 1e8, 100, np.empty(21))[0]
    assert status == kernel.REFERENCE


def _stream(walk_map) -> list[bytes]:
    """A fixed request stream: 600 loadgen datagrams of 20 walking devices, with frames that
    coast (one LED, no LEDs), an unknown ID, a device restarting at seq 0 (old_seq, dropped),
    malformed datagrams and a non-physical range mixed in."""
    dg = [data for _, _, data in four_led_datagrams(walk_map, 600, 20)]

    def edited(i, edit):
        req = json.loads(dg[i])
        edit(req)
        return encode(req)
    replaced = {100: edited(100, lambda r: r.update(leds=r["leds"][:1])),     # one LED: coasts
                101: edited(101, lambda r: r.update(leds=[])),                # no LED: coasts
                400: edited(400, lambda r: r["leds"][0].update(id=99999))}    # unknown to the map
    inserted = {
        200: b'{"v": 1, "device": "x", "seq": 1, "t": NaN, "sigma_uv": 0.1, "leds": []}',
        201: b"\xff\xfe",
        202: encode({"v": 1, "device": "y", "seq": 1, "t": 0.0, "sigma_uv": 3e-4,
                     "leds": [{"id": 7, "u": 0.0, "v": 0.0, "distance_m": 1e9, "sigma_m": 0.01}]}),
        300: dg[10],                                       # a duplicate: dropped
    }
    out = []
    for i, data in enumerate(dg):
        out.append(replaced.get(i, data))
        if i in inserted:
            out.append(inserted[i])
    return out


def _replay(walk_map, stream, batch: int) -> list[bytes | None]:
    srv = LightingServer(walk_map, clock=FakeClock(), source_rate=0)   # one source, frozen clock
    out = []
    for k in range(0, len(stream), batch):
        chunk = [(data, ("127.0.0.1", 9)) for data in stream[k:k + batch]]
        out += [srv.handle_datagram(*chunk[0])] if batch == 1 else srv.handle_datagrams(chunk)
    return out


def test_replies_do_not_depend_on_batching(walk_map, kernel):
    """The fixed stream replayed one datagram at a time (`handle_datagram`) and in batches of 8
    and 64 (`handle_datagrams`, as the socket loop takes them): the same reply bytes."""
    stream = _stream(walk_map)
    one = _replay(walk_map, stream, 1)
    assert _replay(walk_map, stream, 8) == one
    assert _replay(walk_map, stream, 64) == one
    replies = [json.loads(r) for r in one if r is not None]
    errors = [r["error"] for r in replies if "error" in r]
    # The 2-byte datagram's error reply would be larger than it: not sent.
    assert sorted(errors) == ["bad_json", "bad_value"]
    assert sum(r is None for r in one) == 2                                 # and the duplicate
    positions = [r["position"] for r in replies if "error" not in r and r["position"] is not None]
    assert len(positions) == 600 and {p["method"] for p in positions} == {"range+angle", "kalman-coast"}
    assert [r["unknown_ids"] for r in replies if r.get("unknown_ids")] == [[99999]]


def test_kernel_replies_equal_the_numpy_reference(walk_map, kernel, monkeypatch):
    """The same stream through the numpy reference path (OCCLOC_PURE=1, one datagram at a time:
    the server before the kernel): every position object equal after its documented rounding,
    `solve_R_cw` (full precision) within 1e-12."""
    stream = _stream(walk_map)
    fast = _replay(walk_map, stream, 1)
    monkeypatch.setenv("OCCLOC_PURE", "1")
    ref = _replay(walk_map, stream, 1)
    assert len(fast) == len(ref)
    for a, b in zip(ref, fast):
        if a is None or b is None:
            assert a is b
            continue
        ra, rb = json.loads(a), json.loads(b)
        Ra, Rb = ra.pop("solve_R_cw", None), rb.pop("solve_R_cw", None)
        assert ra == rb
        assert (Ra is None) == (Rb is None)
        if Ra is not None:
            np.testing.assert_allclose(Rb, Ra, rtol=0, atol=1e-12)


def test_kernels_refuse_wrong_arrays(kernel):
    """Arrays of another dtype or shape are a TypeError / ValueError, never a read out of bounds."""
    from receiver.locate import _kalman as k
    x, P = np.zeros((6, 1)), np.eye(6)
    with pytest.raises(TypeError):
        k.predict(x.astype(np.float32), P, 0.1, 0.5)
    with pytest.raises(ValueError):
        k.predict(np.zeros((7, 1)), P, 0.1, 0.5)
    with pytest.raises(ValueError):
        k.update(x, P, np.zeros(4), np.eye(3))
    L = np.zeros((4, 3))
    with pytest.raises(ValueError):
        kernel.solve(L, np.zeros((3, 2)), 1e-3, np.zeros(4), np.ones(4), None, 0.1, np.eye(3), np.zeros(3),
                     "soft_l1", 3.0, 1e-6, 1e-8, 1e-9, 1e8, 100, np.empty(21))
    with pytest.raises(ValueError):
        kernel.solve(np.zeros((4, 2)), np.zeros((4, 2)), 1e-3, np.zeros(4), np.ones(4), None, 0.1, np.eye(3),
                     np.zeros(3), "soft_l1", 3.0, 1e-6, 1e-8, 1e-9, 1e8, 100, np.empty(21))


def test_extreme_valid_values_on_the_compiled_path(walk_map, kernel, monkeypatch):
    """Warm devices sent valid but extreme frames -- image points at the |u|, |v| limit, the
    tightest and loosest sigmas, 10 km ranges, every map LED at once, ranges mixed with nulls:
    every reply is strict JSON, a finite position or an error reply, never an exception; the
    numpy reference path answers each with the same kind (position / coast / error)."""
    rng = np.random.default_rng(9)
    leds = list(walk_map.leds.values())[:64]
    base = [data for _, _, data in four_led_datagrams(walk_map, 40, 4)]
    frames = []
    for i in range(120):
        req = json.loads(base[i % 4])
        req.update(seq=10 + i, t=2.0 + i / 30)
        kind = i % 6
        if kind == 0:
            for led in req["leds"]:
                led["u"], led["v"] = (float(rng.choice([-100.0, 100.0])), float(rng.uniform(-100, 100)))
        elif kind == 1:
            req["sigma_uv"] = float(rng.choice([1e-9, 1.0]))
            for led in req["leds"]:
                led["sigma_m"] = float(rng.choice([1e-6, 1e3]))
        elif kind == 2:
            for led in req["leds"]:
                led["distance_m"] = float(rng.choice([1e-3, 1e4]))
        elif kind == 3:
            req["leds"] = [{"id": led.id, "u": float(rng.normal(0, 0.5)), "v": float(rng.normal(0, 0.5)),
                            "distance_m": float(rng.uniform(1, 5)), "sigma_m": 0.01} for led in leds]
        elif kind == 4:
            for led in req["leds"][::2]:
                led["distance_m"] = led["sigma_m"] = None
        frames.append(encode(req))
    stream = base + frames

    def kinds(replies):
        out = []
        for data in replies:
            r = json.loads(data, parse_constant=lambda c: pytest.fail(f"{c} in a reply"))
            if "error" in r:
                out.append(r["error"])
                continue
            p = r["position"]
            assert p is None or all(math.isfinite(p[k]) for k in "xyz")
            out.append(None if p is None else p["method"])
        return out

    fast = kinds(_replay(walk_map, stream, 8))
    monkeypatch.setenv("OCCLOC_PURE", "1")
    assert kinds(_replay(walk_map, stream, 8)) == fast
    assert len(fast) == len(stream) and "range+angle" in fast


def _bits(obj):
    """A value with every float replaced by its repr (so -0.0, NaN and the last digit count)."""
    if isinstance(obj, dict):
        return {k: _bits(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_bits(v) for v in obj]
    return repr(obj) if isinstance(obj, float) else obj


def _rounded(v, n):
    v = float(v)
    return round(v, n) if math.isfinite(v) else v


def _expected_position(state, fix, handedness):
    """The position object of INTERFACES.md by Python's `round`, numpy's `round` (cov, R_wc) and
    `rotation_to_ypr_deg`: the oracle of the kernel's dict."""
    from receiver.locate.pose import rotation_to_ypr_deg

    def xyz(v):
        return {"x": _rounded(v[0], 5), "y": _rounded(v[1], 5), "z": _rounded(v[2], 5)}

    def std(c):
        return [_rounded(math.sqrt(max(0.0, c[i, i])), 5) for i in range(3)]
    if state is not None:
        x, P = state
        pos = xyz(x)
        pos.update(method=fix.method if fix is not None else "kalman-coast", n_leds=4, filtered=True,
                   std_m=std(P), cov=np.round(P[:3, :3], 8).tolist(),
                   velocity_mps=[_rounded(v, 4) for v in x[3:]])
    else:
        pos = xyz(fix.C)
        pos.update(method=fix.method, n_leds=4, filtered=False)
    pos["raw"] = None if fix is None else xyz(fix.C)
    if fix is not None:
        pos["raw_std_m"] = std(fix.cov)
        if fix.R_cw is not None:
            pos["R_wc"] = np.round(fix.R_cw.T, 6).tolist()
            with np.errstate(invalid="ignore"):
                yaw, pitch, roll = rotation_to_ypr_deg(fix.R_cw)
            pos.update(yaw_deg=_rounded(yaw, 3), pitch_deg=_rounded(pitch, 3), roll_deg=_rounded(roll, 3))
    if handedness is not None:
        pos["handedness"] = handedness
    return pos


def test_position_kernel_rounds_as_python_and_writes_wire_json():
    """receiver.locate._position builds the position object with Python's and numpy's rounding
    (key order, every float's repr; yaw / pitch / roll within 1e-3 deg of rotation_to_ypr_deg's)
    and writes its JSON byte for byte as wire.encode does, for random states and fixes and for
    the rounding's hard cases: values on and next to decimal ties, -0.0, huge, tiny, NaN and
    infinite numbers, no track, no fix, no orientation."""
    from receiver.locate import _position as k
    from receiver.locate.lsq import Fix
    rng = np.random.default_rng(11)
    hard = [0.5e-5, 1.5e-5, 2.675, 1.000005, -1.000005, 0.125, -0.0, 0.0, 1e-320, 1e12, -3e15, 1e300, 1e-4, 1e-5,
            123456.78, 1e16, 9.99999999, -0.0000049, 0.0000051, 1200.0,
            np.nextafter(1.000005, 2), np.nextafter(1.000005, 0), 12.34565, 0.00012345, math.nan, math.inf]

    def sample(n):
        v = rng.normal(0, 3, n) * 10.0 ** rng.integers(-6, 3, n)
        pick = rng.random(n) < 0.3
        v[pick] = rng.choice(hard, pick.sum())
        return v
    for trial in range(2000):
        x = sample(6)
        P = sample(36).reshape(6, 6)
        C, cov = sample(3), sample(9).reshape(3, 3)
        rotation = trial % 5 != 0
        R = ypr_to_rotation(*rng.uniform(-180, 180, 3)) if rotation else sample(9).reshape(3, 3)
        state = None if trial % 7 == 3 else (x, P)
        fix = None if trial % 11 == 4 and state is not None else Fix(C, cov, None if trial % 13 == 6 else R,
                                                                    "range+angle", 4)
        handedness = None if trial % 3 else "right"
        args = (*(state or (None, None)), *((None, None, None) if fix is None else (fix.C, fix.cov, fix.R_cw)),
                "kalman-coast" if fix is None else fix.method, 4, handedness)
        got = k.position(*args)
        want = _expected_position(state, fix, handedness)
        assert list(got) == list(want), trial
        angles = ("yaw_deg", "pitch_deg", "roll_deg")
        if rotation and "yaw_deg" in want:
            for key in angles:
                assert abs(got.pop(key) - want.pop(key)) <= 1.01e-3, (trial, key)
        else:
            for key in angles:
                assert (key in got) == (key in want)
                got.pop(key, None), want.pop(key, None)
        assert _bits(got) == _bits(want), trial
        assert _json_or_error(lambda: k.position_json(*args)) == _json_or_error(lambda: encode(k.position(*args))), trial
        if fix is not None and fix.R_cw is not None:
            assert _json_or_error(lambda: k.rotation_json(fix.R_cw)) == _json_or_error(lambda: encode(fix.R_cw.tolist()))


def _json_or_error(make):
    try:
        return make()
    except ValueError:                 # NaN / infinity: refused by both
        return "ValueError"


def _replay_dicts(walk_map, stream) -> list[bytes | None]:
    """The stream through `handle` (reply dicts), each encoded by wire.encode."""
    srv = LightingServer(walk_map, clock=FakeClock(), source_rate=0)
    return [None if r is None else encode(r) for r in (srv.handle(data, ("127.0.0.1", 9)) for data in stream)]


@pytest.mark.parametrize("mirror", [False, True])
def test_reply_bytes_equal_the_encoded_reply_dicts(walk_map, kernel, mirror):
    """The socket path writes position replies straight to JSON (`_reply_json`, the compiled
    `position_json`): the same bytes as `wire.encode` of the reply dicts `handle` returns, on the
    fixed stream, also in a left-handed map (the mirrored numbers are PoseFilter's)."""
    from tests.locate.test_locate import mirrored_map
    led_map = mirrored_map(walk_map) if mirror else walk_map
    stream = _stream(walk_map)
    if mirror:                                    # the same scenes seen in the mirrored map
        stream = [_mirror_request(data) for data in stream]
    fast = _replay(led_map, stream, 8)
    assert fast == _replay_dicts(led_map, stream)
    assert sum(b'"position":{' in r for r in fast if r) >= 590


def _mirror_request(data: bytes) -> bytes:
    """A request of the mirrored map's world: image columns reversed (u -> -u)."""
    try:
        req = json.loads(data)
        for led in req["leds"]:
            led["u"] = -led["u"]
        return encode(req)
    except (ValueError, KeyError, TypeError):
        return data


def test_fast_request_check_accepts_what_the_parser_accepts(walk_map, monkeypatch):
    """wire.parse_request with the compiled check (receiver.serve._wire) and without it: the same
    Request (same values) or the same refusal (reason and detail), on valid requests and 3,000
    seeded mutations of them (bytes flipped, cut, spliced; values replaced by odd ones: null,
    booleans, huge, tiny, -0.0, strings, lists, objects, ints for floats, a camera that is null)."""
    from receiver.serve.server import WIRE_KERNEL
    from receiver.serve.wire import ProtocolError, parse_request
    from tests.serve.test_badinput_serve import _mutations
    monkeypatch.delenv("OCCLOC_PURE", raising=False)
    fast = native.load(WIRE_KERNEL)
    assert fast is not None
    rng = np.random.default_rng(31)
    bases = [data for _, _, data in four_led_datagrams(walk_map, 30, 6)]
    cam = json.loads(bases[0])
    cam["camera"] = None
    bases.append(encode(cam))
    cam["camera"] = {"fx": 1000.0}
    bases.append(encode(cam))
    accepted = 0
    for n in range(3000):
        base = bases[n % len(bases)]
        data = base if n % 10 == 0 else _mutations(rng, base, json.loads(base))

        def outcome(kernel):
            try:
                r = parse_request(data, kernel)
            except ProtocolError as e:
                return ("refused", e.reason, e.detail, e.device, e.seq)
            return ("ok", r.device, r.seq, r.t, r.sigma_uv, r.ids, r.uv.tolist(), _bits(r.d.tolist()),
                    _bits(r.sigma_d.tolist()))
        a, b = outcome(None), outcome(fast)
        assert a == b, data
        accepted += a[0] == "ok"
    assert accepted > 300
