"""A serial port that vanishes mid-command (a USB adapter pulled): pyserial then raises
termios.error, which is neither OSError nor SerialException. `occloc tx` ends with one line
naming the port, and does not try to roll back through the dead port."""

from __future__ import annotations

import argparse
import termios

import pytest

from receiver.cli import tx
from receiver.core.errors import InputError
from receiver.io import txlink


class VanishingPort:
    """Answers PING and STATUS, then every call fails the way a pulled adapter does."""

    def __init__(self):
        self.calls, self.sent, self.gone = 0, [], False
        self._reply = b""

    def reset_input_buffer(self):
        if self.gone:
            raise termios.error(5, "Input/output error")

    def write(self, data):
        self.calls += 1
        if self.gone:
            raise termios.error(5, "Input/output error")
        self.sent.append(data)
        word = data.split()[0].decode()
        self._reply = (b"OK PONG\n" if word == "PING" else
                       b"OK STATUS mode=ook id=1 rate=10000 symclk=16 running=0\n" if word == "STATUS" else b"")
        if word not in ("PING", "STATUS"):
            self.gone = True
            raise termios.error(5, "Input/output error")

    def flush(self):
        pass

    def read_until(self, end, size):
        return self._reply

    def close(self):
        if self.gone:
            raise termios.error(9, "Bad file descriptor")


def test_vanished_port_is_one_line_and_no_rollback(monkeypatch):
    port = VanishingPort()

    def fake_init(self, url, timeout_s=0.1, baudrate=115200):
        self.url, self.timeout_s, self.port = url, timeout_s, port

    monkeypatch.setattr(txlink.TxClient, "__init__", fake_init)
    args = argparse.Namespace(port="/dev/ttyACM9", mode="ook", id=7, rate=None, symclk=None, start=False,
                              stop=False, status=False, dump=None, timeout=0.1)
    with pytest.raises(InputError) as e:
        tx.main(args)
    assert "/dev/ttyACM9" in str(e.value) and "\n" not in str(e.value)
    calls = port.calls
    assert calls == 3  # PING, STATUS, MODE: no rollback commands tried after the port died
