"""Bad input, faults and signals of the lighting server and its client: non-physical values,
non-finite solver results, strict JSON out, strict checking of replies by RemotePositioner,
devices per source address, start-up order and stop signals of `occloc serve`, and a seeded fuzz
of the datagram parser. Server clocks are injected (no wall-clock dependence)."""

from __future__ import annotations

import json
import math
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.serve.client import RemotePositioner
from receiver.serve.server import ERROR_REPLY_RATE, LightingServer
from receiver.serve.wire import REASONS, encode
from tests.serve.test_server import WALK, FakeClock, _good, request, scene, serve_process

ROOT = Path(__file__).resolve().parents[2]
C0 = np.array([3.1, 4.2, 1.0])


@pytest.fixture(scope="module")
def walk_map():
    return load_map(str(WALK / "map.json"))


def _js(obj) -> bytes:
    return json.dumps(obj).encode()


def _finite_json(data: bytes) -> dict:
    """Parse a reply as strict JSON (a NaN / Infinity token raises)."""
    def no_constant(name):
        raise AssertionError(f"{name} in a reply")
    return json.loads(data, parse_constant=no_constant)


# ---------------------------------------------------------------- non-physical request values

def _valid(field=None, value=None, led_field=None) -> dict:
    """A valid 4-LED request of the walk map (distinct IDs) with one value replaced."""
    req = request("d", 0, 0.0, *scene(load_map(str(WALK / "map.json")), C0))
    if field is not None:
        req[field] = value
    if led_field is not None:
        req["leds"][0][led_field] = value
    return req


NON_PHYSICAL = [   # (name, request, the field the reason names)
    ("distance 1e300", _valid(led_field="distance_m", value=1e300), "distance_m"),
    ("distance 20 km", _valid(led_field="distance_m", value=2e4), "distance_m"),
    ("distance 0.1 mm", _valid(led_field="distance_m", value=1e-4), "distance_m"),
    ("sigma_m 1e300", _valid(led_field="sigma_m", value=1e300), "sigma_m"),
    ("sigma_m 1e-300", _valid(led_field="sigma_m", value=1e-300), "sigma_m"),
    ("t 1e300", _valid("t", 1e300), "t"),
    ("t -1e300", _valid("t", -1e300), "t"),
    ("sigma_uv 1e300", _valid("sigma_uv", 1e300), "sigma_uv"),
    ("sigma_uv 1e-300", _valid("sigma_uv", 1e-300), "sigma_uv"),
    ("sigma_uv negative", _valid("sigma_uv", -1e-3), "sigma_uv"),
]


def test_the_valid_base_request_is_served(walk_map):
    assert LightingServer(walk_map, clock=FakeClock()).handle(_js(_valid()))["position"] is not None


@pytest.mark.parametrize("req, field", [r[1:] for r in NON_PHYSICAL], ids=[r[0] for r in NON_PHYSICAL])
def test_non_physical_values_are_bad_value(walk_map, req, field):
    srv = LightingServer(walk_map, clock=FakeClock())
    reply = srv.handle(_js(req))
    assert reply.get("error") == "bad_value" and field in reply["detail"], reply
    assert srv.counters["bad_value"] == 1 and not srv.devices


def test_one_absurd_distance_does_not_poison_the_device(walk_map):
    """Before: distance_m 1e300 was accepted, the filter went NaN and stayed NaN for the device
    (NaN in every later JSON reply)."""
    srv = LightingServer(walk_map, clock=FakeClock())
    ids, uv, d = scene(walk_map, C0)
    assert srv.handle_datagram(encode(request("a", 0, 0.0, ids, uv, d)))
    bad = request("a", 1, 0.1, ids, uv, d)
    bad["leds"][0]["distance_m"] = 1e300         # by hand: make_request would send null
    out = srv.handle_datagram(encode(bad))
    assert _finite_json(out)["error"] == "bad_value"
    reply = _finite_json(srv.handle_datagram(encode(request("a", 2, 0.2, ids, uv, d))))
    assert np.linalg.norm([reply["position"][k] - C0[i] for i, k in enumerate("xyz")]) < 0.01


def test_make_request_sends_out_of_range_ranges_as_null(walk_map):
    ids, uv, d = scene(walk_map, C0)
    d = d.copy()
    d[0], d[1] = 1e300, 1e-9
    req = request("a", 0, 0.0, ids, uv, d)
    assert [led["distance_m"] is None for led in req["leds"]] == [True, True, False, False]
    reply = LightingServer(walk_map, clock=FakeClock()).handle(encode(req))
    assert reply["position"] is not None and reply["n_used"] == 4


def test_non_finite_solver_result_is_an_internal_error(walk_map, monkeypatch):
    srv = LightingServer(walk_map, clock=FakeClock())
    frame = scene(walk_map, C0)
    assert srv.handle(encode(request("a", 0, 0.0, *frame)))["position"] is not None
    filter_class = type(srv.devices["a"].pose)        # PoseFilter, or the server's compiled one
    real_update = filter_class.update

    def nan_update(self, *a, **k):
        pos = real_update(self, *a, **k)
        pos["x"] = math.nan
        return pos

    monkeypatch.setattr(filter_class, "update", nan_update)
    if hasattr(filter_class, "update_json"):        # the compiled filter's JSON path: NaN is ValueError
        monkeypatch.setattr(filter_class, "update_json", lambda self, *a: encode(nan_update(self, *a)))
    out = srv.handle_datagram(encode(request("a", 1, 0.1, *frame)))
    assert _finite_json(out) == {"v": 1, "error": "internal_error", "detail": "FloatingPointError",
                                 "device": "a", "seq": 1}
    assert "a" not in srv.devices and srv.counters["internal_error"] == 1
    assert srv.counters["positions"] == 1
    monkeypatch.undo()
    p = srv.handle(encode(request("a", 0, 0.2, *frame)))["position"]     # a fresh filter
    assert p is not None and p["velocity_mps"] == [0.0, 0.0, 0.0]


def test_fast_led_check_accepts_only_what_the_full_check_accepts():
    """wire._parse_led_fast (the common case by plain comparisons) returns exactly what _parse_led
    returns, or None (then _parse_led runs and names the fault): on valid LEDs and on each field
    set to values around and beyond its limits, of other types, missing, and with centroids."""
    from receiver.serve.wire import ProtocolError, _parse_led, _parse_led_fast
    base = {"id": 7, "u": 0.01, "v": -0.2, "distance_m": 2.5, "sigma_m": 0.004}
    odd = [None, True, 0, 1, -1, 2 ** 31, 2 ** 31 - 1, 0.0, -0.0, 1e-3, 1e-6, 1e3, 1e4, 100.0, -100.0, 100.5,
           1e4 + 1, 1e-7, math.inf, -math.inf, math.nan, "1", [], {}]
    accepted = 0
    for key in list(base) + ["cx"]:
        for value in odd:
            item = dict(base, **{key: value})
            fast = _parse_led_fast(item)
            try:
                slow = _parse_led(item, 0)
            except ProtocolError:
                slow = None
            if fast is not None:
                accepted += 1
                assert fast == slow and all(type(x) is float for x in fast[1:]), (item, fast, slow)
        if key in base:
            assert _parse_led_fast({k: v for k, v in base.items() if k != key}) is None
    assert _parse_led_fast(base) == _parse_led(base, 0) and accepted > 10
    assert _parse_led_fast([1, 2]) is None and _parse_led_fast(dict(base, cx=1.0)) is None


def test_unencodable_reply_falls_back_to_an_error(walk_map, monkeypatch):
    srv = LightingServer(walk_map, clock=FakeClock())
    srv.handle(encode(request("a", 0, 0.0, *scene(walk_map, C0))))
    monkeypatch.setattr(srv, "_handle", lambda datagrams, as_bytes=False: ([{     # not encoded by _reply
        "v": 1, "device": "a", "seq": 1, "position": {"x": math.inf}}], {}))
    out = _finite_json(srv.handle_datagram(b"{}"))
    assert out["error"] == "internal_error" and (out["device"], out["seq"]) == ("a", 1)
    assert "a" not in srv.devices
    with pytest.raises(ValueError):
        encode({"x": math.nan})


# ---------------------------------------------------------------- the client checks replies

def _rot(yaw_deg):
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]


GOOD_POS = {"x": 1.0, "y": 2.0, "z": 0.5, "method": "range+angle", "n_leds": 3, "filtered": True,
            "std_m": [0.01, 0.01, 0.01], "velocity_mps": [0.0, 0.0, 0.0],
            "raw": {"x": 1.0, "y": 2.0, "z": 0.5}, "R_wc": _rot(30)}

BAD_REPLIES = [
    ("NaN token", b'"position": {"x": NaN, "y": 2.0, "z": 0.5}'),
    ("Infinity token", b'"position": {"x": 1.0, "y": Infinity, "z": 0.5}'),
    ("overflow 1e999", b'"position": {"x": 1.0, "y": 2.0, "z": 1e999}'),
    ("x a string", {"position": {**GOOD_POS, "x": "1.0"}}),
    ("x a bool", {"position": {**GOOD_POS, "x": True}}),
    ("x 1e300", {"position": {**GOOD_POS, "x": 1e300}}),
    ("y missing", {"position": {"x": 1.0, "z": 0.5}}),
    ("position a list", {"position": [1.0, 2.0, 0.5]}),
    ("raw x 1e300", {"position": {**GOOD_POS, "raw": {"x": 1e300, "y": 0, "z": 0}}}),
    ("velocity 2 numbers", {"position": {**GOOD_POS, "velocity_mps": [0.0, 0.0]}}),
    ("R_wc scaled", {"position": {**GOOD_POS, "R_wc": (2 * np.array(_rot(30))).tolist()}}),
    ("solve_R_cw scaled", {"solve_R_cw": (2 * np.array(_rot(30))).tolist()}),
    ("solve_R_cw reflection", {"solve_R_cw": [[1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]]}),
    ("solve_R_cw 2x2", {"solve_R_cw": [[1.0, 0], [0, 1.0]]}),
    ("solve_R_cw strings", {"solve_R_cw": [["1", 0, 0], [0, 1, 0], [0, 0, 1]]}),
    ("solve_R_cw 1e300", {"solve_R_cw": [[1e300, 0, 0], [0, 1, 0], [0, 0, 1]]}),
    ("unknown_ids strings", {"unknown_ids": ["7"]}),
    ("n_used negative", {"n_used": -1}),
]


def _reply_bytes(seq: int, change) -> bytes:
    base = {"v": 1, "device": "dev", "seq": seq, "position": GOOD_POS, "unknown_ids": [],
            "n_used": 3, "solve_R_cw": _rot(-30)}
    if isinstance(change, bytes):          # raw JSON text for the position (non-strict tokens)
        base.pop("position")
        return encode(base)[:-1] + b"," + change + b"}"
    return encode({**base, **change})


def test_remote_positioner_refuses_malformed_replies(walk_map):
    """Before: NaN / inf / wrong types in `position` were passed on, and any finite 3 x 3
    `solve_R_cw` (even a scaled or mirrored one) was kept for the next ranges."""
    cam = load_camera(str(WALK / "camera.yaml"))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as fake:
        fake.bind(("127.0.0.1", 0))
        host, port = fake.getsockname()
        with RemotePositioner(cam, walk_map, f"udp://{host}:{port}", device="dev", timeout_s=2.0, protocol=1) as rp:
            client = rp.sock.getsockname()
            for k, (name, change) in enumerate(BAD_REPLIES):
                fake.sendto(_reply_bytes(k, change), client)   # queued before the request
                assert rp.step(0.01 * k, []).position is None, name
                assert rp.errors == k + 1 and rp.last_error.startswith("bad_reply: "), name
                assert rp.local.pose.R_prior(0.01 * k) is None, name     # no orientation kept
            assert rp.n_fixes == 0 and not rp.unknown_ids and rp.timeouts == 0
            # A well-formed reply still goes through, orientation and all.
            k = len(BAD_REPLIES)
            fake.sendto(_reply_bytes(k, {"unknown_ids": [9]}), client)
            assert rp.step(0.01 * k, []).position == GOOD_POS
            assert rp.errors == k and rp.n_fixes == 1 and rp.unknown_ids == {9}
            assert np.allclose(rp.local.pose.R_prior(0.01 * k), _rot(-30))


# ---------------------------------------------------------------- devices per source address

def test_devices_are_bounded_per_source_address(walk_map):
    clock = FakeClock()
    srv = LightingServer(walk_map, max_devices_per_source=2, forget_s=5.0, clock=clock)
    frame = scene(walk_map, C0)

    def send(name, seq, source):
        return srv.handle(encode(request(name, seq, 0.1 * seq, *frame)), source)

    assert send("a", 0, ("10.0.0.1", 4000))["position"] is not None
    assert send("b", 0, ("10.0.0.1", 4001))["position"] is not None
    refused = send("c", 0, ("10.0.0.1", 4002))          # same host, another port
    assert (refused["error"], refused["device"], refused["seq"]) == ("too_many_devices_per_source", "c", 0)
    assert send("d", 0, ("10.0.0.2", 4000))["position"] is not None      # another host: served
    assert send("a", 1, ("10.0.0.1", 4000))["position"] is not None      # known devices: served
    assert srv.counters["too_many_devices_per_source"] == 1
    assert "too_many_devices_per_source 1" in srv.summary()
    clock.now = 5.5                                      # all forgotten: room again
    assert send("c", 1, ("10.0.0.1", 4002))["position"] is not None
    assert dict(srv.per_source) == {"10.0.0.1": 1}
    assert "too_many_devices_per_source" in REASONS


def test_flood_of_names_from_one_source_leaves_room_for_others(walk_map):
    srv = LightingServer(walk_map, max_devices=100, clock=FakeClock())    # default 64 per source
    data = [_js(_good(device=f"flood-{i}", leds=[])) for i in range(200)]
    replies = [srv.handle(d, ("10.6.6.6", 1)) for d in data]
    assert sum(r is not None and "error" not in r for r in replies) == 64
    assert srv.counters["too_many_devices_per_source"] == 136
    # the refusals' replies are rate-limited per host (ERROR_REPLY_RATE, a burst of twice that)
    errors = [r["error"] for r in replies if r is not None and "error" in r]
    assert set(errors) == {"too_many_devices_per_source"} and len(errors) == 2 * ERROR_REPLY_RATE
    assert "error" not in srv.handle(_js(_good(device="honest", leds=[])), ("10.0.0.9", 1))


# ---------------------------------------------------------------- occloc serve: start-up and signals

def _serve_with_signal_at_load(sig) -> subprocess.CompletedProcess:
    """`occloc serve --port 0` in a child that sends itself `sig` while loading the map, i.e.
    during start-up, before the port is bound."""
    code = ("import os, signal, sys\n"
            "import receiver.io.ledmap as m\n"
            "real = m.load_map\n"
            "def load(*a, **k):\n"
            f"    os.kill(os.getpid(), {int(sig)})\n"
            "    return real(*a, **k)\n"
            "m.load_map = load\n"
            "from receiver.cli import main\n"
            "sys.exit(main(['serve', '--port', '0']))\n")
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT],
                         ids=["SIGTERM", "SIGHUP", "SIGINT"])
def test_stop_signal_during_start_up_exits_0_with_a_summary(sig):
    """Before: SIGTERM during start-up killed it (exit 143, no summary); SIGHUP always did (129)."""
    proc = _serve_with_signal_at_load(sig)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        "occloc serve: 0 datagrams, 0 replies, 0 positions; devices: 0 new, 0 forgotten, 0 held; "
        "dropped/refused: none")


def test_sighup_stops_the_server_with_a_summary():
    with serve_process() as (proc, url):
        proc.send_signal(signal.SIGHUP)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert err.strip().splitlines()[-1].startswith("occloc serve: 0 datagrams")


def test_serve_announces_before_importing_the_solver():
    """`listening on` comes before SciPy / the Kalman filter are imported (before: after them,
    2-4 s after start). Checked on the import order (-X importtime), not on the clock."""
    proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "receiver.cli", "serve", "--port", "0"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(ln) for ln in proc.stderr] + [lines.put(None)],
                              daemon=True)
    reader.start()
    text = []

    def read_until(pred, timeout_s):
        end = time.monotonic() + timeout_s
        while (left := end - time.monotonic()) > 0:
            try:
                line = lines.get(timeout=left)
            except queue.Empty:
                return False
            if line is None:
                return False
            text.append(line)
            if pred(line):
                return True
        return False

    try:
        assert read_until(lambda ln: "listening on" in ln, 60), "".join(text)[-2000:]
        # the solver's import follows the announcement (or never comes): then stop
        read_until(lambda ln: ln.rstrip().endswith("receiver.locate.posefilter"), 30)
        proc.send_signal(signal.SIGTERM)
        proc.wait(20)
        reader.join(10)
        read_until(lambda ln: False, 1)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    before, sep, after = "".join(text).partition("occloc serve: listening on")
    modules = lambda part: {ln.rsplit("|", 1)[-1].strip() for ln in part.splitlines() if "|" in ln}  # noqa: E731
    assert not {"scipy", "filterpy", "matplotlib", "receiver.locate.posefilter"} & modules(before)
    assert "receiver.locate.posefilter" in modules(after)        # warmed up once announced
    assert "occloc serve: ready" in after.split("receiver.locate.posefilter", 1)[1]
    assert proc.returncode == 0 and "occloc serve: 0 datagrams" in after


def test_max_devices_per_source_option(capsys):
    from receiver.cli import main as cli
    assert cli(["serve", "--max-devices-per-source", "0"]) == 2
    assert "--max-devices-per-source" in capsys.readouterr().err


# ---------------------------------------------------------------- seeded fuzz of the parser

ERROR_REASONS = set(REASONS) - {"old_seq"}


def _mutations(rng, base: bytes, obj: dict):
    """One mutated datagram: byte flips, truncation, splices, or a JSON-level value change."""
    kind = int(rng.integers(0, 6))
    b = bytearray(base)
    if kind == 0:                                     # flip random bytes
        for _ in range(int(rng.integers(1, 6))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        return bytes(b)
    if kind == 1:                                     # truncate
        return bytes(b[:int(rng.integers(0, len(b)))])
    if kind == 2:                                     # duplicate / splice a slice
        i, j = sorted(rng.integers(0, len(b), 2))
        k = int(rng.integers(0, len(b)))
        return bytes(b[:k] + b[i:j] + b[k:])
    # JSON-level: replace a value somewhere with something odd
    odd = [None, True, -1, 0, 1e300, -1e300, 1e-300, 2 ** 64, "x", [], {}, [[[]]], 1.5, "NaN",
           2 ** 53 + 1, -0.0, 1e4, 1e-3, 99999]
    o = json.loads(base)
    target = o if kind == 3 or not o["leds"] else o["leds"][int(rng.integers(0, len(o["leds"])))]
    keys = list(target) + ["extra"]
    target[keys[int(rng.integers(0, len(keys)))]] = odd[int(rng.integers(0, len(odd)))]
    text = json.dumps(o)
    if kind == 5 and rng.random() < 0.5:              # non-strict tokens
        text = text.replace("1e+300", "Infinity", 1).replace("null", "NaN", 1)
    return text.encode()


def test_seeded_fuzz_of_the_datagram_parser(walk_map):
    """Random mutations of valid requests: every reply is a valid reply or an error reply with
    a known reason, strict JSON (never NaN), never an exception. A fixed count, never a clock:
    on a loaded machine a time bound made the last counter check depend on where it cut."""
    rng = np.random.default_rng(20240607)
    srv = LightingServer(walk_map, clock=FakeClock())
    ids, uv, d = scene(walk_map, C0, rng=np.random.default_rng(1))
    seen = set()
    count = 600
    for n in range(count):
        seq = n
        base_obj = request(f"fz-{n % 7}", seq, 0.01 * n, ids, uv, d)
        base_obj["leds"][0]["cx"] = 600.5
        base = encode(base_obj)
        data = _mutations(rng, base, base_obj) if n % 10 else base
        out = srv.handle_datagram(data, ("127.0.0.1", 5000 + n % 3))
        if out is None:
            seen.add("old_seq")
            continue
        reply = _finite_json(out)
        assert reply["v"] == 1
        if "error" in reply:
            assert reply["error"] in ERROR_REASONS and reply["error"] != "internal_error", reply
            seen.add(reply["error"])
        else:
            assert set(reply) == {"v", "device", "seq", "position", "unknown_ids", "n_used", "solve_R_cw"}
            seen.add("ok")
    assert {"ok", "bad_json", "bad_type", "bad_value"} <= seen, seen
    c = srv.counters
    assert c["datagrams"] == count and c["replies"] + c["old_seq"] == c["datagrams"]
