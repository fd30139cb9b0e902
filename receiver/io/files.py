"""Safe reading and writing of the project's files: input limits, no writing over an input,
atomic replacement, JSON without NaN/Infinity.

* `read_text(path, what, max_bytes)`: a regular file (never a FIFO or device, which would block
  or never end), at most `max_bytes`, UTF-8; one-line `InputError` otherwise.
* `check_nesting(text, path, max_depth)`: a cheap scan of brackets/braces (and YAML indentation)
  before a recursive parser (json, cv2.FileStorage) sees the text: 100,000 nested lists are
  a RecursionError in json and a SIGSEGV in OpenCV.
* `load_json(path, what)`: read_text + check_nesting + json.loads, the map's loader.
* `refuse_overwrite(out, inputs, flag)`: `out` must not be one of the command's inputs (by
  os.path.samefile, so also through symlinks and hard links, and by realpath for files not
  yet there).
* `AtomicWriter(path)`: a temporary file in the target's folder, renamed over `path` on
  `commit()`, removed on `discard()`: a crash never leaves half a file.
* `dumps(obj)`: json.dumps with non-finite floats turned into null, allow_nan=False.
"""

from __future__ import annotations

import json
import math
import os
import stat
import tempfile

from receiver.core.errors import InputError

# Input files of the project are small: a camera file is a few hundred bytes, a map of a large
# building some MB, truth/run files of a long recording tens of MB.
MAX_CAMERA_BYTES = 1 << 20
MAX_JSON_BYTES = 64 << 20
MAX_JSONL_BYTES = 512 << 20
# Deepest nesting of brackets/braces any of the formats needs is 4 (map emitters); allow slack.
MAX_NESTING = 64


def check_regular(path: str, what: str = "file") -> None:
    """InputError unless `path` is an existing regular file (FIFOs, sockets, devices refused)."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise InputError(f"{what} not found: {path}" if isinstance(e, FileNotFoundError)
                         else f"{path}: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file")
        raise InputError(f"{path}: {what} is {kind}, not a regular file")


def read_bytes(path: str, what: str, max_bytes: int) -> bytes:
    check_regular(path, what)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise InputError(f"{path}: cannot read {what} ({e.strerror or e})") from None
    if len(data) > max_bytes:
        raise InputError(f"{path}: {what} larger than {max_bytes} bytes")
    return data


def read_text(path: str, what: str, max_bytes: int) -> str:
    data = read_bytes(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: {what} is not UTF-8 text") from None


def nesting_depth(text: str) -> int:
    """Deepest bracket/brace nesting of `text` (strings are not skipped: an over-estimate only)."""
    depth = best = 0
    for ch in text:
        if ch in "[{":
            depth += 1
            if depth > best:
                best = depth
        elif ch in "]}":
            depth = max(0, depth - 1)
    return best


def check_nesting(text: str, where: str, max_depth: int = MAX_NESTING, yaml: bool = False) -> None:
    """InputError when brackets/braces (or, for YAML, indentation levels) nest deeper than max_depth."""
    if text.count("[") + text.count("{") > max_depth:  # cheap pre-check before the scan
        if nesting_depth(text) > max_depth:
            raise InputError(f"{where}: nested more than {max_depth} levels deep")
    if yaml:
        levels = set()
        for line in text.splitlines():
            stripped = line.lstrip(" -")
            if stripped and not stripped.startswith("#"):
                levels.add(len(line) - len(stripped))
        if len(levels) > max_depth:
            raise InputError(f"{where}: nested more than {max_depth} levels deep")


def loads(text: str, where: str):
    """json.loads with a one-line error for malformed text, too deep nesting and integers too
    long for Python (ValueError). NaN/Infinity tokens parse to floats: every field's validator
    rejects non-finite numbers with its own name."""
    try:
        return json.loads(text)
    except RecursionError:
        raise InputError(f"{where}: nested too deeply") from None
    except ValueError as e:  # json.JSONDecodeError, huge integers, NaN
        msg = getattr(e, "msg", None) or str(e).splitlines()[0]
        raise InputError(f"{where}: not valid JSON ({msg})") from None


def load_json(path: str, what: str, max_bytes: int = MAX_JSON_BYTES):
    try:
        text = read_bytes(path, what, max_bytes).decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not valid JSON (not UTF-8 text)") from None
    check_nesting(text, path)
    return loads(text, path)


def _same(a: str, b: str) -> bool:
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def refuse_overwrite(out: str | None, inputs, flag: str = "--out") -> None:
    """InputError when writing `out` would replace one of `inputs` (files or folders whose files
    are inputs: a recording folder's video, map, camera, truth)."""
    if out is None:
        return
    for inp in inputs:
        if inp is None or inp == "-":
            continue
        if _same(out, inp):
            raise InputError(f"{flag} {out} is an input of this command ({inp}): refusing to overwrite it")
        if os.path.isdir(inp) and os.path.exists(out) and not os.path.isdir(out):
            # a file inside an input folder that the command reads (recording files)
            for name in os.listdir(inp):
                p = os.path.join(inp, name)
                if os.path.isfile(p) and _same(out, p) and _is_recording_file(name):
                    raise InputError(f"{flag} {out} is an input of this command ({p}): refusing to overwrite it")


def _is_recording_file(name: str) -> bool:
    return name.startswith("video.") or name in ("camera.yaml", "map.json", "truth.jsonl")


class AtomicWriter:
    """Text file written to a temporary sibling and renamed over `path` on commit()."""

    def __init__(self, path: str, mode: str = "w"):
        self.path = path
        folder = os.path.dirname(os.path.abspath(path))
        try:
            fd, self.tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
        except OSError as e:
            raise InputError(f"cannot write {path}: {e.strerror or e}") from None
        self.file = os.fdopen(fd, mode, encoding=None if "b" in mode else "utf-8")

    def write(self, s):
        return self.file.write(s)

    def flush(self):
        self.file.flush()

    def commit(self) -> None:
        if self.file.closed and not os.path.exists(self.tmp):
            return
        self.file.close()
        try:
            mode = os.stat(self.path).st_mode & 0o777 if os.path.exists(self.path) else 0o666 & ~_umask()
            os.chmod(self.tmp, mode)
        except OSError:
            pass
        os.replace(self.tmp, self.path)

    def discard(self) -> None:
        try:
            self.file.close()
        finally:
            try:
                os.unlink(self.tmp)
            except OSError:
                pass


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def finite_or_none(obj):
    """A copy of a JSON-able structure with non-finite floats replaced by None."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):  # numpy arrays and scalars
        return finite_or_none(obj.tolist())
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    return obj


def dumps(obj, **kw) -> str:
    """json.dumps that never writes NaN/Infinity (they become null)."""
    try:
        return json.dumps(obj, allow_nan=False, **kw)
    except ValueError:
        default = kw.get("default")
        if default is not None:  # apply it first, so that what it returns is cleaned too
            kw = dict(kw, default=lambda v: finite_or_none(default(v)))
        return json.dumps(finite_or_none(obj), allow_nan=False, **kw)


def read_jsonl(path: str, what: str, *, require: bool = True,
               max_bytes: int = MAX_JSONL_BYTES) -> list[tuple[int, dict]]:
    """(line number, object) for every non-empty line of a JSON Lines file (a regular file of
    at most `max_bytes`; every line nesting-checked before json sees it, NaN/Infinity and
    numbers too long for Python refused). `require`: an empty file is an error."""

    if not os.path.exists(path):
        raise InputError(f"cannot read {what} file {path}: No such file or directory")
    try:
        text = read_bytes(path, f"{what} file", max_bytes).decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{what} file {path} is not UTF-8 text") from None
    out = []
    for n, line in enumerate(text.split("\n"), 1):
        if not line.strip():
            continue
        where = f"{path}:{n}"
        check_nesting(line, where)
        try:
            obj = loads(line, where)
        except InputError as e:
            raise InputError(str(e).replace("not valid JSON", "malformed JSON")) from None
        if not isinstance(obj, dict):
            raise InputError(f"{path}:{n}: expected a JSON object per line")
        out.append((n, obj))
    if require and not out:
        raise InputError(f"{what} file {path} has no frames")
    return out
