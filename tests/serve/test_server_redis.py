"""`occloc serve --state redis://...`: two server processes share their devices through a real
Redis server (started here on a free port); a device moves from one to the other between
datagrams and when one is killed mid-stream, and its replies are those one server alone gives;
either server's HTTP API lists it and its stream relays the other's fixes; Redis's expiry
forgets a silent device for both."""

from __future__ import annotations

import json
import shutil
import signal
import socket
import subprocess
import threading
import time

import numpy as np
import pytest

from receiver.io.ledmap import load_map
from receiver.serve.client import parse_udp_url
from receiver.serve.server import LightingServer
from receiver.serve.wire import encode
from tests.serve.test_server import WALK, FakeClock, request, scene
from tests.serve.test_server_http import _stream_reader, getj, serve, stop

pytest.importorskip("redis")
REDIS = shutil.which("redis-server")
if REDIS is None:
    pytest.skip("no redis-server (tools/dev test installs it)", allow_module_level=True)

N_FRAMES = 24


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def redis_url(tmp_path):
    import redis

    port = _free_port()
    proc = subprocess.Popen([REDIS, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
                             "--dir", str(tmp_path)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        client = redis.Redis(port=port)
        deadline = time.monotonic() + 30
        while True:
            try:
                client.ping()
                break
            except redis.ConnectionError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise
                time.sleep(0.05)
        client.close()
        yield f"redis://127.0.0.1:{port}/0"
    finally:
        proc.terminate()
        proc.wait(10)


def _datagrams(walk_map) -> list[bytes]:
    rng = np.random.default_rng(5)
    return [encode(request("phone-3", i, i / 30.0, *scene(walk_map, np.array([3.0 + 0.02 * i, 4.0, 1.0]), rng=rng)))
            for i in range(N_FRAMES)]


def _exchange(sock, url: str, data: bytes) -> dict:
    sock.sendto(data, parse_udp_url(url))
    while True:
        reply = json.loads(sock.recv(65535))
        if reply.get("device") == "phone-3":
            return reply


def test_two_servers_share_devices_and_one_is_killed_mid_stream(redis_url):
    walk_map = load_map(str(WALK / "map.json"))
    data = _datagrams(walk_map)
    alone = LightingServer(walk_map, clock=FakeClock())
    want = [json.loads(alone.handle_datagram(d, ("127.0.0.1", 1))) for d in data]
    got = []
    with serve("--state", redis_url) as (a, udp_a, http_a), serve("--state", redis_url) as (b, udp_b, http_b), \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(30)
        events: list = []
        done = threading.Event()
        threading.Thread(target=_stream_reader, args=(http_b + "/api/v1/stream", events, 8, done), daemon=True).start()
        time.sleep(1.0)                                   # B's stream is subscribed
        for i in range(8):                                # alternating between the two servers
            got.append(_exchange(sock, udp_a if i % 2 == 0 else udp_b, data[i]))
        for i in range(8, 16):                            # A alone
            got.append(_exchange(sock, udp_a, data[i]))
        assert done.wait(30) and len(events) == 8         # B relayed A's fixes (and has its own)
        listed = getj(http_b + "/api/v1/devices")
        assert [d["device"] for d in listed] == ["phone-3"] and listed[0]["position"] == got[15]["position"]
        a.send_signal(signal.SIGKILL)                     # A dies mid-stream; B takes the device over
        a.wait(10)
        for i in range(16, N_FRAMES):
            got.append(_exchange(sock, udp_b, data[i]))
        assert getj(http_b + "/api/v1/devices")[0]["position"] == got[-1]["position"]
        summary = stop(b)
    assert [g["seq"] for g in got] == list(range(N_FRAMES))
    for g, w in zip(got, want):
        assert g["position"] == w["position"], (g["seq"], g["position"], w["position"])
    assert summary.startswith("occloc serve: 12 datagrams, 12 replies, 12 positions")   # B's share


def test_redis_expiry_forgets_a_device_for_every_server(redis_url):
    walk_map = load_map(str(WALK / "map.json"))
    data = _datagrams(walk_map)
    with serve("--state", redis_url, "--forget-s", "0.5") as (a, udp_a, _), \
            serve("--state", redis_url, "--forget-s", "0.5") as (b, udp_b, _), \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
        sock.bind(("127.0.0.1", 0))
        other.bind(("127.0.0.1", 0))
        sock.settimeout(30)
        other.settimeout(30)
        assert "error" not in _exchange(sock, udp_a, data[0])
        # bound to its first address on both servers while it lives
        assert _exchange(other, udp_b, data[1])["error"] == "wrong_source"
        time.sleep(1.5)                                   # silent past forget_s: expired in Redis
        assert "error" not in _exchange(other, udp_b, data[0])   # the name is free again, seq anew
        stop(a)
        stop(b)


def test_bad_state_urls(capsys):
    from receiver.cli import main as cli

    for url in ("http://x:1/0", "redis://127.0.0.1/0", "redis://127.0.0.1:1/x"):
        assert cli(["serve", "--port", "0", "--state", url]) == 2
        assert "--state must be redis://HOST:PORT/DB" in capsys.readouterr().err
    assert cli(["serve", "--port", "0", "--state", f"redis://127.0.0.1:{_free_port()}/0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("occloc: --state redis://") and "\n" not in err


def test_two_servers_on_one_port_with_reuse_port(redis_url):
    """SO_REUSEPORT: the kernel spreads the sources over both processes; every datagram gets
    its position, and the two summaries add up to what was sent."""
    walk_map = load_map(str(WALK / "map.json"))
    port = _free_port()
    rng = np.random.default_rng(9)
    args = ("--state", redis_url, "--reuse-port", "--port", str(port))
    with serve(*args) as (a, udp_a, _), serve(*args) as (b, udp_b, _):
        assert udp_a == udp_b == f"udp://127.0.0.1:{port}"
        socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(8)]
        try:
            for k, sock in enumerate(socks):
                sock.bind(("127.0.0.1", 0))
                sock.settimeout(30)
                for i in range(3):
                    frame = scene(walk_map, np.array([3.0 + 0.1 * k, 4.0, 1.0]), rng=rng)
                    sock.sendto(encode(request(f"dev-{k}", i, i / 30.0, *frame)), ("127.0.0.1", port))
                    reply = json.loads(sock.recv(65535))
                    assert reply["device"] == f"dev-{k}" and reply["position"] is not None
        finally:
            for sock in socks:
                sock.close()
        counts = [int(stop(p).split()[2]) for p in (a, b)]
    assert sum(counts) == 24


def test_stored_state_round_trips_and_an_unchanged_value_keeps_the_servers_object(redis_url):
    """Two servers' shared states on one Redis: a device written by A and read back unchanged
    is A's own object (not unpickled again); once B has served it, A reads B's newer state (a
    new object whose positioner refers to A's own map); a fix event joined from the position's
    JSON is the bytes json.dumps gives for the same event."""
    from receiver.serve.shared import SharedState
    from tests.serve.test_server_v2 import _v2_request

    walk_map = load_map(str(WALK / "map.json"))
    state_a, state_b = SharedState(redis_url, walk_map, 60.0), SharedState(redis_url, walk_map, 60.0)
    a = LightingServer(walk_map, clock=FakeClock(), shared=state_a)
    b = LightingServer(walk_map, clock=FakeClock(), shared=state_b)
    try:
        first = json.loads(_v2_request())
        assert "error" not in a.handle(encode(first), ("127.0.0.1", 5))
        devs, _ = state_a.load(["dev"], a.devices)
        assert devs["dev"] is a.devices["dev"]
        nxt = {**first, "seq": 1, "t": 1 / 30}
        reply_b = b.handle(encode(nxt), ("127.0.0.1", 5))
        assert reply_b["position"] is not None
        devs, _ = state_a.load(["dev"], a.devices)
        assert devs["dev"] is not a.devices["dev"] and devs["dev"].seq == 1
        assert devs["dev"].loc.led_map is walk_map
        assert b.devices["dev"].loc.led_map is walk_map
        position = reply_b["position"]
        state_a._events.clear()
        state_a.publish_fix("dev \"q\"", 1765000000.25, 1 / 30, encode(position), [7, 42])
        state_a.publish("dev \"q\"", {"device": "dev \"q\"", "t": 1765000000.25, "t_device": 1 / 30,
                                      "position": position, "ids": [7, 42]})
        joined, dumped = state_a._events
        assert joined == dumped and json.loads(joined)["position"] == position
    finally:
        state_a.close()
        state_b.close()
