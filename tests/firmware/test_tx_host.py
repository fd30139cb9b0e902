"""Host side: `python -m firmware_tx` over pipes and over a pty, `TxClient`, and `occloc tx`
with its error paths (no device, silence, ERR replies, non-protocol replies)."""

import os
import subprocess
import sys
import time
import tty

import pytest
import serial

from firmware_tx import VERSION
from receiver import cli
from receiver.core.errors import InputError
from receiver.io.txlink import TxClient, VirtualDriver, wait_for_driver
from receiver.cli.tx import add_arguments, plan_commands

TIMEOUT_S = 5.0
PONG = "OK PONG " + VERSION


def test_module_over_pipes_binary_input_and_clean_eof():
    data = (b"PING\r\nMODE s2psk\nID 0x81\nDUMP 30\n\xff\x00\xfe\n" + b"Z" * 500 + b"\n"
            b"STATUS\nID 7")  # last line unterminated: answered at EOF
    proc = subprocess.run([sys.executable, "-m", "firmware_tx"], input=data,
                          capture_output=True, timeout=TIMEOUT_S * 4)
    assert proc.returncode == 0
    assert proc.stdout.decode().splitlines() == [
        PONG, "OK MODE S2PSK", "OK ID 129", "OK DUMP 30 111000100101010101011010100110",
        "ERR 5 non-ASCII or control characters", "ERR 4 line longer than 64 characters",
        "OK STATUS mode=S2PSK id=129 rate=200 symclk=16 running=0", "OK ID 7"]
    assert proc.stderr == b""


def _read_lines(port, n, timeout_s=TIMEOUT_S):
    lines = []
    end = time.monotonic() + timeout_s
    while len(lines) < n and time.monotonic() < end:
        raw = port.readline()
        if raw:
            lines.append(raw.decode("ascii").rstrip("\n"))
    return lines


def test_module_over_pty_with_pyserial_split_writes_and_garbage():
    with VirtualDriver() as drv:
        port = serial.serial_for_url(drv.port, timeout=TIMEOUT_S)
        try:
            port.write(b"PI")
            time.sleep(0.05)  # the driver sees a partial line first
            port.write(b"NG\nID 0x")
            port.write(b"2A\r\n")
            port.write(bytes(b for b in range(256) if b not in (10, 13)) + b"\n")  # every other byte
            port.write(b"Q" * 200 + b"\n")
            port.write(b"ID \x80\x81\x00\n")
            port.write(b"START\nSTATUS\n")
            got = _read_lines(port, 7)
        finally:
            port.close()
        assert got == [PONG, "OK ID 42", "ERR 4 line longer than 64 characters",
                       "ERR 4 line longer than 64 characters",
                       "ERR 5 non-ASCII or control characters", "OK START",
                       "OK STATUS mode=OOK id=42 rate=20000 symclk=16 running=1"]
    assert drv.proc.returncode == 0  # our end closed -> EIO on its pty -> clean exit


def test_txclient_against_pty_driver():
    with VirtualDriver() as drv, TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
        assert wait_for_driver(c) == PONG
        assert c.command("MODE S2PSK") == "OK MODE S2PSK"
        assert c.command("id 0x81") == "OK ID 129"
        assert c.command("DUMP 30") == "OK DUMP 30 111000100101010101011010100110"
        with pytest.raises(InputError, match=r"refused 'ID 300': ERR 3 "):
            c.command("ID 300")
        with pytest.raises(InputError, match="not a driver command line"):
            c.command("ID " + "1" * 70)
        with pytest.raises(InputError, match="not a driver command line"):
            c.command("ID 5\nSTART")
        # The refused command changed nothing and the driver still serves.
        assert c.command("STATUS") == "OK STATUS mode=S2PSK id=129 rate=200 symclk=16 running=0"


def run_cli(argv, capsys):
    rc = cli.main(argv)
    out, err = capsys.readouterr()
    return rc, out.splitlines(), err.strip()


def test_occloc_tx_configures_pty_driver(capsys):
    with VirtualDriver() as drv:
        with TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
            wait_for_driver(c)
        rc, out, err = run_cli(["tx", "--port", drv.port, "--mode", "s2psk", "--id", "0x2A",
                                "--rate", "125", "--symclk", "8", "--start", "--dump", "30"],
                               capsys)
        assert (rc, err) == (0, "")
        assert out == [PONG, "OK MODE S2PSK", "OK ID 42", "OK RATE 125", "OK SYMCLK 8",
                       "OK START", "OK DUMP 30 111000010110011001100101101010"]
        rc, out, _ = run_cli(["tx", "--port", drv.port, "--status"], capsys)
        assert out == [PONG, "OK STATUS mode=S2PSK id=42 rate=125 symclk=8 running=1"]
        # An ID that does not fit the driver's current mode (S2-PSK): refused before sending
        # it, one line on stderr, exit status 2, no traceback.
        rc, out, err = run_cli(["tx", "--port", drv.port, "--id", "300"], capsys)
        assert rc == 2 and out == [PONG]
        assert err == "occloc: --id must be 0..255 in s2psk mode, not 300"
        # A wide ID with a mode switch to OOK: the switch goes first.
        rc, out, _ = run_cli(["tx", "--port", drv.port, "--mode", "ook", "--id", "48879",
                              "--stop"], capsys)
        assert rc == 0 and out == [PONG, "OK MODE OOK", "OK ID 48879", "OK STOP"]


def test_occloc_tx_no_such_device(capsys):
    rc, out, err = run_cli(["tx", "--port", "/dev/occloc-no-such-tty", "--status"], capsys)
    assert rc == 2 and out == []
    assert err.startswith("occloc: cannot open LED driver port /dev/occloc-no-such-tty: ")
    assert "\n" not in err


def test_occloc_tx_silence_on_a_pty_nobody_serves(capsys):
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        rc, out, err = run_cli(["tx", "--port", os.ttyname(slave), "--timeout", "0.3"],
                               capsys)
    finally:
        os.close(master)
        os.close(slave)
    assert rc == 2 and out == []
    assert err.startswith("occloc: no reply from LED driver on ") and "within 0.3 s" in err


def test_occloc_tx_loop_echo_is_not_a_driver(capsys):
    # loop:// echoes the command back: a reply, but not the protocol's.
    rc, out, err = run_cli(["tx", "--port", "loop://", "--timeout", "0.5"], capsys)
    assert rc == 2 and out == []
    assert err == "occloc: not an LED driver reply from loop:// to 'PING': 'PING'"


def test_txclient_garbage_and_incomplete_replies():
    c = TxClient("loop://", timeout_s=0.3)
    try:
        # Pretend replies by writing into the loop after the command is sent.
        c.port.write = _echo_then(c.port.write, b"\xff\xfe garbage\n")
        with pytest.raises(InputError, match="garbage reply"):
            c.command("PING")
        c.port.write = _echo_then(c.port.write.__wrapped__, b"OK PONG")
        with pytest.raises(InputError, match="incomplete reply"):
            c.command("PING")
        c.port.write = _echo_then(c.port.write.__wrapped__, b"OK STATUS x\n")
        with pytest.raises(InputError, match="not an LED driver reply"):
            c.command("PING")
        c.port.write = _echo_then(c.port.write.__wrapped__, b"OK PONG 9\r\n")
        assert c.command("PING") == "OK PONG 9"
    finally:
        c.close()


def _echo_then(write, reply):
    # Replace what the loop would echo by a canned reply.
    def fake(_data):
        return write(reply)

    fake.__wrapped__ = write
    return fake


def _args(argv):
    import argparse

    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(["--port", "x", *argv])


@pytest.mark.parametrize("argv,lines", [
    ([], ["PING", "STATUS"]),
    (["--dump", "5"], ["PING", "DUMP 5"]),
    (["--mode", "s2psk", "--id", "7"], ["PING", "MODE S2PSK", "ID 7"]),
    (["--mode", "ook", "--id", "0x1234"], ["PING", "MODE OOK", "ID 4660"]),
    (["--id", "300", "--rate", "3000", "--start"], ["PING", "ID 300", "RATE 3000", "START"]),
    (["--symclk", "4", "--stop", "--dump", "2"], ["PING", "SYMCLK 4", "STOP", "DUMP 2"]),
])
def test_plan_commands(argv, lines):
    assert plan_commands(_args(argv)) == lines


def test_bad_cli_numbers_rejected_by_argparse(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["tx", "--port", "loop://", "--id", "-3"])
    assert e.value.code == 2
    assert "must not be negative" in capsys.readouterr().err


STATUS0 = "OK STATUS mode=OOK id=0 rate=20000 symclk=16 running=0"


@pytest.mark.parametrize("argv, err", [
    (["--mode", "tone", "--id", "4660", "--rate", "1", "--start"], "--rate must be 100..25000 Hz in tone mode"),
    (["--mode", "s2psk", "--id", "256"], "--id must be 0..255 in s2psk mode"),
    (["--mode", "ook", "--rate", "999"], "--rate must be 1000..50000 Hz in ook mode"),
    (["--mode", "ook", "--id", "65536"], "--id must be 0..65535 in ook mode"),
    (["--mode", "s2psk", "--rate", "5000"], "--rate must be 10..2000 Hz in s2psk mode"),
    (["--symclk", "65", "--start"], "--symclk must be 1..64"),
    (["--rate", "60000", "--start"], "--rate must be 1000..50000 Hz in ook mode"),   # the driver's mode
])
def test_occloc_tx_invalid_plan_changes_nothing(capsys, argv, err):
    """Before: `--mode tone --id 4660 --rate 1 --start` exited 2 with MODE and ID applied."""
    with VirtualDriver() as drv:
        with TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
            wait_for_driver(c)
        rc, out, got = run_cli(["tx", "--port", drv.port, *argv], capsys)
        assert rc == 2 and got.startswith("occloc: " + err), got
        assert "\n" not in got
        with TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
            assert c.command("STATUS") == STATUS0


def test_occloc_tx_rolls_back_on_an_err_reply(capsys, monkeypatch):
    """A driver that refuses a command the plan thought valid: the STATUS read before is put back."""
    import receiver.cli.tx as tx

    monkeypatch.setattr(tx, "check_plan", lambda args, mode: None)   # let a bad value through
    with VirtualDriver() as drv:
        with TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
            wait_for_driver(c)
            assert c.command("ID 7") == "OK ID 7" and c.command("RATE 3000") == "OK RATE 3000"
        rc, out, err = run_cli(["tx", "--port", drv.port, "--mode", "ook", "--id", "9", "--rate", "999",
                                "--start"], capsys)
        assert rc == 2 and out == [PONG, "OK MODE OOK", "OK ID 9"]
        assert "refused 'RATE 999': ERR 3" in err
        with TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
            assert c.command("STATUS") == "OK STATUS mode=OOK id=7 rate=3000 symclk=16 running=0"


def test_occloc_tx_mode_then_wide_and_narrow_ids(capsys):
    with VirtualDriver() as drv:
        with TxClient(drv.port, timeout_s=TIMEOUT_S) as c:
            wait_for_driver(c)
        rc, out, _ = run_cli(["tx", "--port", drv.port, "--mode", "ook", "--id", "4660"], capsys)
        assert rc == 0 and out == [PONG, "OK MODE OOK", "OK ID 4660"]
        rc, out, _ = run_cli(["tx", "--port", drv.port, "--mode", "s2psk", "--id", "42", "--status"], capsys)
        assert rc == 0 and out == [PONG, "OK MODE S2PSK", "OK ID 42",
                                   "OK STATUS mode=S2PSK id=42 rate=200 symclk=16 running=0"]
        rc, out, _ = run_cli(["tx", "--port", drv.port, "--mode", "ook", "--status"], capsys)
        assert out[-1] == "OK STATUS mode=OOK id=4660 rate=20000 symclk=16 running=0"
