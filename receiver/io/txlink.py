"""Serial link to an LED driver (firmware_tx, INTERFACES.md serial protocol): `TxClient`, `VirtualDriver`.

The port is a pyserial URL (`serial_for_url`): a device (`/dev/ttyACM0`), a pty path,
`socket://host:port`, `loop://` ... `TxClient` is the reusable part (the hardware-in-the-loop
tool drives `python -m firmware_tx` through it, started on a pty by `VirtualDriver`).
Every failure (no device, silence, an `ERR` reply, a reply that is not the protocol's) is an
`InputError` with a one-line reason.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import tty

from receiver.core.errors import InputError

MAX_COMMAND_CHARS = 64  # the protocol's line limit
MAX_REPLY_BYTES = 2048  # longest reply: DUMP 1024 is about 1040 bytes
DEFAULT_TIMEOUT_S = 2.0
DEFAULT_BAUD = 115200  # ignored by USB CDC ports and ptys, needed by real UARTs

# The keyword an OK reply must carry for each command.
REPLY_KEYWORD = {"PING": "PONG", "MODE": "MODE", "ID": "ID", "RATE": "RATE",
                 "SYMCLK": "SYMCLK", "START": "START", "STOP": "STOP", "STATUS": "STATUS",
                 "DUMP": "DUMP"}


class PortGone(InputError):
    """The port itself failed (unplugged, closed under us): no further command can reach the
    driver, so a rollback is not tried."""


def _port_errors() -> tuple:
    """Exceptions of a failing port: pyserial's, the OS's, and termios.error (a USB adapter
    pulled mid-command: pyserial's tcgetattr/tcflush raise it, and it is neither OSError nor
    SerialException)."""
    import serial
    errors = (serial.SerialException, OSError)
    try:
        import termios
        errors += (termios.error,)
    except ImportError:  # not a POSIX system
        pass
    return errors


class TxClient:
    """One open connection to a driver. `command(line) -> reply` (the `OK ...` line).

    `timeout_s` bounds each reply (silence -> InputError). Use as a context manager or
    call `close()`.
    """

    def __init__(self, url: str, timeout_s: float = DEFAULT_TIMEOUT_S,
                 baudrate: int = DEFAULT_BAUD):
        import serial

        self.url = url
        self.timeout_s = timeout_s
        try:
            self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout_s,
                                              write_timeout=timeout_s)
        except (serial.SerialException, ValueError, OSError) as e:
            raise InputError(f"cannot open LED driver port {url}: {_one_line(e)}") from None

    def __enter__(self) -> TxClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        try:
            self.port.close()
        except _port_errors():
            pass  # a port that is gone is closed

    def command(self, line: str) -> str:
        """Send one command line, return its `OK ...` reply (without the line end)."""
        import serial

        if (len(line) > MAX_COMMAND_CHARS or not line.strip()
                or any(not (" " <= c <= "~") for c in line)):
            raise InputError(f"not a driver command line (printable ASCII, 1..64 chars): {line!r}")
        keyword = line.split()[0].upper()
        try:
            self.port.reset_input_buffer()  # stale bytes would be taken for this reply
            self.port.write(line.encode("ascii") + b"\n")
            self.port.flush()
            raw = self.port.read_until(b"\n", MAX_REPLY_BYTES)
        except _port_errors() as e:
            raise PortGone(f"LED driver port {self.url} failed: {_one_line(e)}") from None
        if not raw:
            raise InputError(f"no reply from LED driver on {self.url} to {line!r} "
                             f"within {self.timeout_s:g} s")
        if not raw.endswith(b"\n"):
            raise InputError(f"incomplete reply from LED driver on {self.url} to {line!r}: "
                             f"{raw[:60]!r}")
        try:
            reply = raw.decode("ascii").rstrip("\r\n")
        except UnicodeDecodeError:
            raise InputError(f"garbage reply from {self.url} to {line!r}: {raw[:60]!r}") from None
        words = reply.split()
        if words[:1] == ["ERR"]:
            raise InputError(f"LED driver on {self.url} refused {line!r}: {reply}")
        if words[:1] != ["OK"] or words[1:2] != [REPLY_KEYWORD.get(keyword, keyword)]:
            raise InputError(f"not an LED driver reply from {self.url} to {line!r}: {reply[:60]!r}")
        return reply


class VirtualDriver:
    """`python -m firmware_tx` on a fresh pty; `.port` is the path for `TxClient`.

    The driver holds the pty master; the host side opens the slave path like any serial
    device. Leaving the context closes our end, which the driver sees as end of input.
    """

    def __init__(self, python: str = sys.executable, exit_timeout_s: float = 5.0):
        master, self._slave = os.openpty()
        # Raw before anyone talks: a cooked pty would echo the driver's replies back to it.
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self.exit_timeout_s = exit_timeout_s
        self.proc = subprocess.Popen([python, "-m", "firmware_tx"], stdin=master,
                                     stdout=master, stderr=subprocess.DEVNULL,
                                     close_fds=True)
        os.close(master)

    def __enter__(self) -> VirtualDriver:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> int:
        """Close our end of the pty and wait for the driver; returns its exit status."""
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None
        try:
            return self.proc.wait(timeout=self.exit_timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def wait_for_driver(client: TxClient, deadline_s: float = 5.0, poll_s: float = 0.05) -> str:
    """PING until the driver answers (a freshly started `python -m firmware_tx` needs a moment
    to import); returns the PONG reply, or raises the last InputError after `deadline_s`."""
    end = time.monotonic() + deadline_s
    while True:
        try:
            return client.command("PING")
        except InputError:
            if time.monotonic() >= end:
                raise
            time.sleep(poll_s)
