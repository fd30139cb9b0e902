"""The lighting server (`occloc serve`, receiver.serve.server) and its client (receiver.serve.client):
the v1 datagram protocol without sockets (valid, unknown IDs, every malformed kind, seq order,
forgetting, device cap), 50 devices at once over real UDP with garbage mixed in, RemotePositioner
step for step equal to a local Positioner, the command line, and a per-datagram benchmark.

Scenes are synthetic: a camera at a known pose under the bundled walk map's ceiling panels
(z = 3 m), LED centres projected with a pinhole (normalized u, v), ranges from the geometry with
1 mm noise. Every socket wait is bounded (REPLY_TIMEOUT_S), so a bug fails instead of hanging."""

from __future__ import annotations

import contextlib
import json
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

from receiver.cli import main as cli
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.core.errors import InputError
from receiver.locate.indoor import Positioner
from receiver.locate.pose import ypr_to_rotation
from receiver.serve.client import RemotePositioner, parse_udp_url
from receiver.core.records import LedObservation
from receiver.serve.wire import MAX_DATAGRAM_BYTES, MAX_LEDS, encode, make_request
from receiver.serve.server import BackgroundServer, LightingServer
from tests.locate.test_locate import mirrored_map, observe

ROOT = Path(__file__).resolve().parents[2]
WALK = ROOT / "recordings" / "indoor-walk"
SIGMA_UV = 3e-4          # 0.3 px at the walk camera's 1000 px focal length
SIGMA_M = 0.002
NOISE_M = 0.001
NOISE_UV = 1e-4
R_UP = ypr_to_rotation(10.0, 88.0, 2.0)     # a phone held up at the ceiling, slightly tilted
REPLY_TIMEOUT_S = 10.0

def _distances(res) -> dict:
    """track -> (distance_m, estimator) of a LocateResult's ranged LEDs."""
    return {o.track: (o.distance_m, o.distance_estimator) for o in res.leds if o.distance_m is not None}



@pytest.fixture(scope="module")
def walk_map():
    return load_map(str(WALK / "map.json"))


def _nearest(xyz: np.ndarray, C: np.ndarray, n: int) -> np.ndarray:
    """Indices of the n LEDs nearest above C; for n = 4 the 2 x 2 block of panels around it
    (never one row: collinear LEDs leave a rotation to the tilt prior)."""
    if n != 4:
        return np.argsort(np.linalg.norm(xyz[:, :2] - C[:2], axis=1))[:n]
    cols = [sorted(set(xyz[:, a]), key=lambda c: abs(c - C[a]))[:2] for a in (0, 1)]
    return np.flatnonzero(np.isin(xyz[:, 0], cols[0]) & np.isin(xyz[:, 1], cols[1]))


def scene(led_map, C, R=R_UP, rng=None, n=4):
    """(ids, uv (n, 2), d (n,)) of n LEDs above C (3,) (`_nearest`): pinhole projection of the
    LED centres (normalized, OpenCV camera frame) and ranges, with noise when `rng` is given."""
    leds = list(led_map.leds.values())
    xyz = np.array([led.xyz for led in leds])
    near = _nearest(xyz, C, n)
    L = xyz[near]
    Xc = (L - C) @ R.T
    uv = Xc[:, :2] / Xc[:, 2:]
    d = np.linalg.norm(L - C, axis=1)
    if rng is not None:
        uv = uv + rng.normal(0, NOISE_UV, uv.shape)
        d = d + rng.normal(0, NOISE_M, d.shape)
    return [leds[i].id for i in near], uv, d


def request(device, seq, t, ids, uv, d) -> dict:
    return make_request(device, seq, t, SIGMA_UV, ids, uv, d, np.full(len(ids), SIGMA_M))


def xyz(p) -> np.ndarray:
    return np.array([p["x"], p["y"], p["z"]])


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


# ---------------------------------------------------------------- protocol, no sockets

def test_valid_datagram_gives_the_position(walk_map):
    C = np.array([3.1, 4.2, 1.0])
    srv = LightingServer(walk_map)
    reply = srv.handle(encode(request("phone-1", 0, 0.0, *scene(walk_map, C, rng=np.random.default_rng(1)))))
    assert set(reply) == {"v", "device", "seq", "position", "unknown_ids", "n_used", "solve_R_cw"}
    assert (reply["v"], reply["device"], reply["seq"], reply["n_used"], reply["unknown_ids"]) == (1, "phone-1", 0, 4, [])
    p = reply["position"]
    assert p["method"] == "range+angle" and p["n_leds"] == 4
    assert np.linalg.norm(xyz(p["raw"]) - C) < 0.01
    assert np.linalg.norm(xyz(p) - C) < 0.01
    # Orientation: R_wc (map frame) is the transpose of the true world-to-camera rotation.
    assert np.allclose(np.array(p["R_wc"]).T, R_UP, atol=0.01)
    assert np.allclose(reply["solve_R_cw"], R_UP, atol=0.01)
    assert srv.counters["positions"] == 1 and srv.counters["replies"] == 1


def test_request_format_as_documented(walk_map):
    """A request written by hand as README.md documents it (not by make_request): optional
    pixel centroids, a camera block, an LED without a range (null) and one without the keys."""
    C = np.array([5.0, 6.1, 1.2])
    ids, uv, d = scene(walk_map, C, n=5)
    leds = [{"id": ids[i], "u": float(uv[i, 0]), "v": float(uv[i, 1]), "distance_m": float(d[i]),
             "sigma_m": SIGMA_M, "cx": 600.5, "cy": 300.25} for i in range(3)]
    leds.append({"id": ids[3], "u": float(uv[3, 0]), "v": float(uv[3, 1]), "distance_m": None, "sigma_m": None})
    leds.append({"id": ids[4], "u": float(uv[4, 0]), "v": float(uv[4, 1])})
    text = json.dumps({"v": 1, "device": "hand-written", "seq": 7, "t": 12.5, "sigma_uv": SIGMA_UV,
                       "leds": leds, "camera": {"model": "test", "focal_px": 1000}})
    reply = LightingServer(walk_map).handle(text.encode())
    assert reply["seq"] == 7 and reply["n_used"] == 5
    assert np.linalg.norm(xyz(reply["position"]) - C) < 0.005


def test_unknown_ids_are_reported_and_not_used(walk_map):
    C = np.array([7.3, 2.6, 0.9])
    ids, uv, d = scene(walk_map, C)
    # Two IDs the map does not know, with image points that would wreck the fix if used.
    ids, uv, d = ids + [99999, 7], np.vstack([uv, [[0.5, 0.5], [-0.4, 0.1]]]), np.append(d, [0.3, 9.0])
    reply = LightingServer(walk_map).handle(encode(request("p", 0, 0.0, ids, uv, d)))
    assert reply["unknown_ids"] == [7, 99999] and reply["n_used"] == 4
    assert np.linalg.norm(xyz(reply["position"]) - C) < 0.005


def _good(**change) -> dict:
    """A valid request of 4 LEDs with some fields replaced (None removes a field)."""
    req = {"v": 1, "device": "d", "seq": 0, "t": 0.0, "sigma_uv": SIGMA_UV,
           "leds": [{"id": 45842, "u": 0.01 * i, "v": -0.02 * i, "distance_m": 2.0, "sigma_m": SIGMA_M}
                    for i in range(4)]}
    for k, v in change.items():
        if v is None:
            del req[k]
        else:
            req[k] = v
    return req


def _led(**change) -> list:
    leds = _good()["leds"]
    leds[0] = {k: v for k, v in {**leds[0], **change}.items() if v is not None}
    return leds


def _js(obj) -> bytes:
    return json.dumps(obj).encode()


MALFORMED = [
    ("not JSON", b'{"v": 1, "device": ', "bad_json"),
    ("not UTF-8", b'\xff\xfe{"v": 1}', "bad_json"),
    ("NaN token", _js(_good()).replace(b'"t": 0.0', b'"t": NaN'), "bad_json"),
    ("Infinity token", _js(_good()).replace(b'"sigma_uv": 0.0003', b'"sigma_uv": Infinity'), "bad_json"),
    ("nested too deep", b"[" * 4000 + b"]" * 4000, "bad_json"),
    ("overflowing number", _js(_good()).replace(b'"t": 0.0', b'"t": 1e999'), "bad_value"),
    ("array", b"[1, 2, 3]", "not_object"),
    ("string", b'"hello"', "not_object"),
    ("v missing", _js(_good(v=None)), "bad_version"),
    ("v 3", _js(_good(v=3)), "bad_version"), ("v 2 without camera", _js(_good(v=2)), "missing_field"),
    ("v as string", _js(_good(v="1")), "bad_version"),
    ("v true", _js(_good(v=True)), "bad_version"),
    ("no device", _js(_good(device=None)), "missing_field"),
    ("no seq", _js(_good(seq=None)), "missing_field"),
    ("no t", _js(_good(t=None)), "missing_field"),
    ("no sigma_uv", _js(_good(sigma_uv=None)), "missing_field"),
    ("no leds", _js(_good(leds=None)), "missing_field"),
    ("LED without u", _js(_good(leds=_led(u=None))), "missing_field"),
    ("LED without id", _js(_good(leds=_led(id=None))), "missing_field"),
    ("device a number", _js(_good(device=5)), "bad_type"),
    ("seq a string", _js(_good(seq="3")), "bad_type"),
    ("seq a float", _js(_good(seq=3.0)), "bad_type"),
    ("t a bool", _js(_good(t=True)), "bad_type"),
    ("leds an object", _js(_good(leds={"id": 1})), "bad_type"),
    ("LED a number", _js(_good(leds=[5])), "bad_type"),
    ("u a string", _js(_good(leds=_led(u="0.1"))), "bad_type"),
    ("id a float", _js(_good(leds=_led(id=1.5))), "bad_type"),
    ("cx a string", _js(_good(leds=_led(cx="600"))), "bad_type"),
    ("camera a list", _js(_good(camera=[1])), "bad_type"),
    ("negative seq", _js(_good(seq=-1)), "bad_value"),
    ("empty device", _js(_good(device="")), "bad_value"),
    ("device too long", _js(_good(device="x" * 65)), "bad_value"),
    ("sigma_uv zero", _js(_good(sigma_uv=0)), "bad_value"),
    ("negative distance", _js(_good(leds=_led(distance_m=-2.0))), "bad_value"),
    ("distance without sigma", _js(_good(leds=_led(sigma_m=None))), "bad_value"),
    ("negative id", _js(_good(leds=_led(id=-4))), "bad_value"),
    ("u far off", _js(_good(leds=_led(u=1e6))), "bad_value"),
    ("id listed twice", _js(_good(leds=_good()["leds"] + [_good()["leds"][0]])), "bad_value"),
    ("too many LEDs", _js(_good(leds=[{"id": i, "u": 0.0, "v": 0.0} for i in range(MAX_LEDS + 1)])),
     "too_many_leds"),
    ("oversized", _js(_good(pad="x" * MAX_DATAGRAM_BYTES)), "oversized"),
]


@pytest.mark.parametrize("data, reason", [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED])
def test_malformed_datagrams_are_counted_and_dropped(walk_map, data, reason):
    srv = LightingServer(walk_map)
    reply = srv.handle(data)
    assert reply["v"] == 1 and reply["error"] == reason, reply
    assert srv.counters[reason] == 1 and srv.counters["datagrams"] == 1
    assert not srv.devices and srv.counters["positions"] == 0
    # The server goes on: a valid request is answered with a position.
    C = np.array([3.1, 4.2, 1.0])
    ok = srv.handle(encode(request("d", 0, 0.0, *scene(walk_map, C))))
    assert np.linalg.norm(xyz(ok["position"]) - C) < 0.005


def test_error_replies_name_the_request_when_they_can(walk_map):
    srv = LightingServer(walk_map)
    assert srv.handle(_js(_good(device="ph", seq=4, leds=_led(u="x")))) == {
        "v": 1, "error": "bad_type", "detail": "leds[0].u must be a number", "device": "ph", "seq": 4}
    seq_bad = srv.handle(_js(_good(device="ph", seq=-2)))
    assert seq_bad["device"] == "ph" and "seq" not in seq_bad
    assert set(srv.handle(b"[]")) == {"v", "error", "detail"}


def test_old_and_duplicate_seq_are_dropped_silently(walk_map):
    srv = LightingServer(walk_map)
    ids, uv, d = scene(walk_map, np.array([3.1, 4.2, 1.0]))
    send = lambda seq: srv.handle(encode(request("p", seq, 0.1 * seq, ids, uv, d)))  # noqa: E731
    assert send(5)["seq"] == 5
    assert send(5) is None          # duplicate
    assert send(3) is None          # out of order
    assert send(6)["seq"] == 6
    assert srv.counters["old_seq"] == 2 and srv.counters["replies"] == 2 and srv.counters["datagrams"] == 4


def test_silent_devices_are_forgotten(walk_map):
    clock = FakeClock()
    srv = LightingServer(walk_map, forget_s=5.0, clock=clock)
    rng = np.random.default_rng(3)

    def send(device, seq, C):
        return srv.handle(encode(request(device, seq, 0.1 * seq, *scene(walk_map, C, rng=rng))))

    send("b", 0, np.array([8.0, 8.0, 1.0]))
    for seq in range(3):                          # a moves: its filter has a velocity
        clock.now = float(seq)
        p = send("a", seq, np.array([3.0 + 0.05 * seq, 4.0, 1.0]))["position"]
    assert p["velocity_mps"][0] > 0.1 and p["x"] != p["raw"]["x"]
    clock.now = 7.0                               # a silent for exactly 5 s: still held
    assert send("a", 0, np.array([3.0, 4.0, 1.0])) is None
    assert srv.counters["old_seq"] == 1 and srv.counters["forgotten"] == 1     # only b
    assert list(srv.devices) == ["a"]
    clock.now = 7.01                              # now silent for more than 5 s: forgotten
    p = send("a", 0, np.array([3.2, 4.0, 1.0]))["position"]
    assert srv.counters["forgotten"] == 2 and srv.counters["new_devices"] == 3
    assert p["velocity_mps"] == [0.0, 0.0, 0.0] and p["x"] == p["raw"]["x"]   # a fresh filter


def test_max_devices(walk_map):
    clock = FakeClock()
    srv = LightingServer(walk_map, max_devices=2, forget_s=5.0, clock=clock)
    frame = scene(walk_map, np.array([3.1, 4.2, 1.0]))
    assert srv.handle(encode(request("a", 0, 0.0, *frame)))["position"] is not None
    assert srv.handle(encode(request("b", 0, 0.0, *frame)))["position"] is not None
    refused = srv.handle(encode(request("c", 0, 0.0, *frame)))
    assert (refused["error"], refused["device"], refused["seq"]) == ("too_many_devices", "c", 0)
    assert srv.handle(encode(request("a", 1, 0.1, *frame)))["position"] is not None   # known: served
    clock.now = 5.5                               # a and b forgotten: room again
    assert srv.handle(encode(request("c", 1, 0.2, *frame)))["position"] is not None
    assert srv.counters["too_many_devices"] == 1 and list(srv.devices) == ["c"]


def test_solver_failure_is_an_internal_error(walk_map, monkeypatch):
    srv = LightingServer(walk_map)
    frame = scene(walk_map, np.array([3.1, 4.2, 1.0]))
    assert srv.handle(encode(request("a", 0, 0.0, *frame)))["position"] is not None

    def boom(*a, **k):
        raise np.linalg.LinAlgError("singular")

    monkeypatch.setattr(srv, "_solvers", (boom, srv._solver()[1]))               # the batch fails,
    monkeypatch.setattr("receiver.locate.posefilter.PoseFilter.solve", boom)   # ... and the frame alone
    assert srv.handle(encode(request("a", 1, 0.1, *frame))) == {
        "v": 1, "error": "internal_error", "detail": "LinAlgError", "device": "a", "seq": 1}
    assert "a" not in srv.devices and srv.counters["internal_error"] == 1
    monkeypatch.undo()
    p = srv.handle(encode(request("a", 0, 0.2, *frame)))["position"]     # starts afresh at seq 0
    assert p is not None and p["velocity_mps"] == [0.0, 0.0, 0.0]


# ---------------------------------------------------------------- real UDP, many devices

N_DEVICES = 50
N_FRAMES = 20
DT_S = 0.1
VELOCITY = np.array([0.3, 0.2, 0.0])          # m/s, every device
POSITION_TOL_M = 0.02


def device_truth(k: int, i: int) -> np.ndarray:
    """Device k's camera centre at frame i: a 10 x 5 grid 0.9 m apart, all walking alike."""
    return np.array([1.0 + 0.9 * (k % 10), 1.5 + 0.9 * (k // 10), 1.0 + 0.01 * k]) + VELOCITY * DT_S * i


def _exchange(sock: socket.socket, data: bytes, seq: int | None) -> dict:
    """Send and wait (bounded) for the reply to `seq` (None: the next reply)."""
    sock.send(data)
    while True:
        reply = json.loads(sock.recv(65535))
        if seq is None or reply.get("seq") == seq:
            return reply


def _udp_client(address) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(REPLY_TIMEOUT_S)
    sock.connect(address)
    return sock


def _run_device(address, walk_map, k: int, out: list) -> None:
    rng = np.random.default_rng(100 + k)
    with _udp_client(address) as sock:
        for i in range(N_FRAMES):
            req = request(f"dev-{k:02d}", i, DT_S * i, *scene(walk_map, device_truth(k, i), rng=rng))
            out.append((i, _exchange(sock, encode(req), None)))


# (an error reply is never larger than its request: the garbage is padded with spaces, which
# JSON allows around a value, so that every one gets its reply)
GARBAGE = [(data + b" " * 160 if reason != "oversized" else data, reason) for _, data, reason in MALFORMED[::4]]


def _run_garbage(address, walk_map, out: list) -> None:
    with _udp_client(address) as sock:
        for data, reason in GARBAGE:
            out.append((reason, _exchange(sock, data, None)))
        # Duplicates and an out-of-order seq: dropped without a reply.
        frame = scene(walk_map, np.array([6.0, 6.0, 1.0]))
        out.append(("ok", _exchange(sock, encode(request("dup", 3, 0.3, *frame)), 3)))
        sock.send(encode(request("dup", 3, 0.3, *frame)))
        sock.send(encode(request("dup", 1, 0.1, *frame)))
        out.append(("ok", _exchange(sock, encode(request("dup", 4, 0.4, *frame)), 4)))


def test_fifty_devices_at_once_over_udp(walk_map):
    # The server's clock is frozen: no device may be forgotten however slowly the machine runs
    # (with the real clock and forget_s = 5, the garbage thread's device "dup" expired on a
    # slow machine before the last device had sent: 50 devices held instead of 51).
    # 51 devices on one host; error replies not rate-limited (the garbage's are all expected)
    srv = LightingServer(walk_map, clock=FakeClock(), source_rate=0, error_rate=1e6)
    results = {k: [] for k in range(N_DEVICES)}
    garbage: list = []
    failures: list = []

    def guarded(fn, *args):
        try:
            fn(*args)
        except Exception as e:  # noqa: BLE001 -- reported by the test below
            failures.append(repr(e))

    t0 = time.perf_counter()
    with BackgroundServer(srv) as bg:
        threads = [threading.Thread(target=guarded, args=(_run_device, bg.address, walk_map, k, results[k]))
                   for k in range(N_DEVICES)]
        threads.append(threading.Thread(target=guarded, args=(_run_garbage, bg.address, walk_map, garbage)))
        for th in threads:
            th.start()
        for th in threads:
            th.join(60.0)
        assert not any(th.is_alive() for th in threads)
    wall = time.perf_counter() - t0
    assert not failures, failures
    worst = 0.0
    for k, replies in results.items():
        assert [i for i, _ in replies] == list(range(N_FRAMES))
        for i, reply in replies:
            assert (reply["device"], reply["seq"], reply["n_used"]) == (f"dev-{k:02d}", i, 4)
            err = float(np.linalg.norm(xyz(reply["position"]) - device_truth(k, i)))
            worst = max(worst, err)
            assert err < POSITION_TOL_M, (k, i, err)
    for reason, reply in garbage:
        assert reply.get("error", "ok") == reason, reply
    n_garbage = len(GARBAGE) + 4
    c = srv.counters
    assert c["datagrams"] == N_DEVICES * N_FRAMES + n_garbage
    assert c["positions"] == N_DEVICES * N_FRAMES + 2
    assert c["replies"] == c["datagrams"] - 2 and c["old_seq"] == 2
    for reason in {r for _, r in GARBAGE}:
        assert c[reason] == sum(r == reason for _, r in GARBAGE)
    assert len(srv.devices) == N_DEVICES + 1 and c["socket_errors"] == 0
    print(f"\n{N_DEVICES} devices x {N_FRAMES} frames: {wall:.2f} s wall, worst error {100 * worst:.2f} cm")


# ---------------------------------------------------------------- RemotePositioner

# A warm-started server's fixes (the default) equal a local positioner's within the solver's
# tolerance: its stopping rule (relative cost decrease 1e-8) leaves a fix about 1e-4 of its own
# 1-sigma from the exact minimum, ~5 um for a 3-LED fix of 5 cm sigma. Allowed differences per
# field (`ulp=True`): positions 0.1 mm (the bound for a solver change), the other fields in
# proportion, plus WARM_REL of the value (a weak fix's sigma of 1.3 m moved by 4e-5 m). Measured on
# these tests: at most a quarter of each tolerance.
WARM_TOL = {"x": 1e-4, "y": 1e-4, "z": 1e-4, "velocity_mps": 3e-3, "yaw_deg": 1e-2, "pitch_deg": 1e-2,
            "roll_deg": 1e-2, "R_wc": 1e-4, "cov": 1e-7, "std_m": 2e-5, "raw_std_m": 2e-5, "distance_m": 2e-4}
WARM_REL = 1e-4


def _assert_same(a, b, path="position", ulp=False):
    """Equal JSON-like values, numbers within 1e-9 (ulp: within `WARM_TOL` of their field)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, a, b)
        for k in a:
            _assert_same(a[k], b[k], f"{path}.{k}", ulp)
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), (path, a, b)
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{path}[{i}]", ulp)
    elif isinstance(a, float) or isinstance(b, float):
        field = path.split(".")[-1].split("[")[0]
        tol = WARM_TOL[field] + WARM_REL * max(abs(a), abs(b)) if ulp else 1e-9
        assert abs(a - b) <= tol, (path, a, b)
    else:
        assert a == b, (path, a, b)


def _walk_frames(cam, led_map) -> list:
    """(t, observations) of a short walk with pixel noise, one frame with a single LED (the filter
    coasts), one without LEDs, one with an ID the map does not know."""
    rng = np.random.default_rng(11)
    ids = scene(led_map, np.array([3.3, 4.2, 1.0]), n=16)[0]
    frames = []
    for i in range(14):
        C = np.array([3.0 + 0.05 * i, 4.0 + 0.03 * i, 1.0])
        obs = observe(cam, led_map, C, ypr_to_rotation(3.0 * i, 88.0, 2.0), rng=rng, px_noise=0.2, ids=ids)
        if i == 4:
            obs = obs + [LedObservation(track=99, cx=640.0, cy=360.0, area_px=400.0,
                                        contour=np.zeros((0, 2)), id=4242)]
        frames.append((i / 30.0, obs[:1] if i == 8 else [] if i == 10 else obs))
    return frames


@pytest.mark.parametrize("warm", [False, True], ids=["cold", "warm"])
@pytest.mark.parametrize("mirror, declared", [(False, None), (True, None), (True, "left")],
                         ids=["right-detected", "left-detected", "left-declared"])
def test_remote_positioner_equals_the_local_one(walk_map, mirror, declared, warm):
    """Also for the walk map described left-handed (its orientation is reported mirrored, the
    server's reply carries the solving frame's); undeclared, the first frame tells it. A server
    solving from scratch gives the local numbers exactly; one warm-starting each fix from the
    device's previous pose (the default) within one unit of each field's rounding."""
    cam = load_camera(str(WALK / "camera.yaml"))
    frames = _walk_frames(cam, walk_map)
    assert min(len(o) for _, o in frames if len(o) > 1) >= 3
    led_map = mirrored_map(walk_map, declared) if mirror else walk_map
    local = Positioner(cam, led_map)
    # frames as fast as the machine runs, from one trusted source: no per-source limits
    with BackgroundServer(LightingServer(led_map, warm_start=warm, source_rate=0)) as bg, \
            RemotePositioner(cam, led_map, bg.url, timeout_s=REPLY_TIMEOUT_S, protocol=1) as remote:
        methods = []
        for t, obs in frames:
            a, b = local.step(t, obs), remote.step(t, obs)
            methods.append(a.position["method"])
            assert _distances(a).keys() == _distances(b).keys()
            for track, (d, name) in _distances(a).items():
                assert _distances(b)[track][1] == name
                assert abs(_distances(b)[track][0] - d) <= (1.001e-5 if warm else 1e-9), (track, d, _distances(b)[track][0])
            _assert_same(a.position, b.position, ulp=warm)
        assert remote.unknown_ids == local.unknown_ids == {4242}
        assert remote.n_fixes == local.n_fixes == len(frames) - 2
        assert remote.timeouts == 0 and remote.errors == 0
    assert methods[8] == methods[10] == "kalman-coast" and methods.count("range+angle") == len(frames) - 2
    assert local.pose.handedness == ("left" if mirror else "right")


def test_remote_positioner_timeouts_stale_replies_and_errors(walk_map):
    cam = load_camera(str(WALK / "camera.yaml"))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as fake:     # a server that never answers
        fake.bind(("127.0.0.1", 0))
        fake.settimeout(REPLY_TIMEOUT_S)
        host, port = fake.getsockname()
        with RemotePositioner(cam, walk_map, f"udp://{host}:{port}", device="dev", timeout_s=0.05, protocol=1) as rp:
            t0 = time.monotonic()
            assert rp.step(0.0, []).position is None
            assert rp.timeouts == 1 and time.monotonic() - t0 < 1.0
            sent = json.loads(fake.recvfrom(65535)[0])
            assert (sent["device"], sent["seq"], sent["leds"]) == ("dev", 0, [])
            # Queued before the next request: a late reply to seq 0, garbage, another device's
            # reply, then the reply to seq 1 -- only the last one counts.
            client = rp.sock.getsockname()
            for msg in ({"v": 1, "device": "dev", "seq": 0, "position": {"x": 9.0}},
                        b"garbage", {"v": 1, "device": "other", "seq": 1, "position": {"x": 8.0}},
                        {"v": 1, "device": "dev", "seq": 1, "position": {"x": 1.0, "y": 2.0, "z": 0.5, "raw": None},
                         "unknown_ids": [77], "n_used": 0, "solve_R_cw": None},
                        {"v": 1, "error": "too_many_devices", "device": "dev", "seq": 2}):
                fake.sendto(msg if isinstance(msg, bytes) else encode(msg), client)
            assert rp.step(0.1, []).position == {"x": 1.0, "y": 2.0, "z": 0.5, "raw": None}
            assert rp.unknown_ids == {77} and rp.n_fixes == 0 and rp.timeouts == 1
            assert rp.step(0.2, []).position is None          # the error reply to seq 2
            assert rp.errors == 1 and rp.last_error == "too_many_devices"
    with RemotePositioner(cam, walk_map, f"udp://{host}:{port}", timeout_s=0.5, protocol=1) as rp:   # port closed
        t0 = time.monotonic()
        for k in range(3):
            assert rp.step(0.1 * k, []).position is None
        assert rp.timeouts == 3 and time.monotonic() - t0 < 3 * 0.5 + 1.0


@pytest.mark.parametrize("url", ["http://127.0.0.1:9720", "udp://127.0.0.1", "udp://:9720",
                                 "udp://127.0.0.1:0", "udp://127.0.0.1:70000", "udp://h:x", "127.0.0.1:9720"])
def test_bad_server_urls(url):
    with pytest.raises(InputError, match="udp://HOST:PORT"):
        parse_udp_url(url)


def test_server_urls():
    assert parse_udp_url("udp://127.0.0.1:9720") == ("127.0.0.1", 9720)
    assert parse_udp_url("udp://[::1]:5000/") == ("::1", 5000)


# ---------------------------------------------------------------- command line

def _err_one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("occloc: ") and "\n" not in err and "Traceback" not in err, err
    return err


def _first_line(stream, timeout_s: float) -> str:
    q: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: q.put(stream.readline()), daemon=True).start()
    return q.get(timeout=timeout_s)


def _local_run(path: Path, n: int, **positioner_kw) -> None:
    """The first n frames of the walk through a local receiver, as `occloc run` writes them."""
    from receiver.core.records import Frame
    from receiver.io.output import frame_line
    from receiver.io.sources import open_source
    from receiver.pipeline import Receiver
    cam, led_map = load_camera(str(WALK / "camera.yaml")), load_map(str(WALK / "map.json"))
    rx = Receiver(cam, led_map, positioner=Positioner(cam, led_map, **positioner_kw))
    src = open_source(str(WALK / "video.avi"), camera=cam)
    try:
        lines = []
        for f in src:
            if len(lines) >= n:
                break
            lines.append(frame_line(rx.process(Frame(f.index, f.t_s, f.gray))))
    finally:
        src.close()
    path.write_text("".join(line + "\n" for line in lines))


def _positions(path: Path) -> list:
    return [{"frame": r["frame"], "position": r["position"], "distance_m": [d["distance_m"] for d in r["leds"]]}
            for r in map(json.loads, path.read_text().splitlines())]


@contextlib.contextmanager
def serve_process(*args):
    """`occloc serve --port 0 ARGS` as a subprocess: yields (process, its udp:// URL); killed at
    the end if still running."""
    proc = subprocess.Popen([sys.executable, "-m", "receiver.cli", "serve", "--port", "0", *args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        line = _first_line(proc.stderr, 60.0)
        assert line.startswith("occloc serve: listening on udp://127.0.0.1:"), line
        ready = _first_line(proc.stderr, 60.0)      # the solver is imported after the announcement
        assert ready.strip() == "occloc serve: ready", ready
        yield proc, line.split()[-1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def _stop(proc, sig) -> str:
    """Send `sig`; the server must exit 0. Its last stderr line (the summary)."""
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    return err.strip().splitlines()[-1]


def test_serve_and_run_with_server_equal_a_local_run(tmp_path, capsys):
    with serve_process() as (proc, url):
        # A generous reply wait: on a loaded machine 0.2 s is not always enough (not a speed test).
        assert cli(["run", str(WALK), "--max-frames", "10", "--server", url, "--server-timeout", "30",
                    "--out", str(tmp_path / "r.jsonl")]) == 0
        assert "server" not in capsys.readouterr().err          # no timeouts, no errors
        summary = _stop(proc, signal.SIGINT)
    assert summary.startswith("occloc serve: 10 datagrams, 10 replies") and "dropped/refused: none" in summary
    # The v2 datagram carries the observations with their edge points: the server runs the local
    # positioner (outline solve included) and gives the local run's numbers.
    _local_run(tmp_path / "l.jsonl", 10)
    remote, local = _positions(tmp_path / "r.jsonl"), _positions(tmp_path / "l.jsonl")
    assert len(remote) == 10 and sum(r["position"] is not None for r in local) >= 5
    _assert_same(local, remote)


def test_serve_stops_on_sigterm_with_a_summary():
    with serve_process("--forget-s", "1") as (proc, url):
        with _udp_client(parse_udp_url(url)) as sock:
            # (an error reply is never larger than its request: a 5-byte one gets none)
            assert _exchange(sock, b"{oops" + b" " * 100, None)["error"] == "bad_json"
        summary = _stop(proc, signal.SIGTERM)
    assert summary == ("occloc serve: 1 datagrams, 1 replies, 0 positions; devices: 0 new, "
                       "0 forgotten, 0 held; dropped/refused: bad_json 1")


def test_server_timeout_without_a_server_is_an_error(capsys):
    assert cli(["run", str(WALK), "--server-timeout", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--server-timeout needs --server" in err[0]


def test_run_counts_server_timeouts(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert cli(["run", str(WALK), "--max-frames", "3", "--server", f"udp://127.0.0.1:{port}"]) == 0
    out, err = capsys.readouterr()
    assert [json.loads(line)["position"] for line in out.splitlines()] == [None] * 3
    assert err.strip().splitlines()[-1].endswith("; server timeouts: 3")


def test_command_line_errors_are_one_line(capsys):
    assert cli(["run", str(WALK), "--server", "http://127.0.0.1:9720"]) == 2
    assert "udp://HOST:PORT" in _err_one_line(capsys)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        assert cli(["serve", "--port", str(port)]) == 2
        assert f"cannot listen on udp://127.0.0.1:{port}" in _err_one_line(capsys)
    assert cli(["serve", "--host", "192.0.2.1", "--port", "0"]) == 2      # not this machine's address
    assert "cannot listen" in _err_one_line(capsys)
    assert cli(["serve", "--port", "70000"]) == 2
    assert "--port" in _err_one_line(capsys)
    assert cli(["serve", "--forget-s", "0"]) == 2
    _err_one_line(capsys)
    assert cli(["serve", "--max-devices", "0"]) == 2
    _err_one_line(capsys)


# ---------------------------------------------------------------- benchmark

def test_handle_datagram_benchmark(walk_map, benchmark):
    """One 4-LED datagram: parse, map lookup, fix, Kalman update, reply (no socket)."""
    srv = LightingServer(walk_map)
    C = np.array([3.1, 4.2, 1.0])
    ids, uv, d = scene(walk_map, C, rng=np.random.default_rng(5))
    seqs = iter(range(10 ** 9))

    def next_datagram():
        seq = next(seqs)
        return (encode(request("bench", seq, seq / 30.0, ids, uv, d)),), {}

    reply = benchmark.pedantic(srv.handle, setup=next_datagram, rounds=200)
    assert np.linalg.norm(xyz(reply["position"]) - C) < 0.005


def test_queued_datagrams_are_answered_in_batches(walk_map):
    """serve_socket takes every datagram already queued: 120 datagrams of 12 devices (10 each,
    a device's in seq order) waiting before it starts are handled in a few batches, each answered
    once with the position a server handling them one by one gives (to WARM_TOL)."""
    from receiver.serve.loadcore import four_led_datagrams
    dg = four_led_datagrams(walk_map, 120, 12)
    srv, replies = _serve_queued(walk_map, dg)
    seqs = {}
    for r in replies:                                 # a device's replies in its seq order
        assert r["seq"] > seqs.get(r["device"], -1)
        seqs[r["device"]] = r["seq"]
    assert srv.counters["batches"] <= 20 and srv.counters["replies"] == 120


def _serve_queued(walk_map, dg):
    """(server, replies) of `serve_socket` started with every datagram of `dg` (device, seq,
    bytes) already queued in its socket; asserts each is answered once with the position a
    server handling them one by one gives (to WARM_TOL)."""
    from receiver.serve.server import bind_udp, serve_socket
    one_by_one = LightingServer(walk_map, clock=FakeClock())
    expected = {(dev, seq): one_by_one.handle(data) for dev, seq, data in dg}
    srv = LightingServer(walk_map, clock=FakeClock())
    sock = bind_udp("127.0.0.1", 0)
    stop = threading.Event()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.settimeout(REPLY_TIMEOUT_S)
        # Room for all the replies (~100 kB, more as the kernel counts it): the server thread may
        # send them all before this thread gets the GIL back, and a full buffer drops datagrams.
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        for _, _, data in dg:
            client.sendto(data, sock.getsockname())
        worker = threading.Thread(target=serve_socket, args=(srv, sock, stop), daemon=True)
        worker.start()
        try:
            replies = [json.loads(client.recv(65536)) for _ in dg]
        finally:
            stop.set()
            worker.join(5.0)
            sock.close()
    assert sorted((r["device"], r["seq"]) for r in replies) == sorted(expected)
    for r in replies:
        _assert_same(expected[r["device"], r["seq"]]["position"], r["position"], ulp=True)
    return srv, replies


def test_batches_end_at_their_byte_bound(walk_map):
    """Large datagrams (64 LEDs, ~7 kB) queued together are taken a few at a time (a batch ends
    after the datagram that reaches MAX_BATCH_BYTES), so a small datagram behind them waits for
    little work; every one is answered with the position one-by-one handling gives."""
    from receiver.serve.loadcore import four_led_datagrams
    from receiver.serve.server import MAX_BATCH_BYTES
    dg = four_led_datagrams(walk_map, 40, 4, n_leds=64)
    size = min(len(data) for _, _, data in dg)
    per_batch = -(-MAX_BATCH_BYTES // size)             # datagrams that reach the bound, at most
    assert 1 < per_batch < 16
    srv, _ = _serve_queued(walk_map, dg)
    assert srv.counters["batches"] >= len(dg) / per_batch and srv.counters["replies"] == len(dg)


def test_a_sources_queued_flood_does_not_go_before_another_sources_datagram(walk_map):
    """40 64-LED datagrams from one host queued before a 4-LED one from another host: the
    sources are taken in turn, so the other host's datagram is solved second (not 41st), and
    every datagram is answered. The order comes from the server's own fix observer."""
    from receiver.serve.loadcore import four_led_datagrams
    from receiver.serve.server import bind_udp, serve_socket
    flood = four_led_datagrams(walk_map, 40, 4, n_leds=64, prefix="flood-")
    honest = four_led_datagrams(walk_map, 1, 1, prefix="honest-")
    srv = LightingServer(walk_map, clock=FakeClock())
    order = []
    srv.on_fix = lambda device, *_: order.append(device)
    sock = bind_udp("127.0.0.1", 0)
    stop = threading.Event()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as b:
        for client, host in ((a, "127.0.0.2"), (b, "127.0.0.3")):
            client.bind((host, 0))
            client.settimeout(REPLY_TIMEOUT_S)
            client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        for _, _, data in flood:
            a.sendto(data, sock.getsockname())
        b.sendto(honest[0][2], sock.getsockname())
        worker = threading.Thread(target=serve_socket, args=(srv, sock, stop), daemon=True)
        worker.start()
        try:
            reply = json.loads(b.recv(65536))
            flood_replies = [json.loads(a.recv(65536)) for _ in flood]
        finally:
            stop.set()
            worker.join(5.0)
            sock.close()
    assert reply["device"] == "honest-0" and reply["position"] is not None
    assert all(r["position"] is not None for r in flood_replies)
    assert len(order) == 41 and order.index("honest-0") == 1, order[:5]
    assert [d for d in order if d != "honest-0"] == [dev for dev, _, _ in flood]     # a host's order kept


def test_source_queues_bound_each_host_and_the_whole():
    from receiver.serve.queues import SourceQueues
    q = SourceQueues(max_host_bytes=10, max_bytes=25)
    assert q.put(b"aaaa", ("h1", 1)) and q.put(b"bbbb", ("h1", 2)) and not q.put(b"ccc", ("h1", 1))
    assert q.put(b"dddddddd", ("h2", 1)) and q.put(b"ee", ("h1", 3))
    assert not q.put(b"ffffffff", ("h3", 1)) and q.put(b"fffffff", ("h3", 1))
    assert (q.count, q.nbytes) == (5, 25)
    assert [d for d, _ in q.take(10, 100)] == [b"aaaa", b"dddddddd", b"fffffff", b"bbbb", b"ee"]
    assert (q.count, q.nbytes) == (0, 0) and q.put(b"ccc", ("h1", 1))
    assert q.take(10, 1) == [(b"ccc", ("h1", 1))] and q.take(10, 1) == []


def test_serve_socket_ends_when_its_socket_is_closed(walk_map):
    """A socket closed under the loop (a persistent error) ends it instead of spinning on the
    error away from the stop check: the thread is gone without `stop` being set."""
    from receiver.serve.server import bind_udp, serve_socket
    srv = LightingServer(walk_map, clock=FakeClock())
    sock = bind_udp("127.0.0.1", 0)
    stop = threading.Event()
    worker = threading.Thread(target=serve_socket, args=(srv, sock, stop), daemon=True)
    worker.start()
    sock.close()
    worker.join(30.0)
    alive = worker.is_alive()
    stop.set()
    assert not alive and srv.counters["socket_errors"] <= 2


def test_a_failing_batch_is_answered_one_by_one(walk_map, monkeypatch):
    """Should the batched path raise (a bug's guard), every datagram of the batch is still
    answered, each handled alone."""
    from receiver.serve.loadcore import four_led_datagrams
    from receiver.serve.server import _handle_batch
    dg = four_led_datagrams(walk_map, 8, 4)
    srv = LightingServer(walk_map, clock=FakeClock())

    def broken(_batch):
        raise RuntimeError("batched path broken")
    monkeypatch.setattr(srv, "handle_datagrams", broken)
    outs = _handle_batch(srv, [(data, ("127.0.0.1", 9)) for _, _, data in dg])
    replies = [json.loads(o) for o in outs]
    assert len(replies) == 8 and all(r.get("position") is not None or "error" not in r for r in replies)
    assert [(r["device"], r["seq"]) for r in replies] == [(dev, seq) for dev, seq, _ in dg]


def test_handle_batch_benchmark(walk_map, benchmark):
    """16 queued 4-LED datagrams of 16 walking devices handled together, as `serve_socket` does
    under load (`handle_datagrams`: one batched warm-started solve): divide by 16 for the cost
    of one datagram. Every reply is a warm-started range+angle position."""
    from receiver.serve.loadcore import four_led_datagrams
    # one trusted source at any rate (the per-source bucket would run dry on the frozen clock)
    srv = LightingServer(walk_map, clock=FakeClock(), source_rate=0)
    dg = [(data, ("127.0.0.1", 9)) for _, _, data in four_led_datagrams(walk_map, 16 * 240, 16)]
    srv.handle_datagrams(dg[:16 * 20])                   # every device has a track
    batches = iter(range(20, 240))

    def next_batch():
        k = next(batches)
        return (dg[16 * k:16 * (k + 1)],), {}

    out = benchmark.pedantic(srv.handle_datagrams, setup=next_batch, rounds=200)
    replies = [json.loads(o) for o in out]
    assert len(replies) == 16 and all(r["position"]["method"] == "range+angle" for r in replies)
    assert srv.counters["internal_error"] == 0


def test_server_load_benchmark(walk_map, benchmark, request):
    """4-LED datagrams at 3,000/s over loopback to `occloc serve` in its own process
    (receiver.serve.loadgen); reports replies/s and the reply latency. Only with
    --benchmark-enable: it measures this machine. Without it, a slow functional run of the same
    path (40 datagrams at 40/s, up to 60 s for the replies): every datagram is answered."""
    from receiver.serve.loadcore import four_led_datagrams, run_load, start_server
    timed = request.config.getoption("benchmark_enable", False)
    rate, n, drain_s = (3000.0, 6000, 1.0) if timed else (40.0, 40, 60.0)
    dg = four_led_datagrams(walk_map, n, devices=50 if timed else 4)
    proc, address = start_server()
    try:
        report = benchmark.pedantic(run_load, args=(address, dg, rate, drain_s), rounds=1, iterations=1)
    finally:
        proc.kill()
        proc.wait(10)
    benchmark.extra_info.update(report)
    print(report)
    assert report["replies"] > 0 and report["p99_ms"] is not None
    if not timed:
        assert report["lost"] == 0, report
