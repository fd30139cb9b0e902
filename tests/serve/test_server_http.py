"""`occloc serve --http HOST:PORT --db FILE`: the HTTP API (map, devices, track, stream,
healthz, metrics, bearer token) and the fix store (every accepted fix, flushed on SIGTERM, kept
across a restart, a keyed device's seq too), against real server processes."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

from receiver.cli import main as cli  # noqa: E402
from receiver.serve.auth import sign  # noqa: E402
from receiver.serve.wire import encode  # noqa: E402
from tests.serve.test_server import WALK, _first_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
KEY = bytes.fromhex("5a" * 32)


@contextlib.contextmanager
def serve(*args):
    """`occloc serve --port 0 --http 127.0.0.1:0 ARGS`: yields (process, udp URL, http URL)."""
    proc = subprocess.Popen([sys.executable, "-m", "receiver.cli", "serve", "--port", "0",
                             "--http", "127.0.0.1:0", *args], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        udp = _first_line(proc.stderr, 60.0)
        assert udp.startswith("occloc serve: listening on udp://127.0.0.1:"), udp
        http = _first_line(proc.stderr, 60.0)
        assert http.startswith("occloc serve: http on http://127.0.0.1:"), http
        assert _first_line(proc.stderr, 60.0).strip() == "occloc serve: ready"
        yield proc, udp.split()[-1], http.split()[-1].strip()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def stop(proc) -> str:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    return err.strip().splitlines()[-1]


def get(url: str, token: str | None = None):
    req = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}"} if token else {})
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            body = r.read()
            return r.status, r.headers.get("Content-Type", ""), body
    except urllib.error.HTTPError as e:
        return e.code, e.headers.get("Content-Type", ""), e.read()


def getj(url: str, token: str | None = None):
    status, _, body = get(url, token)
    assert status == 200, (url, status, body)
    return json.loads(body)


def _stream_reader(url: str, events: list, want: int, done: threading.Event) -> None:
    with urllib.request.urlopen(url, timeout=60) as r:
        for line in r:
            if line.startswith(b"data: "):
                events.append(json.loads(line[6:]))
                if len(events) >= want:
                    break
    done.set()


def test_http_api_storage_and_restart(tmp_path, capsys):
    db = tmp_path / "fixes.db"
    out = tmp_path / "r.jsonl"
    n = 6
    with serve("--db", str(db)) as (proc, udp, http):
        status, kind, body = get(http + "/healthz")
        assert status == 200 and body == b"ok\n"
        assert getj(http + "/api/v1/map") == json.loads((WALK / "map.json").read_text())
        assert getj(http + "/api/v1/devices") == []
        events: list = []
        done = threading.Event()
        reader = threading.Thread(target=_stream_reader, args=(http + "/api/v1/stream", events, n, done),
                                  daemon=True)
        reader.start()
        deadline = time.monotonic() + 30                      # the stream is subscribed
        while time.monotonic() < deadline and "occloc" not in get(http + "/metrics")[2].decode():
            time.sleep(0.05)
        time.sleep(0.5)
        assert cli(["run", str(WALK), "--max-frames", str(n), "--server", udp, "--server-timeout", "30",
                    "--out", str(out)]) == 0
        capsys.readouterr()
        positions = [json.loads(line)["position"] for line in out.read_text().splitlines()]
        assert len(positions) == n and all(p is not None for p in positions)
        (dev,) = getj(http + "/api/v1/devices")
        assert dev["position"] == positions[-1] and dev["datagrams"] == dev["positions"] == n
        assert 0 <= dev["age_s"] < 60
        assert done.wait(30), events
        assert [e["position"] for e in events] == positions and {e["device"] for e in events} == {dev["device"]}
        metrics = get(http + "/metrics")[2].decode()
        assert f"occloc_positions_total {n}" in metrics and "# TYPE occloc_datagrams_total counter" in metrics
        assert 'occloc_refused_total{reason="bad_json"} 0' in metrics
        assert get(http + "/api/v1/devices/x/track?since=abc")[0] == 400
        assert get(http + "/nope")[0] == 404
        summary = stop(proc)                                 # SIGTERM: the queue is flushed
    assert summary.startswith(f"occloc serve: {n} datagrams, {n} replies, {n} positions")
    with serve("--db", str(db)) as (proc, udp, http):        # a restart: the track is still there
        track = getj(http + f"/api/v1/devices/{dev['device']}/track")
        assert [r["position"] for r in track] == positions
        t = [r["t"] for r in track]
        assert t == sorted(t) and all(len(r["ids"]) >= 3 for r in track)
        part = getj(http + f"/api/v1/devices/{dev['device']}/track?since={t[2]}&until={t[4]}")
        assert [r["t"] for r in part] == t[2:5]
        assert getj(http + "/api/v1/devices/nobody/track") == []
        stop(proc)


def test_bearer_token(tmp_path):
    token_file = tmp_path / "token"
    token_file.write_text("s3cret-token-0123456789\n")
    with serve("--http-token-file", str(token_file)) as (proc, udp, http):
        assert get(http + "/api/v1/devices")[0] == 401
        assert get(http + "/metrics")[0] == 401
        assert get(http + "/api/v1/devices", "wrong-token-0123456789")[0] == 401
        assert getj(http + "/api/v1/devices", "s3cret-token-0123456789") == []
        assert get(http + "/api/v1/map?token=s3cret-token-0123456789")[0] == 200
        assert get(http + "/healthz")[0] == 200
        stop(proc)


def test_a_keyed_devices_seq_survives_a_restart(tmp_path, capsys):
    """A datagram captured before a restart is refused after it (the seq is in the database)."""
    keys = tmp_path / "keys"
    keys.write_text(f"phone-7 {KEY.hex()}\n")
    db = tmp_path / "fixes.db"
    with serve("--keys", str(keys), "--db", str(db)) as (proc, udp, http):
        assert cli(["run", str(WALK), "--max-frames", "3", "--server", udp, "--server-timeout", "30",
                    "--key-file", str(keys), "--out", str(tmp_path / "r.jsonl")]) == 0
        capsys.readouterr()
        (dev,) = getj(http + "/api/v1/devices")
        assert dev["device"] == "phone-7" and dev["positions"] == 3
        stop(proc)
    from receiver.serve.client import _connect
    with serve("--keys", str(keys), "--db", str(db)) as (proc, udp, http):
        sock = _connect(udp)
        try:
            body = encode({"v": 1, "device": "phone-7", "seq": 5, "t": 0.0, "sigma_uv": 3e-4, "leds": []})
            sock.send(sign(KEY, "phone-7", 5, body))              # validly signed, but an old seq
            body = encode({"v": 1, "device": "phone-7", "seq": 2 ** 52, "t": 0.0, "sigma_uv": 3e-4, "leds": []})
            sock.send(sign(KEY, "phone-7", 2 ** 52, body))        # a fresh seq: served
            sock.settimeout(30)
            reply = json.loads(sock.recv(65535))
            assert reply["seq"] == 2 ** 52 and "error" not in reply
        finally:
            sock.close()
        summary = stop(proc)
    assert "old_seq 1" in summary and "2 datagrams, 1 replies" in summary
