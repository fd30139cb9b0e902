"""Hardware-in-the-loop through the real serial protocol with `python -m firmware_tx` on a pty."""

import subprocess
import sys

import pytest

from firmware_tx.framing import ook_packet, to_str
from receiver.core.errors import InputError
from receiver.io.txlink import TxClient, VirtualDriver, wait_for_driver
from tools.hil import parse_dump, run_loop, tx_commands


def test_loop_ids_come_back_from_the_driver_stream():
    with VirtualDriver() as driver, TxClient(driver.port, timeout_s=2.0) as client:
        wait_for_driver(client)
        report = run_loop(client, driver.port, mode="ook", frames=12, seed=3)
    assert report["ok"], report
    assert report["in_view"] >= 3 and not report["wrong_ids"]
    for r in report["ids"]:
        # What the driver emitted is exactly the PROTOCOL.md packet of the configured ID ...
        assert r["stream"] == to_str(ook_packet(r["id"]))
        # ... and the receiver got it back within 3 frames of the LED entering the view.
        assert r["decoded_at"] - r["first_in_view"] <= 2


def test_commands_are_the_occloc_tx_plan():
    lines = tx_commands("loop://", "ook", 0xBEEF, 20000, None)
    assert lines == ["PING", "MODE OOK", "ID 48879", "RATE 20000", "START", "DUMP 54"]


@pytest.mark.parametrize("reply", ["OK DUMP 54 1110", "ERR 3 range", "OK DUMP 4 1x10", "OK DUMP 4"])
def test_malformed_dump_is_an_error(reply):
    with pytest.raises(InputError):
        parse_dump(reply, 54 if "54" in reply else 4)


def test_cli_reports_pass_and_exit_status():
    proc = subprocess.run([sys.executable, "-m", "receiver.cli", "hil", "--frames", "6", "--seed", "2"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "PASS" in proc.stderr and '"ok": true' in proc.stdout


def test_cli_absent_port_is_one_line_error():
    proc = subprocess.run([sys.executable, "-m", "receiver.cli", "hil", "--port", "/dev/does-not-exist"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("occloc:")


def test_s2psk_resolvable_needs_two_separated_emitters_for_a_packet():
    from tools.hil import packet_frames, resolved_in_frame
    from tools.synth import make_scene
    em = [{"cx": 100.0, "cy": 50.0, "area_px": 9.0, "visible": True},
          {"cx": 106.0, "cy": 50.0, "area_px": 9.0, "visible": True}]
    led = {"id": 142, "visible": True, "emitters": em}
    assert resolved_in_frame(led, "s2psk")
    assert not resolved_in_frame({**led, "emitters": [em[0], {**em[1], "cx": 102.0}]}, "s2psk")
    assert not resolved_in_frame({**led, "emitters": [em[0], {**em[1], "area_px": 1.5}]}, "s2psk")
    assert not resolved_in_frame({**led, "visible": False}, "s2psk")
    assert resolved_in_frame({"id": 1, "visible": True}, "ook")
    # 30 symbols x 16 clocks / 200 Hz = 2.4 s = 72 frames at 30 fps
    assert packet_frames(make_scene("vehicle", seed=1, n_frames=2)) == 72


@pytest.mark.parametrize("found", [["MODE TONE", "ID 7", "RATE 3000", "START"],
                                   ["MODE OOK", "ID 1234", "RATE 10000", "STOP"]])
def test_loop_leaves_the_driver_as_it_found_it(found):
    from tools.hil import parse_status
    with VirtualDriver() as driver, TxClient(driver.port, timeout_s=2.0) as client:
        wait_for_driver(client)
        for line in found:
            client.command(line)
        before = client.command("STATUS")
        client.command("MODE OOK")
        ook_before = client.command("STATUS")
        client.command(found[0])
        report = run_loop(client, driver.port, mode="ook", frames=3, seed=3)
        assert report["configured"] > 0
        assert client.command("STATUS") == before
        client.command("MODE OOK")
        assert parse_status(client.command("STATUS"))["id"] == parse_status(ook_before)["id"]
