"""What each compiled kernel saves of a whole frame, in instructions (callgrind), per bench case.

    .venv/bin/python -m tools.kernel_shares [KERNEL ...] [--source CASE ...] [--instr-frames K] [--out FILE.md]

Runs `occloc bench --instructions --json` once with every kernel built in, then once per KERNEL
(default: all of them) with `OCCLOC_PURE=KERNEL`, which sends only that kernel's stage down its
numpy path. A KERNEL may name several kernels joined by commas (`_kalman,_position`): their
pure paths together, an upper bound of each one's share. `--source` (repeatable): only those
cases (a recording folder, or `synthetic` for the built-in scene), each its own bench run.
`--skip-uncalled`: first count, per case, which kernels its counted frames call (each kernel
function wrapped in a counter before the stages import it), and measure a kernel only on the
cases that call it; elsewhere its share is 0 by construction (the frame runs the same code
either way) and the table says `-`. A kernel's share on a case is (pure - native) / native instructions per frame: the
part of a whole frame the kernel saves there. The house keeps a kernel only where that share is
at least KEEP_SHARE_PCT on some bundled case. Instruction counts do not depend on the machine's
load, so the figures are repeatable on a busy machine (slow: minutes per run).

`--inside`: instead, one callgrind run per case with every kernel built, and for each kernel
module the share of the counted frames' instructions spent inside it: its functions' own
instructions plus what their calls into other objects (CPython, numpy, libm) cost, calls between
its own functions counted once. That is what a kernel without a numpy path (the one
implementation) costs of a frame, not what it saves.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
from pathlib import Path

from receiver.core import native

KEEP_SHARE_PCT = 5.0
ROOT = Path(__file__).resolve().parents[1]


def bench_instructions(pure: str, instr_frames: int, sources: list[str] | None = None) -> dict[str, float]:
    """{case: instructions per frame} of `occloc bench --instructions` with OCCLOC_PURE=pure, on
    every bundled case or on each of `sources` in turn."""
    if not sources:
        return _bench_once(pure, instr_frames, None)
    out: dict[str, float] = {}
    for source in sources:
        out.update(_bench_once(pure, instr_frames, source))
    return out


def _bench_once(pure: str, instr_frames: int, source: str | None) -> dict[str, float]:
    """{case: instructions per frame} of one `occloc bench --instructions` run with OCCLOC_PURE=pure."""
    env = dict(os.environ)
    env.pop("OCCLOC_PURE", None)
    if pure:
        env["OCCLOC_PURE"] = pure
    cmd = [sys.executable, "-m", "receiver.cli", "bench", "--instructions", "--json", "--frames", "20",
           "--instr-frames", str(instr_frames)] + ([source] if source else [])
    done = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        said = (done.stderr.strip().splitlines() or [f"exit {done.returncode}"])[-1]
        raise SystemExit(f"kernel_shares: occloc bench failed ({said})")
    out = done.stdout
    return {row["case"]: row["instructions_per_frame"] for row in json.loads(out)["cases"]}


class _Counted:
    """A kernel function that records its kernel's name in `called` when it runs; indexing (a
    fused function's specialisation) gives a counted specialisation."""

    def __init__(self, f, name: str, called: set):
        self.f, self.name, self.called = f, name, called

    def __call__(self, *args, **kwargs):
        self.called.add(self.name)
        return self.f(*args, **kwargs)

    def __getitem__(self, key):
        return _Counted(self.f[key], self.name, self.called)


def _calls_child(spec: str, warm: int, k: int) -> int:
    """Print the kernels (JSON list) that frames [warm, warm + k) of case `spec` call, as
    `occloc bench --instructions` counts them: every kernel's functions are wrapped before any
    stage imports them."""
    import importlib
    called: set[str] = set()
    counting: set[str] = set()
    for name in native.kernel_sources():
        mod = native.load(name)
        if mod is None:
            continue
        short = name.rsplit(".", 1)[-1]
        for attr in dir(mod):
            f = getattr(mod, attr)
            if not attr.startswith("__") and callable(f) and not isinstance(f, type):
                setattr(mod, attr, _Counted(f, short, counting))
    bench = importlib.import_module("receiver.cli.bench")
    from receiver.io.output import frame_line
    cam, led_map, frames, still = bench.load_case(spec, warm + k)
    warm = min(warm, max(0, len(frames) - k))
    rx = bench.whole_receiver(cam, led_map, still=still)
    for f in frames[:warm]:
        frame_line(rx.process(f))
    counting.clear()
    for f in frames[warm:warm + k]:
        frame_line(rx.process(f))
    called |= counting
    print(json.dumps(sorted(called)))
    return 0


def kernels_called(source: str, instr_frames: int) -> set[str]:
    """The kernels the counted frames of case `source` call (`_calls_child`, its own process)."""
    from receiver.cli.bench import INSTR_WARM_FRAMES
    cmd = [sys.executable, "-m", "tools.kernel_shares", "--_calls", source, str(INSTR_WARM_FRAMES), str(instr_frames)]
    env = {k: v for k, v in os.environ.items() if k != "OCCLOC_PURE"}
    done = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        said = (done.stderr.strip().splitlines() or [f"exit {done.returncode}"])[-1]
        raise SystemExit(f"kernel_shares: counting the calls of {source} failed ({said})")
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


def inside_costs(path: str) -> tuple[dict[str, int], int]:
    """({object file: instructions inside it}, total) of a callgrind output file: each object's
    functions' own instructions plus the inclusive cost of their calls into other objects."""
    names: dict[tuple[str, str], str] = {}
    inside: dict[str, int] = {}
    total, ob, fn_ob, call_ob, pending_cob, in_call = 0, "", "", "", None, False

    def name(kind: str, rest: str) -> str:   # "(id) name" or "(id)": callgrind's name compression
        if rest.startswith("("):
            key, _, text = rest.partition(")")
            key = (kind, key + ")")
            if text.strip():
                names[key] = text.strip()
            return names.get(key, "")
        return rest.strip()

    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            c = line[:1]
            if c.isdigit() or c in "+-*":
                parts = line.split()
                cost = int(parts[1]) if len(parts) > 1 else 0
                if in_call:
                    if call_ob != fn_ob:
                        inside[fn_ob] = inside.get(fn_ob, 0) + cost
                    in_call = False
                else:
                    inside[fn_ob] = inside.get(fn_ob, 0) + cost
                    total += cost
            elif line.startswith("ob="):
                ob = name("ob", line[3:])
            elif line.startswith("fn="):
                fn_ob, pending_cob = ob, None
            elif line.startswith("cob="):
                pending_cob = name("ob", line[4:])
            elif line.startswith("calls="):
                call_ob, pending_cob, in_call = (pending_cob if pending_cob is not None else fn_ob), None, True
    return inside, total


def kernel_inside_shares(path: str) -> dict[str, float]:
    """{kernel short name: % of the counted instructions inside its module} of a callgrind file."""
    inside, total = inside_costs(path)
    out: dict[str, float] = {}
    for obj, cost in inside.items():
        base = os.path.basename(obj)
        short = base.split(".", 1)[0]
        if short.startswith("_") and base.endswith(".so") and f"{os.sep}receiver{os.sep}" in obj:
            out[short] = out.get(short, 0.0) + 100.0 * cost / total
    return out


def inside_table(sources: list[str] | None, instr_frames: int, out) -> int:
    """Print (and write to `out`) each kernel's share of a frame spent inside it, per case."""
    import tempfile
    from receiver.cli import bench
    sources = sources or bench.bundled_recordings() + [bench.SCENE]
    shares: dict[str, dict[str, float]] = {}
    per_frame: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="occloc-inside-") as tmp:
        for src in sources:
            case = bench._case_name(src)
            print(f"kernel_shares: {case} under callgrind ...", file=sys.stderr, flush=True)
            keep = os.path.join(tmp, case + ".out")
            got = bench.count_instructions(src, instr_frames, keep=keep)
            if got["instructions_per_frame"] is None:
                raise SystemExit(f"kernel_shares: {case}: {got['note']}")
            per_frame[case] = got["instructions_per_frame"]
            shares[case] = kernel_inside_shares(keep)
    cases = list(shares)
    built = {n.rsplit(".", 1)[-1] for n in native.kernel_sources()}   # uncalled ones: 0
    kernels = sorted(built | {k for s in shares.values() for k in s},
                     key=lambda k: (-max(s.get(k, 0) for s in shares.values()), k))
    _emit(out, "| kernel | lines | " + " | ".join(cases) + " | max % |")
    _emit(out, "|---|---|" + "---|" * (len(cases) + 1))
    _emit(out, "| (M instr/frame, all built) | | " + " | ".join(f"{per_frame[c] / 1e6:.2f}" for c in cases) + " | |")
    for k in kernels:
        _emit(out, f"| {k} | {kernel_lines(k)} | " + " | ".join(f"{shares[c].get(k, 0.0):.1f}" for c in cases)
              + f" | {max(s.get(k, 0.0) for s in shares.values()):.1f} |")
    return 0


def kernel_lines(short: str) -> int:
    """Lines of a kernel's .pyx and the .pxi files it includes (`_name_*.pxi` beside it)."""
    for mod in native.kernel_sources():
        if mod.rsplit(".", 1)[-1] == short:
            pyx = ROOT.joinpath(*mod.split(".")).with_suffix(".pyx")
            files = [pyx] + sorted(pyx.parent.glob(short + "_*.pxi"))
            return sum(len(p.read_text(encoding="utf-8").splitlines()) for p in files)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.kernel_shares", description=__doc__.split("\n\n")[0])
    p.add_argument("kernels", nargs="*",
                   help="kernel module names, e.g. _tone, or a group _kalman,_position (default: every kernel)")
    p.add_argument("--instr-frames", type=int, default=5, help="frames counted per case (5)")
    p.add_argument("--source", action="append",
                   help="a recording folder or `synthetic` instead of every bench case (repeatable)")
    p.add_argument("--out", help="also write the table to this Markdown file")
    p.add_argument("--skip-uncalled", action="store_true",
                   help="measure a kernel only on the cases whose counted frames call it (`-` elsewhere)")
    p.add_argument("--inside", action="store_true",
                   help="each kernel's share of a frame spent inside it (one callgrind run per case, all built)")
    p.add_argument("--_calls", nargs=3, metavar=("CASE", "W", "K"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args._calls:
        return _calls_child(args._calls[0], int(args._calls[1]), int(args._calls[2]))
    if args.inside:
        with (open(args.out, "w") if args.out else contextlib.nullcontext()) as out:
            return inside_table(args.source, args.instr_frames, out)
    known = [n for n in (m.rsplit(".", 1)[-1] for m in native.kernel_sources())
             if n not in native.ONE_IMPLEMENTATION]
    unknown = [n for group in args.kernels for n in group.split(",") if n not in known]
    if unknown:   # OCCLOC_PURE would ignore it: its share would read 0 %, "drop it"
        p.error(f"kernel {', '.join(unknown)} has no numpy path to measure against or does not exist "
                f"(choose from {', '.join(known)})")
    names = args.kernels or known
    sources, calls = args.source, None
    if args.skip_uncalled:
        from receiver.cli import bench
        sources = sources or bench.bundled_recordings() + [bench.SCENE]
        print("kernel_shares: counting which kernels each case calls ...", file=sys.stderr, flush=True)
        calls = {bench._case_name(src): kernels_called(src, args.instr_frames) for src in sources}
    print("kernel_shares: all kernels built in ...", file=sys.stderr, flush=True)
    base = bench_instructions("", args.instr_frames, sources)
    cases = list(base)
    lines = ["| kernel | " + " | ".join(cases) + " | max % | keep |",
             "|---|" + "---|" * (len(cases) + 2),
             "| (M instr/frame, all built) | " + " | ".join(f"{base[c] / 1e6:.2f}" for c in cases) + " | | |"]
    with (open(args.out, "w") if args.out else contextlib.nullcontext()) as out:
        _emit(out, "\n".join(lines))       # each row as it is measured: a long run shows progress
        for name in names:
            print(f"kernel_shares: {name} pure ...", file=sys.stderr, flush=True)
            if calls is None:
                pure = bench_instructions(name, args.instr_frames, args.source)
            else:   # only the cases that call one of the group's kernels
                group = set(name.split(","))
                todo = [src for src, c in zip(sources, cases) if group & calls[c]]
                pure = bench_instructions(name, args.instr_frames, todo) if todo else {}
            shares = {c: 100.0 * (pure[c] - base[c]) / base[c] for c in cases if c in pure}
            best = max(shares.values(), default=0.0)
            lines.append(f"| {name} | " + " | ".join(f"{shares[c]:.1f}" if c in shares else "-" for c in cases)
                         + f" | {best:.1f} | {'yes' if best >= KEEP_SHARE_PCT else 'no'} |")
            _emit(out, lines[-1])
    return 0


def _emit(out, text: str) -> None:
    """Print `text` and append it to the open --out file, both flushed at once."""
    print(text, flush=True)
    if out is not None:
        out.write(text + "\n")
        out.flush()


if __name__ == "__main__":
    raise SystemExit(main())
