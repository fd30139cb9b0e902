"""Devices that cannot be impersonated, and a server no stranger can steer: device keys (a MAC
over each datagram, checked before the JSON is read), an unkeyed name bound to its first source
address, bounded seq jumps, no replay after forgetting, per-source rate limits, and error
replies that are rate-limited and never larger than their request."""

from __future__ import annotations

import secrets
import signal
import subprocess
import sys

import numpy as np
import pytest

from receiver.cli import main as cli
from receiver.core.errors import InputError
from receiver.io.ledmap import load_map
from receiver.serve.auth import load_device_key, load_keys, sign
from receiver.serve.server import ERROR_REPLY_RATE, SEQ_WINDOW, LightingServer
from receiver.serve.wire import MAX_SEQ, encode
from tests.serve.test_server import WALK, FakeClock, _first_line, request, scene, xyz

KEY = bytes.fromhex("8f" * 32)
HONEST = ("10.0.0.7", 5000)
ATTACKER = ("10.6.6.6", 4444)


@pytest.fixture(scope="module")
def walk_map():
    return load_map(str(WALK / "map.json"))


def _frame(walk_map, i, C=None, seq=None, device="phone-7"):
    C = np.array([3.0 + 0.02 * i, 4.0, 1.0]) if C is None else C
    return encode(request(device, i if seq is None else seq, i / 30.0,
                          *scene(walk_map, C, rng=np.random.default_rng(i))))


def _signed(walk_map, i, key=KEY, **kw):
    seq = kw.get("seq", i)
    return sign(key, kw.get("device", "phone-7"), seq, _frame(walk_map, i, **kw))


def test_spoofed_datagrams_never_change_a_keyed_devices_position(walk_map):
    """The honest device's replies with an attacker sending between its frames equal those of a
    server without the attacker, bit for bit; every forgery is refused and counted."""
    far = np.array([8.0, 8.0, 1.0])
    control = LightingServer(walk_map, keys={"phone-7": KEY}, clock=FakeClock())
    attacked = LightingServer(walk_map, keys={"phone-7": KEY}, clock=FakeClock())
    captured = _signed(walk_map, 0)
    for i in range(12):
        honest = _signed(walk_map, i)
        want = control.handle_datagram(honest, HONEST)
        assert attacked.handle_datagram(honest, HONEST) == want
        assert b'"position":{' in want
        forged = [
            _frame(walk_map, i + 1, C=far),                         # unsigned, the next seq
            _frame(walk_map, i + 1, C=far, seq=MAX_SEQ),            # unsigned, a lock-out seq
            _signed(walk_map, i + 1, key=b"\x01" * 32, C=far),      # signed with another key
            captured,                                               # a replay of frame 0
            honest,                                                 # a replay of this frame
            _signed(walk_map, i + 1, C=far)[:-3] + b"  }",          # signed, body altered
        ]
        for data in forged:
            reply = attacked.handle(data, ATTACKER)
            assert reply is None or "error" in reply
    c = attacked.counters
    assert c["bad_mac"] == 12 * 4 and c["old_seq"] == 12 * 2
    assert attacked.devices["phone-7"].seq == control.devices["phone-7"].seq == 11
    assert attacked.key_seq == {"phone-7": 11}


def test_a_keyed_device_is_not_replayed_after_it_is_forgotten(walk_map):
    clock = FakeClock()
    srv = LightingServer(walk_map, keys={"phone-7": KEY}, clock=clock)
    first = _signed(walk_map, 5)
    assert srv.handle(first, HONEST)["position"] is not None
    clock.now = 100.0                                        # silent: forgotten
    assert srv.handle(_signed(walk_map, 3), ATTACKER) is None   # a captured older datagram
    assert srv.handle(first, ATTACKER) is None
    assert srv.counters["old_seq"] == 2 and not srv.devices
    assert srv.handle(_signed(walk_map, 6), ("10.0.0.8", 6000))["position"] is not None   # roams


def test_an_unkeyed_name_is_bound_to_its_first_source_until_forgotten(walk_map):
    clock = FakeClock()
    srv = LightingServer(walk_map, clock=clock)
    assert srv.handle(_frame(walk_map, 0), HONEST)["position"] is not None
    before = xyz(srv.handle(_frame(walk_map, 1), HONEST)["position"])
    for seq in (2, MAX_SEQ):
        assert srv.handle(_frame(walk_map, 2, C=np.array([8.0, 8.0, 1.0]), seq=seq), ATTACKER)["error"] == "wrong_source"
    assert srv.handle(_frame(walk_map, 2, seq=2), (HONEST[0], 5001))["error"] == "wrong_source"   # another port
    assert srv.counters["wrong_source"] == 3
    after = xyz(srv.handle(_frame(walk_map, 2), HONEST)["position"])
    assert np.linalg.norm(after - before) < 0.1                # the honest track went on undisturbed
    clock.now = 100.0                                          # forgotten: the name is free again
    assert "error" not in srv.handle(_frame(walk_map, 0), ATTACKER)


def test_seq_jumps_are_bounded(walk_map):
    srv = LightingServer(walk_map, clock=FakeClock())
    assert "error" not in srv.handle(_frame(walk_map, 0, seq=10), HONEST)
    assert srv.handle(_frame(walk_map, 1, seq=11 + SEQ_WINDOW), HONEST)["error"] == "seq_jump"
    assert srv.devices["phone-7"].seq == 10
    assert "error" not in srv.handle(_frame(walk_map, 1, seq=10 + SEQ_WINDOW), HONEST)


def test_error_replies_are_limited_and_never_larger_than_the_request(walk_map):
    srv = LightingServer(walk_map, clock=FakeClock())
    assert srv.handle(b"x", ATTACKER) is None                  # a 1-byte datagram: no reply
    assert srv.handle_datagram(b"{" + b" " * 30, ATTACKER) is None or \
        len(srv.handle_datagram(b"{" + b" " * 30, ("10.9.9.9", 1))) <= 31
    srv = LightingServer(walk_map, clock=FakeClock())
    bad = b'{"v": 1, "device": "x"}' + b" " * 200
    replies = [srv.handle_datagram(bad, ATTACKER) for _ in range(50)]
    sent = [r for r in replies if r is not None]
    assert len(sent) == 2 * ERROR_REPLY_RATE and all(len(r) <= len(bad) for r in sent)
    assert srv.counters["missing_field"] == 50
    assert srv.handle_datagram(bad, HONEST) is not None          # another host has its own budget


def test_one_sources_flood_is_dropped_unread_and_others_are_served(walk_map):
    srv = LightingServer(walk_map, clock=FakeClock(), source_rate=10)
    flood = [srv.handle(_frame(walk_map, i, device=f"flood-{i % 4}", seq=i), ATTACKER) for i in range(100)]
    assert sum(r is not None for r in flood) == 20 and srv.counters["rate_limited"] == 80
    assert srv.handle(_frame(walk_map, 0), HONEST)["position"] is not None


def test_keys_files(tmp_path):
    good = tmp_path / "keys"
    good.write_text(f"# fleet\nphone-7 {KEY.hex()}\n\nphone-8 {secrets.token_hex(16)}\n")
    assert set(load_keys(str(good))) == {"phone-7", "phone-8"}
    one = tmp_path / "phone-7.key"
    one.write_text(f"phone-7 {KEY.hex()}\n")
    assert load_device_key(str(one)) == ("phone-7", KEY)
    for text in ("", "phone-7\n", "phone-7 zz\n", "phone-7 0011\n", f"a {KEY.hex()}\na {KEY.hex()}\n",
                 "\xe9 00\n"):
        bad = tmp_path / "bad"
        bad.write_text(text)
        with pytest.raises(InputError):
            load_keys(str(bad))
    with pytest.raises(InputError, match="one DEVICE HEXKEY"):
        load_device_key(str(good))


def test_serve_keys_and_run_key_file(tmp_path, capsys):
    """`occloc serve --keys F` and `occloc run --server URL --key-file F`: the keyed run is
    served; a run signing with a wrong key is refused (`bad_mac`) and told so on stderr."""
    keys = tmp_path / "keys"
    keys.write_text(f"phone-7 {KEY.hex()}\n")
    wrong = tmp_path / "wrong.key"
    wrong.write_text(f"phone-7 {'11' * 32}\n")
    proc = subprocess.Popen([sys.executable, "-m", "receiver.cli", "serve", "--port", "0", "--keys", str(keys)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        url = _first_line(proc.stderr, 60.0).split()[-1]
        assert _first_line(proc.stderr, 60.0).strip() == "occloc serve: ready"
        assert cli(["run", str(WALK), "--max-frames", "3", "--server", url, "--server-timeout", "30",
                    "--key-file", str(keys), "--out", str(tmp_path / "r.jsonl")]) == 0
        assert "server" not in capsys.readouterr().err
        assert cli(["run", str(WALK), "--max-frames", "3", "--server", url, "--server-timeout", "2",
                    "--key-file", str(wrong), "--out", str(tmp_path / "w.jsonl")]) == 0
        err = capsys.readouterr().err
        assert "refused a frame: bad_mac" in err and "server errors: 3 (last: bad_mac)" in err
        proc.send_signal(signal.SIGTERM)
        _, tail = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    summary = tail.strip().splitlines()[-1]
    assert summary.startswith("occloc serve: 6 datagrams, 6 replies, 3 positions") and "bad_mac 3" in summary
    assert cli(["run", str(WALK), "--key-file", str(keys)]) == 2
    assert "--key-file needs --server" in capsys.readouterr().err


def test_loadgen_counts_only_position_replies_as_served(walk_map):
    """Refusals are errors, not service: 10 devices against a server holding 4."""
    from receiver.serve.loadcore import four_led_datagrams, run_load
    from receiver.serve.server import BackgroundServer

    dg = four_led_datagrams(walk_map, 40, 10)
    srv = LightingServer(walk_map, max_devices=4, source_rate=0, error_rate=1e6)
    with BackgroundServer(srv) as bg:
        report = run_load(bg.address, dg, rate=2000.0, drain_s=30.0)
    assert report["replies"] == 16 and report["lost"] == 24
    assert report["errors"] == {"too_many_devices": 24} and report["no_position"] == 0


def test_a_sources_cpu_share_is_bounded(walk_map):
    """Expensive datagrams (64 LEDs) from one host: once they have taken its CPU budget (a
    tenth of a second, refilled at --source-cpu-share per second of the server's clock, frozen
    here) the rest is dropped unread; another host is still served."""
    from receiver.serve.loadcore import four_led_datagrams

    srv = LightingServer(walk_map, clock=FakeClock(), source_rate=1e6)
    served = 0
    for k, (_, _, data) in enumerate(four_led_datagrams(walk_map, 3000, 64, n_leds=64)):
        served += srv.handle(data, ATTACKER) is not None
        if srv.counters["rate_limited"] >= 100:
            break
    assert srv.counters["rate_limited"] == 100 and 10 <= served < k
    assert srv.handle(_frame(walk_map, 0), HONEST)["position"] is not None
