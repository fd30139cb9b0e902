"""The load generator's own workings (receiver.serve.loadgen, receiver.serve.loadsuite): replies
read by kind as a JSON parse reads them, devices kept on one source socket each from the warm-up
through the timed load (the server binds an unkeyed name to its first address), and many devices
spread over source addresses within the server's default per-address quota. Functional only: the
waits are generous and nothing here measures a speed."""

from __future__ import annotations

import json

from receiver.io.ledmap import load_map
from receiver.serve.loadcore import (four_led_datagrams, read_reply, run_load, source_socks, start_server, stop_server,
                                    warm_up)
from receiver.serve.server import LightingServer
from receiver.serve.wire import ProtocolError, encode
from tests.serve.test_server import WALK, FakeClock


def _kind_by_json(data: bytes) -> tuple:
    rep = json.loads(data)
    if "error" in rep:
        return rep["error"], rep.get("device"), rep.get("seq")
    return ("no_position" if rep["position"] is None else "position"), rep["device"], rep["seq"]


def test_read_reply_reads_every_reply_as_json_does():
    walk_map = load_map(str(WALK / "map.json"))
    srv = LightingServer(walk_map, clock=FakeClock())
    replies = [srv.handle_datagram(data, ("127.0.0.1", 5)) for _, _, data in four_led_datagrams(walk_map, 20, 4)]
    replies += [encode(ProtocolError("bad_value", "x", 'odd "name"', 3).reply()),
                encode({"v": 1, "device": 'odd "name\\', "seq": 4, "position": None}),
                encode({"v": 1, "device": 'odd "name\\', "seq": 5, "position": {"x": 1.0}})]
    kinds = [read_reply(r) for r in replies]
    assert kinds == [_kind_by_json(r) for r in replies]
    assert sum(k[0] == "position" for k in kinds) == 21
    assert read_reply(b"\xff{") == ("unreadable", None, None) and read_reply(b"[1]")[0] == "unreadable"


def test_many_devices_from_many_sources_within_the_default_quota():
    """300 devices over 5 source addresses (60 each, under the default 64) against `occloc
    serve` with its default limits: every warm-up and timed datagram gets its position, no
    refusal, and the server holds all 300 (its summary)."""
    walk_map = load_map(str(WALK / "map.json"))
    devices = 300
    dg = four_led_datagrams(walk_map, 2 * devices, devices)
    proc, address = start_server(("--forget-s", "600"))
    try:
        socks = source_socks(address, 5)
        assert warm_up(address, dg[:devices], socks=socks, window=16, wait_s=60.0) == devices
        report = run_load(address, dg[devices:], 300.0, drain_s=60.0, socks=socks)
    finally:
        summary = stop_server(proc)
    assert report["replies"] == devices and report["lost"] == 0 and report["errors"] == {}, report
    assert f"{devices} new, 0 forgotten, {devices} held" in summary and "refused: none" in summary, summary


def test_a_missing_map_is_one_line_and_exit_2(tmp_path, capsys):
    from receiver.serve.loadgen import main
    missing = str(tmp_path / "none.json")
    for argv in (["--map", missing, "--rate", "10", "--seconds", "1"], ["--map", missing, "--suite", "--figures", "v2"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"loadgen: map file not found: {missing}"], err
