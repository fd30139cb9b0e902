"""`occloc` command line: a thin dispatcher over subcommand modules.

Each subcommand lives in its own module exposing `HELP` (one line), `add_arguments(parser)`
and `main(args) -> int`. Only modules that exist are listed, and a module is imported only
when its subcommand runs (so `occloc tx` does not pay for OpenCV). Every `InputError`
becomes `occloc: <reason>` on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

from receiver.errors import InputError

# subcommand -> module; help text comes from the module's HELP string.
SUBCOMMANDS = {
    "run": "receiver.run",
    "bench": "receiver.bench",
    "tx": "receiver.txhost",
    "synth": "tools.synth.cli",
    "hil": "tools.hil",
    "serve": "receiver.server",
    "eval": "receiver.evaluate",
}

EXIT_BAD_INPUT = 2


def _available() -> dict[str, str]:
    out = {}
    for name, module in SUBCOMMANDS.items():
        try:
            if importlib.util.find_spec(module) is not None:
                out[name] = module
        except ModuleNotFoundError:
            pass
    return out


def _help_line(module: str) -> str:
    # Read the HELP line from the source without importing heavy dependencies.
    spec = importlib.util.find_spec(module)
    try:
        with open(spec.origin, encoding="utf-8") as f:
            for line in f:
                if line.startswith("HELP = "):
                    return line[len("HELP = "):].strip().strip("\"'")
    except (OSError, TypeError):
        pass
    return ""


def build_parser(commands: dict[str, str], selected: str | None = None) -> argparse.ArgumentParser:
    from receiver import __version__

    parser = argparse.ArgumentParser(
        prog="occloc",
        description="Localization and ID reception with optical camera communication.")
    parser.add_argument("--version", action="version", version=f"occloc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in commands.items():
        p = sub.add_parser(name, help=_help_line(module), description=_help_line(module))
        if name == selected:
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = _available()
    selected = next((a for a in argv if not a.startswith("-")), None)
    if selected not in commands:
        selected = None
    parser = build_parser(commands, selected)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    try:
        return int(importlib.import_module(commands[args.command]).main(args) or 0)
    except InputError as e:
        print(f"occloc: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("occloc: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Downstream closed the pipe (e.g. `occloc run | head`): not an error of ours.
        try:
            sys.stdout = None
        finally:
            return 0


if __name__ == "__main__":
    sys.exit(main())
