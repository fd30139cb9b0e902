"""`occloc tx`: configure an LED driver (firmware_tx) over a serial port; the command plan is
validated before anything is sent. The serial link itself is `receiver.io.txlink`.
"""

from __future__ import annotations

import argparse
from receiver.io.txlink import DEFAULT_TIMEOUT_S, TxClient


HELP = "talk to an LED driver (firmware_tx) over a serial port: mode, ID, rate, start/stop"


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
