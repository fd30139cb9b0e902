"""`occloc tx`: configure an LED driver (firmware_tx) over a serial port. The whole command
plan is validated before anything is changed (`check_plan`: with --mode before the port is
opened, else against the mode a STATUS read reports); should the driver still refuse a command
(ERR), the configuration read before is restored and the exit status is 2. The serial link
itself is `receiver.io.txlink`.
"""

from __future__ import annotations

import argparse

from receiver.cli.args import seconds_up_to
from receiver.core.errors import InputError
from receiver.io.txlink import DEFAULT_TIMEOUT_S, PortGone, TxClient


HELP = "talk to an LED driver (firmware_tx) over a serial port: mode, ID, rate, start/stop"


def _number(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative: {text!r}")
    return value


_seconds = seconds_up_to(600.0)


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


def check_plan(args: argparse.Namespace, mode: str | None) -> None:
    """InputError unless every value fits `mode` (the --mode given, else the driver's current
    one; None: unknown, only mode-free checks): ID 16-bit OOK/tone, 8-bit S2-PSK; RATE the
    mode's range (OOK chip rate 1-50 kHz, S2-PSK clock, tone frequency); SYMCLK 1..64. The
    ranges are the firmware's own (`firmware_tx.driver`)."""
    from firmware_tx.driver import ID_MAX, RATE_RANGE_HZ, SYMCLK_RANGE

    if args.symclk is not None and not SYMCLK_RANGE[0] <= args.symclk <= SYMCLK_RANGE[1]:
        raise InputError("--symclk must be %d..%d" % SYMCLK_RANGE)
    if args.dump is not None and not 1 <= args.dump <= 1024:
        raise InputError("--dump must be 1..1024")
    if mode is None:
        return
    if args.id is not None and not 0 <= args.id <= ID_MAX[mode]:
        raise InputError(f"--id must be 0..{ID_MAX[mode]} in {mode} mode, not {args.id}")
    if args.rate is not None:
        lo, hi = RATE_RANGE_HZ[mode]
        if not lo <= args.rate <= hi:
            raise InputError(f"--rate must be {lo}..{hi} Hz in {mode} mode, not {args.rate}")


def plan_commands(args: argparse.Namespace) -> list[str]:
    """The command lines `occloc tx` sends, in order (PING first, queries last). Each mode
    keeps its own ID and rate on the driver, so MODE goes first and ID / RATE set that mode's."""
    lines = ["PING"]
    if args.mode:
        lines.append(f"MODE {args.mode.upper()}")
    if args.id is not None:
        lines.append(f"ID {args.id}")
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


CHANGES = ("MODE", "ID", "RATE", "SYMCLK", "START", "STOP")


def parse_status(reply: str) -> dict:
    """{'mode': 'ook', 'id': .., 'rate': .., 'symclk': .., 'running': 0/1} of a STATUS reply."""
    fields = dict(w.split("=", 1) for w in reply.split()[2:] if "=" in w)
    try:
        return {"mode": fields["mode"].lower(), "id": int(fields["id"]), "rate": int(fields["rate"]),
                "symclk": int(fields["symclk"]), "running": int(fields["running"])}
    except (KeyError, ValueError):
        raise InputError(f"not a STATUS reply: {reply[:60]!r}") from None


def restore_commands(before: dict) -> list[str]:
    """Lines putting the current mode's configuration back as `before` (a parsed STATUS)."""
    return [f"MODE {before['mode'].upper()}", f"ID {before['id']}", f"RATE {before['rate']}",
            f"SYMCLK {before['symclk']}", "START" if before["running"] else "STOP"]


def main(args: argparse.Namespace) -> int:
    check_plan(args, args.mode)            # before the port is even opened
    lines = plan_commands(args)
    changes = any(line.split()[0] in CHANGES for line in lines)
    with TxClient(args.port, timeout_s=args.timeout) as client:
        print(client.command(lines[0]), flush=True)          # PING
        before = None
        if changes:
            before = parse_status(client.command("STATUS"))   # for checks and a rollback
            if args.mode is None:
                check_plan(args, before["mode"] if before["mode"] in ("ook", "s2psk", "tone") else None)
        for line in lines[1:]:
            try:
                reply = client.command(line)
            except PortGone:
                raise  # nothing reaches the driver any more: no rollback
            except InputError:
                if before is not None and line.split()[0] in CHANGES:
                    _roll_back(client, before)
                raise
            print(reply, flush=True)
    return 0


def _roll_back(client, before: dict) -> None:
    """Best effort: restore the STATUS read before the plan (the current mode's ID, rate,
    symclk and running state; another mode's values the plan changed stay changed)."""
    for line in restore_commands(before):
        try:
            client.command(line)
        except PortGone:
            return
        except InputError:
            pass
