"""`occloc` command line: a thin dispatcher over subcommand modules.

Each subcommand lives in its own module exposing `HELP` (one line), `add_arguments(parser)`
and `main(args) -> int`. Only modules that exist are listed, and a module is imported only
when its subcommand runs (so `occloc tx` does not pay for OpenCV). Every `InputError`
becomes `occloc: <reason>` on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.machinery
import importlib.util
import os
import sys

from receiver.core.errors import InputError

# subcommand -> module; help text comes from the module's HELP string.
SUBCOMMANDS = {
    "run": "receiver.cli.run",
    "bench": "receiver.cli.bench",
    "tx": "receiver.cli.tx",
    "serve": "receiver.cli.serve",
    "eval": "receiver.cli.eval",
    "calibrate": "receiver.cli.calibrate",
    "check": "receiver.cli.check",
    "export": "receiver.cli.export",
}

# Developer commands: the synthetic camera and hardware-in-the-loop live in the source
# checkout's `tools/` (not in the installed wheel); they are offered when that folder is there.
DEV_SUBCOMMANDS = {
    "synth": "tools.synth.cli",
    "hil": "tools.hil",
    "experiments": "tools.experiments.cli",
}

EXIT_BAD_INPUT = 2

# Control characters (a newline, a terminal's escape sequences) in an error's text, from a file
# name or an option's value: shown escaped, so the error stays one line and the terminal's own.
_CONTROL_ESCAPES = {c: f"\\x{c:02x}" for c in (*range(32), 127)}


def one_line(text) -> str:
    """`text` with every control character shown as \\xNN."""
    return str(text).translate(_CONTROL_ESCAPES)


def _source_checkout() -> str | None:
    """The repository root when this package runs from a source checkout with its `tools/`."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return root if os.path.isfile(os.path.join(root, "tools", "synth", "__init__.py")) else None


def _available() -> dict[str, str]:
    commands = dict(SUBCOMMANDS)
    root = _source_checkout()
    if root is not None:
        if root not in sys.path:
            sys.path.append(root)  # after site-packages: never shadows an installed module
        commands.update(DEV_SUBCOMMANDS)
    return {name: module for name, module in commands.items() if _find_spec(module) is not None}


def _find_spec(module: str):
    """The module's spec without running any package's `__init__` below the top level (an
    `importlib.util.find_spec` of `tools.synth.cli` would import `tools.synth`, i.e. OpenCV);
    None when it is not there."""
    top, *rest = module.split(".")
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return None
    for part in rest:
        if spec is None or spec.submodule_search_locations is None:
            return None
        spec = importlib.machinery.PathFinder.find_spec(part, list(spec.submodule_search_locations))
    return spec


_HELP_LINES: dict[str, str] = {}


def _help_line(module: str) -> str:
    """The module's `HELP = "..."` (or a parenthesised run of string literals over several
    lines), read from its source without importing it or its dependencies ('' when it has none)."""
    text = _HELP_LINES.get(module)
    if text is None:
        text = _HELP_LINES[module] = _read_help_line(module)
    return text


def _read_help_line(module: str) -> str:
    spec = _find_spec(module)
    try:
        with open(spec.origin, encoding="utf-8") as f:
            lines = iter(f)
            for line in lines:
                if line.startswith("HELP = "):
                    text = line[len("HELP = "):].strip()
                    while text.startswith("(") and not text.endswith(")"):
                        text += " " + next(lines).strip()
                    return _string_literal(text)
    except (OSError, TypeError, ValueError, SyntaxError, StopIteration):
        pass
    return ""


def _string_literal(text: str) -> str:
    """The value of a Python expression of string literals (adjacent ones are one string), as
    ast.literal_eval reads it, without importing `ast` (9 M of the 153 M instructions of
    `occloc --help`) and without evaluating anything: the expression is compiled, and its value
    taken when the code is nothing but the return of one string constant (the compiler also
    folds e.g. 'a' * 3 into one). ValueError otherwise (names, numbers, calls, containers)."""
    code = compile(text, "<HELP>", "eval", dont_inherit=True)
    if (code.co_code != _ONE_CONSTANT or code.co_names or len(code.co_consts) != 1
            or not isinstance(code.co_consts[0], str)):
        raise ValueError(f"not a string literal: {text!r}")
    return code.co_consts[0]


# The bytecode of an expression that is one constant (this interpreter's opcodes).
_ONE_CONSTANT = compile("''", "<HELP>", "eval", dont_inherit=True).co_code


def build_parser(commands: dict[str, str], selected: str | None = None, *,
                 every_help: bool = True) -> argparse.ArgumentParser:
    """The parser of `commands`; the `selected` command's own arguments are added (its module
    imported). `every_help` False: the other commands get no help line (read from their source
    otherwise), for a command line whose top-level help cannot be printed (`_needs_every_help`)."""
    from receiver import __version__

    parser = argparse.ArgumentParser(
        prog="occloc",
        description="Localization and ID reception with optical camera communication.")
    parser.add_argument("--version", action="version", version=f"occloc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in commands.items():
        text = _help_line(module) if every_help or name == selected else None
        p = sub.add_parser(name, help=text, description=text)
        if name == selected:
            importlib.import_module(module).add_arguments(p)
    return parser


def _needs_every_help(argv: list[str], selected: str | None) -> bool:
    """Can this command line print the top-level help (which lists every command's help line)?
    Without a command, or with -h / --help (or an abbreviation of it) before the command."""
    if selected is None:
        return True
    before = argv[:argv.index(selected)]
    return any(a == "-h" or (len(a) > 2 and "--help".startswith(a)) for a in before)


# Commands whose files are staged: SIGTERM/SIGHUP end them through their `finally` blocks (no
# temporary file left); the others (servers, the serial link) keep their own signal handling.
_STAGING_COMMANDS = ("run", "eval", "calibrate", "check", "bench", "synth")


class _Stopped(BaseException):
    """Raised by the SIGTERM/SIGHUP handler: unwinds the command through its cleanups."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_stopped(signum, frame):
    raise _Stopped(signum)


def _devnull_fd(fd: int) -> None:
    """Point file descriptor `fd` at /dev/null (the interpreter's final flush of text that could
    not be written, or a closed standard stream that a later open would otherwise reuse)."""
    try:
        null = os.open(os.devnull, os.O_RDWR)
    except OSError:
        return
    if null != fd:
        os.dup2(null, fd)
        os.close(null)


def _fill_closed_std_fds() -> None:
    """A closed fd 0/1/2 (`2>&-`) is pointed at /dev/null: the next file opened would get that
    number, and OpenCV's or libjpeg's messages to fd 2 would land in it. A closed standard error
    also gets a /dev/null sys.stderr: `print(file=None)` writes to standard output."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            _devnull_fd(fd)
    if sys.stderr is None:
        sys.stderr = open(os.devnull, "w", encoding="utf-8")


def _finish_stdout() -> int:
    """Flush standard output; 2 with a one-line error when it cannot be written."""
    stream = sys.stdout
    if stream is None:
        return 0
    try:
        stream.flush()
    except BrokenPipeError:
        _devnull_fd(1)
    except (OSError, InputError) as e:
        _devnull_fd(1)
        msg = str(e) if isinstance(e, InputError) else f"cannot write standard output: {e.strerror or e}"
        print(f"occloc: {one_line(msg)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


def main(argv: list[str] | None = None) -> int:
    import signal

    import receiver
    try:
        if signal.getsignal(signal.SIGINT) is receiver._interrupted_while_loading:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        return _main(argv)
    except KeyboardInterrupt:  # e.g. while a command module is imported
        print("occloc: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        # Ctrl-C inside a class body's hook while a module loads (a dataclass field's
        # __set_name__) reaches here as the RuntimeError it was wrapped in.
        if not _caused_by_interrupt(e):
            raise
        print("occloc: interrupted", file=sys.stderr)
        return 130


def _caused_by_interrupt(e: BaseException | None) -> bool:
    """True when a KeyboardInterrupt is in `e`'s chain of causes and contexts."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _main(argv: list[str] | None) -> int:
    from receiver.io.files import StdoutOutput

    _fill_closed_std_fds()
    old = sys.stdout
    if sys.stdout is not None and not isinstance(sys.stdout, StdoutOutput):
        sys.stdout = StdoutOutput(sys.stdout)
    try:
        return _parse_and_run(argv)
    finally:
        sys.stdout = old


def _parse_and_run(argv: list[str] | None) -> int:
    import signal

    from receiver.io.files import remove_live_temps

    argv = list(sys.argv[1:] if argv is None else argv)
    commands = _available()
    selected = next((a for a in argv if not a.startswith("-")), None)
    if selected not in commands:
        selected = None
    parser = build_parser(commands, selected, every_help=_needs_every_help(argv, selected))
    try:
        args = parser.parse_args(argv)  # a usage error: argparse's SystemExit(2), said on stderr
    except InputError as e:  # --help or --version on a standard output that cannot be written
        _devnull_fd(1)
        print(f"occloc: {one_line(e)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SystemExit:  # --help, --version (buffered): their text must reach standard output
        if _finish_stdout():
            return EXIT_BAD_INPUT
        raise
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    old = {}
    if args.command in _STAGING_COMMANDS:
        for sig in (signal.SIGTERM, signal.SIGHUP):
            try:
                if signal.getsignal(sig) is signal.SIG_DFL:
                    old[sig] = signal.signal(sig, _raise_stopped)
            except (OSError, ValueError):  # not the main thread
                pass
    try:
        rc = int(importlib.import_module(commands[args.command]).main(args) or 0)
        return _finish_stdout() or rc
    except InputError as e:
        _finish_stdout()
        print(f"occloc: {one_line(e)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("occloc: interrupted", file=sys.stderr)
        return 130
    except _Stopped as e:
        return 128 + e.signum
    except BrokenPipeError:
        # Downstream closed the pipe (e.g. `occloc run | head`): not an error of ours.
        _devnull_fd(1)
        return 0
    finally:
        remove_live_temps()
        for key, value in old.items():
            signal.signal(key, value)
