"""Safe reading and writing of the project's files: input limits, no writing over an input,
atomic replacement, JSON without NaN/Infinity.

* `read_text(path, what, max_bytes)`: a regular file (never a FIFO or device, which would block
  or never end), at most `max_bytes`, UTF-8; one-line `InputError` otherwise.
* `check_nesting(text, path, max_depth)`: a cheap scan of brackets/braces (and YAML indentation)
  before a recursive parser (json, cv2.FileStorage) sees the text: 100,000 nested lists are
  a RecursionError in json and a SIGSEGV in OpenCV.
* `load_json(path, what)`: read_text + check_nesting + json.loads, the map's loader.
* `claim_output(path, inputs, flag)`: every output of every command goes through this, before
  any work: refused (one-line `InputError`) when it resolves to an input (by st_dev/st_ino, so
  also through symlinks and hard links), to another output or to a folder. `Output.open()`
  stages a regular file anonymously in its folder and renames it into place on commit (a crash
  leaves nothing); a device, FIFO or socket is opened and written directly; a symlink is
  followed; an existing file keeps its mode. `StdoutOutput`: standard output, same interface.
* `dumps(obj)`: json.dumps with non-finite floats turned into null, allow_nan=False.
* `cv_path(path, what)`: a file name OpenCV can be given (UTF-8), or a one-line InputError.
"""

from __future__ import annotations

import errno
import json
import math
import os
import stat
import sys

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


def cv_path(path: str, what: str = "file") -> str:
    """`path` for an OpenCV call that takes a file name (VideoCapture, VideoWriter, FileStorage,
    imread): InputError when the name is not valid UTF-8 (bytes Python keeps as surrogates,
    e.g. a Latin-1 name under LANG=C), which OpenCV's binding turns into a segmentation fault."""
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        shown = path.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise InputError(f"{shown}: OpenCV cannot open a {what} whose path is not valid UTF-8 "
                         f"(rename it)") from None
    return path


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


class _DuplicateKey(ValueError):
    pass


def _unique_keys(pairs):
    """object_pairs_hook: the object, or _DuplicateKey when a key is given twice (json.loads
    keeps the last silently: a map whose second "leds" list replaced the first lost every light
    of it without a word)."""
    obj = dict(pairs)
    if len(obj) != len(pairs):
        seen = set()
        for k, _ in pairs:
            if k in seen:
                raise _DuplicateKey(f"key {k!r} given twice in one object")
            seen.add(k)
    return obj


def loads(text: str, where: str, *, unique_keys: bool = False):
    """json.loads with a one-line error for malformed text, too deep nesting and integers too
    long for Python (ValueError). NaN/Infinity tokens parse to floats: every field's validator
    rejects non-finite numbers with its own name. `unique_keys`: a key given twice in one object
    is an error (files a user writes by hand: maps, settings)."""
    try:
        return json.loads(text, object_pairs_hook=_unique_keys) if unique_keys else json.loads(text)
    except RecursionError:
        raise InputError(f"{where}: nested too deeply") from None
    except _DuplicateKey as e:
        raise InputError(f"{where}: {e}") from None
    except ValueError as e:  # json.JSONDecodeError, huge integers, NaN
        msg = getattr(e, "msg", None) or str(e).splitlines()[0]
        raise InputError(f"{where}: not valid JSON ({msg})") from None


def load_json(path: str, what: str, max_bytes: int = MAX_JSON_BYTES):
    try:
        text = read_bytes(path, what, max_bytes).decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not valid JSON (not UTF-8 text)") from None
    check_nesting(text, path)
    return loads(text, path, unique_keys=True)


# Names in an input folder that a command reads: a recording's files and any image or video
# (a photo folder's images, calibration views). Other files in the folder are not inputs.
_MEDIA_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm",
               ".avi", ".mkv", ".mp4", ".mov", ".webm")


def _is_recording_file(name: str) -> bool:
    return (name.startswith("video.") or name in ("camera.yaml", "map.json", "truth.jsonl")
            or name.lower().endswith(_MEDIA_EXTS))


def _identities(inputs) -> dict[tuple[int, int], str]:
    """(st_dev, st_ino) -> path of every input file (symlinks followed); a folder stands for
    itself and the files in it that a command reads (`_is_recording_file`)."""
    ids: dict[tuple[int, int], str] = {}
    for inp in inputs:
        if inp is None or inp == "-":
            continue
        try:
            st = os.stat(inp)
        except (OSError, ValueError):
            continue
        ids.setdefault((st.st_dev, st.st_ino), inp)
        if stat.S_ISDIR(st.st_mode):
            try:
                names = os.listdir(inp)
            except OSError:
                continue
            for name in names:
                if _is_recording_file(name):
                    p = os.path.join(inp, name)
                    try:
                        sp = os.stat(p)
                    except OSError:
                        continue
                    ids.setdefault((sp.st_dev, sp.st_ino), p)
    return ids


# Named temporary files alive right now (the staging of a library that needs a path): removed
# by `remove_live_temps`, which the command line calls from its signal handlers and at exit.
_LIVE_TEMPS: set[str] = set()


def remove_live_temps() -> None:
    for p in list(_LIVE_TEMPS):
        try:
            os.unlink(p)
        except OSError:
            pass
        _LIVE_TEMPS.discard(p)


def _reason(e: OSError) -> str:
    return e.strerror or str(e)


class Output:
    """An output file of a command, checked before any work (`claim_output`).

    `target`: the path written (symlinks followed: a link is never replaced, its target is
    written). `special`: the target exists and is not a regular file (a device, FIFO or socket),
    so it is opened and written directly; a regular or new target is written to a file in its
    folder and renamed into place on commit (a crash never leaves half a file). An existing file
    keeps its mode; a new one gets the umask's."""

    def __init__(self, path: str, flag: str, target: str, st):
        self.path, self.flag, self.target = path, flag, target
        self.special = st is not None and not stat.S_ISREG(st.st_mode)
        self.mode = (st.st_mode & 0o7777) if st is not None and not self.special else None
        self.owner = (st.st_uid, st.st_gid) if st is not None and not self.special else None

    def open(self, binary: bool = False) -> "OutputFile":
        return OutputFile(self, binary)

    def write_bytes(self, data: bytes) -> None:
        with self.open(binary=True) as f:
            f.write(data)

    def write_text(self, text: str) -> None:
        with self.open() as f:
            f.write(text)

    def error(self, e: OSError) -> InputError:
        return InputError(f"cannot write {self.flag} {self.path}: {_reason(e)}")

    def staging_path(self, suffix: str) -> str:
        """A named temporary file (ending in `suffix`) for a library that only writes to a path
        (OpenCV's video writer); `commit_staged` moves it into place, `discard_staged` removes
        it. It is hidden in the target's folder (a private folder for a special target)."""
        import tempfile
        try:
            if self.special:
                folder = tempfile.mkdtemp(prefix=".occloc-")
                tmp = os.path.join(folder, "out" + suffix)
                open(tmp, "wb").close()
            else:
                fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(self.target) + ".",
                                           suffix=".tmp" + suffix, dir=os.path.dirname(self.target))
                os.close(fd)
        except OSError as e:
            raise self.error(e) from None
        _LIVE_TEMPS.add(tmp)
        return tmp

    def commit_staged(self, tmp: str) -> None:
        try:
            if self.special:
                with open(tmp, "rb") as src, self.open(binary=True) as dst:
                    while True:
                        block = src.read(1 << 20)
                        if not block:
                            break
                        dst.write(block)
            else:
                os.chmod(tmp, self.mode if self.mode is not None else 0o666 & ~_umask())
                os.replace(tmp, self.target)
                _LIVE_TEMPS.discard(tmp)
        except OSError as e:
            raise self.error(e) from None
        finally:
            self.discard_staged(tmp)

    def discard_staged(self, tmp: str) -> None:
        _LIVE_TEMPS.discard(tmp)
        for p in (tmp, os.path.dirname(tmp)) if self.special else (tmp,):
            try:
                os.rmdir(p) if p != tmp else os.unlink(p)
            except OSError:
                pass


class OutputFile:
    """A writable file of an `Output`: write(), flush(), commit() (into place), discard()
    (nothing left behind). A regular target is staged in an anonymous file of its folder
    (O_TMPFILE: nothing survives a crash, even SIGKILL) linked into place on commit; where the
    file system has no anonymous files, a hidden named one removed on error and on signals.
    Every OSError becomes an InputError naming the output. As a context manager: commit on
    success, discard on an exception."""

    def __init__(self, out: Output, binary: bool):
        self.out, self.tmp, self.done = out, None, False
        flags = os.O_WRONLY | getattr(os, "O_CLOEXEC", 0)
        try:
            if out.special:
                fd = os.open(out.target, flags)
            else:
                fd = self._stage(flags)
        except OSError as e:
            raise out.error(e) from None
        self.file = os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"}))

    def _stage(self, flags: int) -> int:
        folder = os.path.dirname(self.out.target)
        if hasattr(os, "O_TMPFILE"):
            try:
                return os.open(folder, flags | os.O_TMPFILE, 0o600)
            except OSError as e:
                if e.errno not in (errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL, errno.ENOENT):
                    raise
        import tempfile
        fd, self.tmp = tempfile.mkstemp(prefix="." + os.path.basename(self.out.target) + ".",
                                        suffix=".tmp", dir=folder)
        _LIVE_TEMPS.add(self.tmp)
        return fd

    def write(self, s):
        try:
            return self.file.write(s)
        except OSError as e:
            raise self.out.error(e) from None

    def flush(self) -> None:
        try:
            self.file.flush()
        except OSError as e:
            raise self.out.error(e) from None

    def commit(self) -> None:
        if self.done:
            return
        self.done = True
        out = self.out
        try:
            self.file.flush()
            if out.special:
                self.file.close()
                return
            fd = self.file.fileno()
            if out.owner is not None and out.owner != (os.geteuid(), os.getegid()):
                try:  # root replacing another user's file: it stays theirs
                    os.fchown(fd, *out.owner)
                except OSError:
                    pass
            os.fchmod(fd, out.mode if out.mode is not None else 0o666 & ~_umask())
            os.fsync(fd)
            if self.tmp is None:
                name = os.path.join(os.path.dirname(out.target),
                                    f".{os.path.basename(out.target)}.{os.getpid()}.{id(self):x}.tmp")
                # linkat(AT_SYMLINK_FOLLOW) through /proc: a plain link() would link the magic link
                proc = os.open("/proc/self/fd", os.O_RDONLY | os.O_DIRECTORY)
                try:
                    os.link(str(fd), name, src_dir_fd=proc, follow_symlinks=True)
                finally:
                    os.close(proc)
                self.tmp = name
                _LIVE_TEMPS.add(name)
            self.file.close()
            os.replace(self.tmp, out.target)
            _LIVE_TEMPS.discard(self.tmp)
            self.tmp = None
        except OSError as e:
            self.discard()
            raise out.error(e) from None

    def discard(self) -> None:
        self.done = True
        try:
            self.file.close()
        except OSError:
            pass
        if self.tmp is not None:
            _LIVE_TEMPS.discard(self.tmp)
            try:
                os.unlink(self.tmp)
            except OSError:
                pass
            self.tmp = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.discard()
        return False


class StdoutOutput:
    """Standard output with the OutputFile interface (write, flush, commit, discard): a write
    error (a full disk, a closed terminal) is an InputError naming standard output, never a
    bare OSError a command would blame on its input. `stream`: the stream wrapped (None:
    whatever sys.stdout is at each write). The command line puts one around sys.stdout for
    every command, argparse's --help and --version included."""

    def __init__(self, stream=None):
        self._stream = stream

    @property
    def stream(self):
        return sys.stdout if self._stream is None else self._stream

    def write(self, s):
        try:
            return self.stream.write(s)
        except BrokenPipeError:
            raise
        except OSError as e:
            raise InputError(f"cannot write standard output: {_reason(e)}") from None

    def flush(self) -> None:
        try:
            self.stream.flush()
        except BrokenPipeError:
            raise
        except OSError as e:
            raise InputError(f"cannot write standard output: {_reason(e)}") from None

    def commit(self) -> None:
        self.flush()

    def discard(self) -> None:
        try:
            self.flush()
        except InputError:
            pass

    def __getattr__(self, name):  # isatty, fileno, encoding, buffer ... of the stream
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.stream, name)


def claim_output(path: str | None, inputs=(), flag: str = "--out", *, others=(),
                 update: bool = False) -> Output | None:
    """The checked `Output` of `path` (None for None): an InputError, before any work, when the
    path (symlinks and hard links followed) is one of `inputs` (files, or folders standing for
    the files in them that a command reads), one of the `others` (this command's other outputs),
    a folder, or inside a folder that is not there. `update`: the output is meant to replace
    the input of the same name (a file updated in place), which is not refused."""
    if path is None:
        return None
    if path == "":
        raise InputError(f"{flag}: empty file name")
    try:
        st = os.stat(path)  # the kernel follows links, /dev/stdout's /proc/self/fd/1 -> pipe:[N] too
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise InputError(f"cannot write {flag} {path}: {_reason(e)}") from None
    # A device, FIFO or socket is opened by the name given (a magic link such as /dev/stdout has
    # no path to resolve to); a file is staged beside the file the links lead to.
    special = st is not None and not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode)
    target = path if special else os.path.realpath(path)
    if st is not None and not special:
        try:
            st = os.stat(target)
        except OSError as e:
            raise InputError(f"cannot write {flag} {path}: {_reason(e)}") from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise InputError(f"{flag} {path} is a folder: give a file name")
    if path.endswith(os.sep) or os.path.basename(path) in ("", ".", ".."):
        raise InputError(f"{flag} {path} is a folder: give a file name")
    if st is None:
        folder = os.path.dirname(target)
        if not os.path.isdir(folder):
            raise InputError(f"cannot write {flag} {path}: no folder {os.path.dirname(path) or '.'}")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise InputError(f"cannot write {flag} {path}: Permission denied")
        key = None
    else:
        key = (st.st_dev, st.st_ino)
    ids = _identities(inputs)
    if update and key is not None:
        ids.pop(key, None)
    if key is not None and key in ids:
        raise InputError(f"{flag} {path} is an input of this command ({ids[key]}): refusing to overwrite it")
    if key is None and not update:
        for inp in inputs:
            if inp not in (None, "-") and os.path.realpath(inp) == target:
                raise InputError(f"{flag} {path} is an input of this command ({inp}): refusing to overwrite it")
    for other_flag, other in others:
        if other is None:
            continue
        if os.path.realpath(other) == target or (key is not None and _key(other) == key):
            raise InputError(f"{flag} {path} is also {other_flag}: give each output its own file")
    return Output(path, flag, target, st)


def _key(path: str):
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def refuse_overwrite(out: str | None, inputs, flag: str = "--out") -> None:
    """InputError when writing `out` would replace one of `inputs` (see `claim_output`)."""
    claim_output(out, inputs, flag)


class AtomicWriter(OutputFile):
    """An `OutputFile` of a path checked against nothing but its own kind (folders refused,
    devices written directly, symlinks followed)."""

    def __init__(self, path: str, mode: str = "w"):
        super().__init__(claim_output(path, (), "file"), "b" in mode)


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
