"""`occloc tx`: configure an LED driver (firmware_tx) over its serial protocol (INTERFACES.md).

The port is a pyserial URL (`serial_for_url`): a device (`/dev/ttyACM0`), a pty path,
`socket://host:port`, `loop://` ... `TxClient` is the reusable part (the hardware-in-the-loop
tool drives `python -m firmware_tx` through it, started on a pty by `VirtualDriver`).
Every failure (no device, silence, an `ERR` reply, a reply that is not the protocol's) is an
`InputError` with a one-line reason.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import tty

from receiver.errors import InputError

HELP = "talk to an LED driver (firmware_tx) over a serial port: mode, ID, rate, start/stop"

MAX_COMMAND_CHARS = 64  # the protocol's line limit
MAX_REPLY_BYTES = 2048  # longest reply: DUMP 1024 is about 1040 bytes
DEFAULT_TIMEOUT_S = 2.0
DEFAULT_BAUD = 115200  # ignored by USB CDC ports and ptys, needed by real UARTs

# The keyword an OK reply must carry for each command.
REPLY_KEYWORD = {"PING": "PONG", "MODE": "MODE", "ID": "ID", "RATE": "RATE",
                 "SYMCLK": "SYMCLK", "START": "START", "STOP": "STOP", "STATUS": "STATUS",
                 "DUMP": "DUMP"}


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
        self.port.close()

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
        except (serial.SerialException, OSError) as e:
            raise InputError(f"LED driver port {self.url} failed: {_one_line(e)}") from None
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


def _number(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative: {text!r}")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value <= 600:
        raise argparse.ArgumentTypeError("timeout must be in (0, 600] s")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True,
                        help="serial port or pyserial URL (/dev/ttyACM0, a pty path, "
                             "socket://host:port, loop://)")
    parser.add_argument("--mode", choices=["ook", "s2psk", "tone"], help="drive mode")
    parser.add_argument("--id", type=_number, help="LED ID (16-bit OOK, 8-bit S2-PSK; 0x.. ok)")
    parser.add_argument("--rate", type=_number,
                        help="Hz: OOK chip rate, S2-PSK clock or tone frequency")
    parser.add_argument("--symclk", type=_number, help="S2-PSK clock periods per symbol")
    run = parser.add_mutually_exclusive_group()
    run.add_argument("--start", action="store_true", help="start emitting")
    run.add_argument("--stop", action="store_true", help="stop emitting (LED off)")
    run.add_argument("--status", action="store_true", help="print the driver's state")
    parser.add_argument("--dump", type=_number, metavar="N",
                        help="print the first N chips/symbols/half-periods of the stream")
    parser.add_argument("--timeout", type=_seconds, default=DEFAULT_TIMEOUT_S,
                        help=f"seconds to wait for each reply (default {DEFAULT_TIMEOUT_S:g})")


def plan_commands(args: argparse.Namespace) -> list[str]:
    """The command lines `occloc tx` sends, in order (PING first, queries last)."""
    lines = ["PING"]
    mode = f"MODE {args.mode.upper()}" if args.mode else None
    led_id = f"ID {args.id}" if args.id is not None else None
    # An 8-bit ID fits every mode, so set it before switching (an S2-PSK switch refuses a
    # wider ID still in place); a wider ID needs OOK/tone, so switch first.
    if led_id and (mode is None or args.id <= 0xFF):
        lines.append(led_id)
        led_id = None
    if mode:
        lines.append(mode)
    if led_id:
        lines.append(led_id)
    if args.rate is not None:
        lines.append(f"RATE {args.rate}")
    if args.symclk is not None:
        lines.append(f"SYMCLK {args.symclk}")
    if args.start:
        lines.append("START")
    if args.stop:
        lines.append("STOP")
    if args.status or len(lines) == 1 and args.dump is None:
        lines.append("STATUS")
    if args.dump is not None:
        lines.append(f"DUMP {args.dump}")
    return lines


def main(args: argparse.Namespace) -> int:
    with TxClient(args.port, timeout_s=args.timeout) as client:
        for line in plan_commands(args):
            print(client.command(line), flush=True)
    return 0


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
