"""Bad-input sweep: run every command of the project on damaged, hostile or wrong input and
check that it never hangs, never prints a traceback, never damages its input, never leaves a
hidden temporary file, and keeps standard output clean.

    python tools/badinput_sweep.py [--quick] [--seed N] [--budget-s S] [--realtime-runs 20]
                                   [--only SUBSTRING] [--keep]
    python tools/badinput_sweep.py --settings-probe [--only FIELD-SUBSTRING]

Prints one row per case: input, exit code, first line of stderr, traceback yes/no, input
intact yes/no, and a closing line `N cases, M held`. Exits 1 when any row has a traceback, a
hang (timeout), a damaged input or a failed check. Every case works on copies in a temporary
folder; the bundled recordings are only read. `--quick`: the cases marked quick (one or more of
every command and class, a few frames each), for CI. `--seed`: the seeded cases (random option
values, random cuts and byte flips, signal delays) draw from random.Random(seed). `--budget-s`:
cases not started within this many seconds are counted as not run (said in the closing line).
`--settings-probe`: instead of the cases, every numeric field of every settings record is set to
each of `PROBE_VALUES` in a file given to `occloc run --settings` (in this process: thousands of
runs); each must run cleanly or be refused in one line.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import struct
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REC = os.path.join(ROOT, "recordings")
PY = sys.executable
TIMEOUT_S = 90


def occloc(*args) -> list[str]:
    return [PY, "-m", "receiver.cli", *args]


def sha(path: str) -> str | None:
    if os.path.isdir(path):
        h = hashlib.sha256()
        for name in sorted(os.listdir(path)):
            h.update(name.encode())
            h.update((sha(os.path.join(path, name)) or "-").encode())
        return h.hexdigest()
    if not os.path.isfile(path):
        return None
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


class Case:
    """One command line. `inputs`: files/folders that must be byte-identical afterwards;
    `expect`: allowed exit codes (None: any); `check(rc, out, err) -> problem or ''`;
    `clean`: folders that must hold no hidden (dot) file afterwards; `quick`: in --quick."""

    def __init__(self, name, argv, inputs=(), shell=False, stdin=None, expect=None, signal_after=None,
                 check=None, clean=(), quick=False, preexec_fn=None):
        self.name, self.argv, self.inputs, self.shell = name, argv, list(inputs), shell
        self.stdin, self.expect, self.signal_after, self.check = stdin, expect, signal_after, check
        self.clean, self.quick, self.preexec_fn = list(clean), quick, preexec_fn


def run_case(c: Case) -> dict:
    before = {p: sha(p) for p in c.inputs}
    t0 = time.monotonic()
    hung = False
    stdin = open(c.stdin, "rb") if isinstance(c.stdin, str) else c.stdin
    try:
        p = subprocess.Popen(c.argv, cwd=ROOT, shell=c.shell, stdin=stdin if stdin is not None else subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                             executable="/bin/bash" if c.shell else None, preexec_fn=c.preexec_fn)
        if c.signal_after is not None:
            sig, delay = c.signal_after
            time.sleep(delay)
            os.killpg(p.pid, sig) if c.shell else p.send_signal(sig)
        try:
            out, err = p.communicate(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            hung = True
            os.killpg(p.pid, signal.SIGKILL)
            out, err = p.communicate()
    finally:
        if isinstance(c.stdin, str):
            stdin.close()
    err_text = err.decode("utf-8", "replace")
    rc = p.returncode
    lines = [ln for ln in err_text.splitlines() if ln.strip() and not re.match(r"^(frame|synth \S+: frame) \d+", ln)]
    row = {"input": c.name, "rc": "HANG" if hung else rc, "stderr": lines[0][:100] if lines else "",
           "traceback": "Traceback" in err_text or "Fatal Python error" in err_text or (rc is not None and rc < 0
                                                                                         and c.signal_after is None),
           "intact": all(sha(q) == before[q] for q in c.inputs), "s": time.monotonic() - t0, "hung": hung,
           "problem": ""}
    problems = []
    if c.check is not None and not hung:
        problems.append(c.check(rc, out.decode("utf-8", "replace"), err_text) or "")
    if c.expect is not None and not hung and rc not in c.expect:
        problems.append(f"exit {rc}, expected {'/'.join(map(str, c.expect))}")
    for folder in c.clean:
        left = [n for n in os.listdir(folder) if n.startswith(".")] if os.path.isdir(folder) else []
        if left:
            problems.append(f"hidden file left: {left[0]}")
    row["problem"] = "; ".join(p for p in problems if p)
    return row


def _movi_chunks(data: bytes) -> list[int]:
    m = data.find(b"movi")
    p, out = m + 4, []
    while p + 8 <= len(data):
        cid, size = data[p:p + 4], struct.unpack("<I", data[p + 4:p + 8])[0]
        if cid == b"idx1":
            break
        out.append(p)
        p += 8 + size + (size & 1)
    return out


def build_cases(tmp: str, realtime_runs: int) -> list[Case]:
    walk, static, vehicle = (os.path.join(REC, n) for n in ("indoor-walk", "indoor-static", "vehicle"))
    cam_ok = open(os.path.join(static, "camera.yaml"), encoding="utf-8").read()
    map_ok = json.load(open(os.path.join(static, "map.json"), encoding="utf-8"))
    cases: list[Case] = []

    def copy_rec(name, src=static):
        d = os.path.join(tmp, name)
        shutil.copytree(src, d)
        return d

    def write(name, text):
        p = os.path.join(tmp, name)
        with open(p, "w", encoding="utf-8") as f:
            f.write(text)
        return p

    def run_with(label, cam=None, map_=None, extra=(), src=static, frames="3"):
        args = ["run", src, "--max-frames", frames, *extra]
        inputs = [src]
        if cam:
            args += ["--camera", cam]
            inputs.append(cam)
        if map_:
            args += ["--map", map_]
            inputs.append(map_)
        cases.append(Case(label, occloc(*args), inputs))

    def summary_check(rc, out, err):
        if "frames," not in err:
            return "no summary"
        if out and not out.endswith("\n"):
            return "last line cut"
        return ""

    # 1. --realtime: no hang, no abort, video and stdin
    for i in range(realtime_runs):
        cases.append(Case(f"run indoor-walk --realtime --max-frames 5 (#{i + 1})",
                          occloc("run", walk, "--realtime", "--max-frames", "5"), [walk], check=summary_check))
    raw = os.path.join(tmp, "frames.raw")
    with open(raw, "wb") as f:
        f.write(bytes(1280 * 720 * 12))
    for i in range(realtime_runs):
        cmd = (f"(cat {raw}; sleep 3) | {PY} -m receiver.cli run - --camera {walk}/camera.yaml --map {walk}/map.json "
               f"--size 1280x720 --realtime --max-frames 5")
        cases.append(Case(f"run - --realtime (open writer) (#{i + 1})", cmd, [raw], shell=True, check=summary_check))
    # 2. camera files
    cases.append(Case("camera.yaml of 50,000 nested '['",
                      occloc("run", static, "--camera", write("deep.yaml", "%YAML 1.2\n---\nimage_width: " + "[" * 50000 + "\n"),
                             "--max-frames", "1"), [static]))
    for key, value in [("pixel_size_um", ".nan"), ("focal_length_mm", ".inf"), ("row_readout_us", ".nan"),
                       ("row_readout_us", "1e300"), ("row_readout_us", "1e-300"), ("image_width", ".nan"),
                       ("image_width", ".inf"), ("row_readout_us", "0."), ("exposure_us", ".nan"), ("fps", "1e300")]:
        text = re.sub(rf"(?m)^{key}:.*$", f"{key}: {value}", cam_ok)
        run_with(f"camera {key}: {value}", cam=write(f"cam-{key}-{value}.yaml", text))
    text = re.sub(r"data: \[ -0\.04[^\]]*\]", "data: [ .nan, 0., 0., 0., 0. ]", cam_ok)
    run_with("camera distortion NaN", cam=write("cam-dist-nan.yaml", text))
    # 3. map files
    def map_variant(label, mutate):
        m = json.loads(json.dumps(map_ok))
        mutate(m)
        p = write(f"map-{len(cases)}.json", json.dumps(m))
        run_with(f"map {label}", map_=p, frames="12")
    map_variant("rate_hz 1e300", lambda m: m["leds"][0].__setitem__("rate_hz", 1e300))
    map_variant("rate_hz 1e-300", lambda m: m["leds"][0].__setitem__("rate_hz", 1e-300))
    map_variant("emitters strings", lambda m: m["leds"][0].__setitem__("emitters", ["ab", "cd"]))
    p = write("map-emit-big.json", json.dumps(map_ok).replace('"x":', '"emitters": [[1e400, 0, 0], [0, 0, 0]], "x":', 1))
    run_with("map emitters 1e400", map_=p)
    p = write("map-id-digits.json", json.dumps(map_ok).replace('"id": ', '"id": ' + "9" * 5001 + ', "_": ', 1))
    run_with("map 5,001-digit ID", map_=p)
    deep_json = write("deep.json", "[" * 100000 + "]" * 100000)
    run_with("map of 100,000 nested lists", map_=deep_json)
    cases.append(Case("serve --map of 100,000 nested lists", occloc("serve", "--map", deep_json), [deep_json]))
    # 4. nothing overwritten
    rec = copy_rec("rec-out")
    cases.append(Case("run rec --out rec/video.avi", occloc("run", rec, "--out", os.path.join(rec, "video.avi")), [rec]))
    cases.append(Case("run rec --out rec/map.json", occloc("run", rec, "--out", os.path.join(rec, "map.json")), [rec]))
    link = os.path.join(tmp, "link.jsonl")
    os.symlink(os.path.join(rec, "camera.yaml"), link)
    cases.append(Case("run rec --out symlink-to-rec/camera.yaml", occloc("run", rec, "--out", link), [rec]))
    run_file = os.path.join(tmp, "run.jsonl")
    subprocess.run(occloc("run", static, "--out", run_file), cwd=ROOT, capture_output=True, timeout=TIMEOUT_S)
    truth = os.path.join(static, "truth.jsonl")
    cases.append(Case("eval RUN --plot RUN", occloc("eval", run_file, "--truth", truth, "--plot", run_file), [run_file]))
    cases.append(Case("eval RUN --truth <another recording's truth>",
                      occloc("eval", run_file, "--truth", os.path.join(walk, "truth.jsonl")), [run_file]))
    deep_line = write("deep.jsonl", "[" * 100000 + "]" * 100000 + "\n")
    cases.append(Case("eval truth of 100,000 nested lists", occloc("eval", run_file, "--truth", deep_line), [run_file]))
    cases.append(Case("eval run of 100,000 nested lists", occloc("eval", deep_line, "--truth", truth), [deep_line]))
    existing = copy_rec("rec-synth")
    cases.append(Case("synth --out EXISTING_RECORDING", occloc("synth", "indoor-static", "--frames", "2", "--out", existing),
                      [existing]))
    # 5. damaged video (chunk headers of two frames)
    dmg = copy_rec("rec-damaged", walk)
    data = bytearray(open(os.path.join(dmg, "video.avi"), "rb").read())
    ch = _movi_chunks(bytes(data))
    for k in (20, 35):
        data[ch[k] + 4:ch[k] + 8] = b"\xff\xff\x00\x00"
    open(os.path.join(dmg, "video.avi"), "wb").write(data)
    cases.append(Case("run recording with 2 damaged AVI chunk headers", occloc("run", dmg, "--out", os.path.join(tmp, "d.jsonl")),
                      [dmg]))
    trunc = copy_rec("rec-truncated", walk)
    vp = os.path.join(trunc, "video.avi")
    data = open(vp, "rb").read()
    open(vp, "wb").write(data[:_movi_chunks(data)[16]])
    cases.append(Case("run recording cut after 16 of 54 frames", occloc("run", trunc, "--out", os.path.join(tmp, "t.jsonl")),
                      [trunc]))
    # 6. synth / hil arguments
    synth_out = os.path.join(tmp, "synth-new")
    for kv in ("fps=1e400", "dist=(1,2)", "read_noise_dn=nan", "fps=-1", "width=0"):
        cases.append(Case(f"synth --set {kv}", occloc("synth", "indoor-static", "--frames", "2", "--set", kv, "--out", synth_out)))
    cases.append(Case("synth --out /proc/x", occloc("synth", "indoor-static", "--frames", "2", "--out", "/proc/x")))
    cases.append(Case("synth --out an existing file", occloc("synth", "indoor-static", "--frames", "2", "--out", run_file),
                      [run_file]))
    cases.append(Case("hil --seed -1", occloc("hil", "--seed", "-1")))
    # 7. standard streams, FIFOs, arguments
    cases.append(Case("run - <&- (closed stdin)",
                      f"exec {PY} -m receiver.cli run - --size 64x36 --camera {walk}/camera.yaml --map {walk}/map.json <&-",
                      shell=True))
    cases.append(Case("run REC >&- (closed stdout)", f"exec {PY} -m receiver.cli run {static} --max-frames 2 >&-",
                      [static], shell=True))
    fifo = os.path.join(tmp, "x.png")
    os.mkfifo(fifo)
    cases.append(Case("run FIFO x.png (no writer)", occloc("run", fifo, "--camera", os.path.join(static, "camera.yaml"),
                                                           "--map", os.path.join(static, "map.json"))))
    run_with("run --fps inf", extra=("--fps", "inf"))
    # 8. signals mid-run: summary printed, whole lines
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        cmd = f"exec {PY} -m receiver.cli run {walk}"
        cases.append(Case(f"run indoor-walk, {sig.name} after 6 s", cmd, [walk], shell=True,
                          signal_after=(sig, 6.0), check=summary_check))
    return cases


def _json_lines_only(rc, out, err):
    bad = [ln for ln in out.splitlines() if not ln.startswith("{")]
    return f"stdout holds a non-JSON line: {bad[0][:40]!r}" if bad else ""


def _no_nan(rc, out, err):
    return "nan in output" if re.search(r"\bnan\b", out + err, re.I) else ""


def _clean_end(rc, out, err):
    """Exit 0 with no NaN in the output, or a refusal whose last stderr line is our one-line
    error (which may quote a bad value, NaN included) and no NaN on standard output."""
    if rc == 0:
        return _no_nan(rc, out, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if not lines or not lines[-1].startswith("occloc"):
        return "no one-line error"
    return "nan in output" if re.search(r"\bnan\b", out, re.I) else ""


def _says(*words):
    def check(rc, out, err):
        missing = [w for w in words if w not in err]
        return f"stderr lacks {missing[0]!r}" if missing else ""
    return check


def _no_raw_decoder_text(rc, out, err):
    """No line of stderr that is not ours (`occloc...`) carries a decoder's own message."""
    raw = "\n".join(ln for ln in err.splitlines() if not ln.startswith("occloc"))
    for w in ("Premature end", "Corrupt JPEG", "libpng", "[ WARN:", "[ERROR:"):
        if w in raw:
            return f"raw decoder message on stderr: {w!r}"
    return ""


def _all(*checks):
    def check(rc, out, err):
        return "; ".join(p for p in (c(rc, out, err) for c in checks) if p)
    return check


def _file_limit():
    """preexec_fn: files stop growing at 64 KB (EFBIG): a full disk for the command's outputs."""
    import resource
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 << 10, 64 << 10))


def _png_header(path, w, h):
    import zlib

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", __import__("zlib").compress(bytes(64))) + chunk(b"IEND", b""))


# Numeric options of every command, with a valid value each (the seeded cases replace it with
# a hostile one: huge, tiny, negative, zero, NaN, infinite, not a number).
NUMERIC_OPTIONS = [
    (("run", "{static}", "--max-frames", "2"), "--fps", "30"),
    (("run", "{static}"), "--max-frames", "2"),
    (("run", "{static}", "--max-frames", "2"), "--max-pixels", "1000000"),
    (("run", "{static}", "--max-frames", "2"), "--threads", "1"),
    (("calibrate", "intrinsics", "{views}", "--board", "chess:9x6", "--out", "{tmp}/i.yaml"), "--square-mm", "20"),
    (("calibrate", "intrinsics", "{views}", "--board", "chess:9x6", "--square-mm", "20", "--out", "{tmp}/i.yaml"),
     "--max-views", "40"),
    (("calibrate", "intrinsics", "{views}", "--board", "chess:9x6", "--square-mm", "20", "--out", "{tmp}/i.yaml"),
     "--max-blur-px", "4"),
    (("calibrate", "rows", "{static}", "--camera", "{static}/camera.yaml", "--out", "{tmp}/r.yaml",
      "--max-frames", "5"), "--freq-hz", "1000"),
    (("calibrate", "rows", "{static}", "--camera", "{static}/camera.yaml", "--out", "{tmp}/r.yaml",
      "--max-frames", "5"), "--ook-rate", "20000"),
    (("eval", "{run}", "--truth", "{static}/truth.jsonl"), "--gate-px", "15"),
    (("eval", "{run}", "--truth", "{static}/truth.jsonl"), "--fv-gate-deg", "5"),
    (("check", "{static}"), "--max-frames", "5"),
    (("bench", "{static}", "--frames", "2"), "--repeat", "1"),
    (("tx", "--port", "loop://", "--status"), "--timeout", "0.2"),
]
HOSTILE = ["1e300", "1e-300", "-1", "0", "nan", "inf", "-inf", "1e400", "x", "9" * 40]


def build_more_cases(tmp: str, rng) -> list[Case]:
    """The output discipline, full disks, closed streams, range checks, bounded work and silent
    loss, for every command; `rng` draws the seeded ones."""
    import numpy as np
    static, vehicle = os.path.join(REC, "indoor-static"), os.path.join(REC, "vehicle")
    cases: list[Case] = []
    full = "/dev/full"

    def rec(name):
        d = os.path.join(tmp, name)
        shutil.copytree(static, d)
        return d

    def outdir(name):
        d = os.path.join(tmp, name)
        os.makedirs(d, exist_ok=True)
        return d

    r = rec("out-rec")
    o = outdir("outs")
    cam, map_, truth = (os.path.join(r, n) for n in ("camera.yaml", "map.json", "truth.jsonl"))
    hard = os.path.join(o, "hard.jsonl")
    os.link(os.path.join(r, "video.avi"), hard)
    soft = os.path.join(o, "soft.jsonl")
    os.symlink(cam, soft)
    run_file = os.path.join(tmp, "run3.jsonl")
    subprocess.run(occloc("run", static, "--max-frames", "3", "--out", run_file), cwd=ROOT, capture_output=True,
                   timeout=TIMEOUT_S)
    views = outdir("views")
    import cv2
    for i in range(3):
        cv2.imwrite(os.path.join(views, f"v{i}.png"), np.full((90, 160), 60 * i, np.uint8))
    fmt = {"static": static, "views": views, "tmp": o, "run": run_file}

    def case(name, argv, inputs=(r,), **kw):
        kw.setdefault("clean", [o, r, tmp])
        cases.append(Case(name, argv, list(inputs), **kw))

    refused = dict(expect=(2,))
    is_input = dict(expect=(2,), check=_says("input of this command"))
    # -- outputs that are inputs, folders, other outputs (every command that writes a file)
    case("run --out hard link to the video", occloc("run", r, "--out", hard), quick=True, **is_input)
    case("run --out symlink to camera.yaml", occloc("run", r, "--out", soft), **is_input)
    case("run --overlay map.json", occloc("run", r, "--max-frames", "2", "--overlay", map_), **is_input)
    case("run --settings-out truth.jsonl", occloc("run", r, "--settings-out", truth), **is_input)
    case("run --out DIR", occloc("run", r, "--out", o), quick=True, **refused)
    case("run --overlay DIR", occloc("run", r, "--overlay", o), **refused)
    case("run --out X --settings-out X", occloc("run", r, "--out", f"{o}/x", "--settings-out", f"{o}/x"), **refused)
    case("eval --plot map.json beside truth", occloc("eval", run_file, "--truth", truth, "--plot", map_),
         quick=True, **is_input)
    case("eval --plot RUN", occloc("eval", run_file, "--truth", truth, "--plot", run_file), [r, run_file], **is_input)
    case("calibrate rows --out video.avi", occloc("calibrate", "rows", r, "--camera", cam, "--ook-rate", "20000",
                                                  "--out", os.path.join(r, "video.avi")), **is_input)
    case("calibrate rows --out map.json --map map.json",
         occloc("calibrate", "rows", r, "--camera", cam, "--ook-rate", "20000", "--out", map_, "--map", map_), **is_input)
    case("calibrate intrinsics --out a source image",
         occloc("calibrate", "intrinsics", views, "--board", "chess:9x6", "--square-mm", "20",
                "--out", os.path.join(views, "v1.png")), [views], quick=True, **is_input)
    case("calibrate intrinsics --out DIR", occloc("calibrate", "intrinsics", views, "--board", "chess:9x6",
                                                  "--square-mm", "20", "--out", o), [views], **refused)
    fifo = os.path.join(o, "fifo")
    os.mkfifo(fifo)
    case("run --out FIFO (reader: cat)", f"cat {fifo} > {o}/fifo.txt & exec {PY} -m receiver.cli run {r} "
         f"--max-frames 2 --out {fifo}", shell=True, expect=(0,), quick=True,
         check=lambda rc, out, err: "" if os.path.exists(fifo) and not os.path.isfile(fifo) else "FIFO replaced")
    # -- full disks and closed streams
    for cmd in (("run", r, "--max-frames", "2"), ("eval", run_file, "--truth", truth), ("check", r, "--max-frames", "5"),
                ("bench", r, "--frames", "2"), ("calibrate", "rows", r, "--camera", cam, "--ook-rate", "20000",
                                                "--max-frames", "5", "--out", f"{o}/rows.yaml")):
        case(f"{cmd[0]} >/dev/full", f"exec {PY} -m receiver.cli {' '.join(cmd)} >{full}", shell=True, expect=(2,),
             check=_says("standard output"), quick=cmd[0] in ("run", "eval"))
    # a private copy of /dev/full (root): a regression must never replace the system's device
    dev = os.path.join(o, "full")
    try:
        os.mknod(dev, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
        case("run --out DEVICE (a /dev/full)", occloc("run", r, "--max-frames", "2", "--out", dev), quick=True,
             check=_all(_says("No space left"),
                        lambda rc, out, err: "" if stat.S_ISCHR(os.stat(dev).st_mode) else "device replaced"),
             **refused)
    except OSError:
        pass
    case("run --out on a full disk", occloc("run", os.path.join(REC, "indoor-walk"), "--out", f"{o}/big.jsonl"),
         preexec_fn=_file_limit, check=_says("--out"), **refused)
    case("run --overlay o.avi on a full disk", occloc("run", r, "--max-frames", "12", "--out", f"{o}/ov.jsonl",
                                                     "--overlay", f"{o}/ov.avi"),
         preexec_fn=_file_limit, check=_says("--overlay"), quick=True, **refused)
    case("firmware_tx >/dev/full", f"echo PING | exec {PY} -m firmware_tx >{full}", shell=True, expect=(1,),
         quick=True)
    case("run 2>&- (closed stderr)", f"exec {PY} -m receiver.cli run {r} --max-frames 2 2>&-", shell=True,
         expect=(0,), check=_json_lines_only, quick=True)
    case("run --max-frames 0", occloc("run", r, "--max-frames", "0"), expect=(0,), check=_no_nan)
    # -- range checks (seeded hostile values for every numeric option)
    for base, opt, _ok in NUMERIC_OPTIONS:
        for value in rng.sample(HOSTILE, 3):
            if opt in ("--max-frames",) and value == "0" and base[0] == "run":
                continue  # 0 frames is a valid request
            argv = [a.format(**fmt) for a in base] + [opt, value]
            case(f"{base[0]} {opt} {value}", occloc(*argv), [r, views], expect=(2,))
    quick_opts = [("calibrate", "intrinsics", views, "--board", "chess:9x6", "--square-mm", "1e300", "--out", f"{o}/q.yaml"),
                  ("calibrate", "intrinsics", views, "--board", "chess:9x6", "--square-mm", "20", "--max-views", "1",
                   "--out", f"{o}/q.yaml"),
                  ("calibrate", "rows", r, "--camera", cam, "--freq-hz", "1e-10")]
    for argv in quick_opts:
        case(f"{argv[0]} {argv[1]} {' '.join(argv[-4:-2] if argv[1] == 'intrinsics' else argv[-2:])}",
             occloc(*argv), [r, views], expect=(2,), quick=True)
    # -- bounded work
    lines = open(run_file, encoding="utf-8").read().splitlines()
    tlines = open(os.path.join(vehicle, "truth.jsonl"), encoding="utf-8").read().splitlines()
    vrun = os.path.join(tmp, "vrun2.jsonl")
    subprocess.run(occloc("run", vehicle, "--max-frames", "2", "--out", vrun), cwd=ROOT, capture_output=True,
                   timeout=TIMEOUT_S)
    vlines = open(vrun, encoding="utf-8").read().splitlines()
    for big in (3 * 10 ** 7, 10 ** 12):
        ro, to = json.loads(vlines[1]), json.loads(tlines[1])
        ro["frame"] = to["frame"] = big
        rp, tp = os.path.join(tmp, f"vr{big}.jsonl"), os.path.join(tmp, f"vt{big}.jsonl")
        open(rp, "w").write(vlines[0] + "\n" + json.dumps(ro) + "\n")
        open(tp, "w").write(tlines[0] + "\n" + json.dumps(to) + "\n")
        case(f"eval 2-line vehicle run, frame {big:.0e}", occloc("eval", rp, "--truth", tp, "--map",
                                                               os.path.join(vehicle, "map.json")),
             [rp, tp], expect=(0,), quick=big > 10 ** 9)
    huge = os.path.join(tmp, "huge.png")
    _png_header(huge, 32000, 18000)
    case("run 32000x18000 PNG (header)", occloc("run", huge, "--camera", cam, "--map", map_), [huge, r],
         check=_says("pixel limit"), quick=True, **refused)
    case("run - --size 100000x100000", occloc("run", "-", "--size", "100000x100000", "--camera", cam, "--map", map_),
         **refused)
    del lines
    # -- silent loss: damaged photos (seeded cuts), first file unreadable
    img = (np.indices((180, 320)).sum(axis=0) % 256).astype(np.uint8)
    jpg = cv2.imencode(".jpg", img)[1].tobytes()
    for k in range(4):
        cut = rng.uniform(0.1, 0.9)
        pth = os.path.join(tmp, f"cut{k}.jpg")
        open(pth, "wb").write(jpg[:int(len(jpg) * cut)])
        case(f"run one JPEG cut at {cut:.2f}", occloc("run", pth, "--camera", cam, "--map", map_), [pth, r],
             check=_no_raw_decoder_text, quick=k == 0, **refused)
    ph = outdir("photos")
    open(os.path.join(ph, "a.jpg"), "wb").write(jpg[:len(jpg) // 3])
    for n in ("b.jpg", "c.jpg"):
        open(os.path.join(ph, n), "wb").write(jpg)
    case("run photo folder, first JPEG cut to a third", occloc("run", ph, "--camera", cam, "--map", map_), [ph, r],
         expect=(0,), check=_all(_says("skipped corrupt frames: 1"), _no_raw_decoder_text, _json_lines_only),
         quick=True)
    for k in range(3):
        data = bytearray(jpg)
        for _ in range(8):
            data[rng.randrange(200, len(data) - 2)] = rng.randrange(256)
        pth = os.path.join(tmp, f"flip{k}.jpg")
        open(pth, "wb").write(bytes(data))
        case(f"run JPEG with 8 random bytes changed (#{k})", occloc("run", pth, "--camera", cam, "--map", map_),
             [pth, r], expect=(0, 2), check=_no_raw_decoder_text)
    # -- interrupts at seeded moments, including imports
    for k in range(4):
        delay = round(rng.uniform(0.1, 3.0), 2)
        case(f"calibrate rows, SIGINT after {delay} s", f"exec {PY} -m receiver.cli calibrate rows {r} --camera {cam} "
             f"--ook-rate 20000 --out {o}/int.yaml", shell=True, signal_after=(signal.SIGINT, delay),
             expect=(0, 130, -signal.SIGINT), quick=k == 0)
    case("tx --port /nonexistent", occloc("tx", "--port", "/nonexistent/ttyACM0", "--status"), (), expect=(2,),
         quick=True)
    # -- help and version text lost on a full disk (argparse drops the error: exit 0)
    for args in ("--help", "--version", "run --help"):
        case(f"occloc {args} >/dev/full", f"exec {PY} -m receiver.cli {args} >{full}", shell=True, expect=(2,),
             check=_says("cannot write standard output"), quick=args == "--help")
    # -- names OpenCV's binding cannot take (not UTF-8: a segmentation fault inside OpenCV)
    latin = os.fsencode(tmp) + b"/caf\xe9"
    os.mkdir(latin)
    for name in ("camera.yaml", "map.json", "video.avi"):
        shutil.copy(os.path.join(static, name), latin + b"/" + name.encode())
    latin_s = os.fsdecode(latin)
    utf8 = dict(expect=(2,), check=_says("not valid UTF-8"))
    case("LANG=C run folder named caf\\xe9", f"LANG=C LC_ALL=C exec {PY} -m receiver.cli run '{latin_s}' --max-frames 2",
         [r], shell=True, quick=True, **utf8)
    case("run --overlay caf\\xe9/o.avi", occloc("run", r, "--max-frames", "2", "--out", f"{o}/u.jsonl",
                                             "--overlay", latin_s + "/o.avi"), **utf8)
    case("run --camera caf\\xe9/camera.yaml", occloc("run", r, "--max-frames", "2", "--camera", latin_s + "/camera.yaml"),
         **utf8)
    case("check caf\\xe9", occloc("check", latin_s, "--max-frames", "2"), **utf8)
    case("synth --out caf\\xe9/new", occloc("synth", "indoor-static", "--frames", "2", "--out", latin_s + "/new"),
         **utf8)
    # -- what an error line shows: control characters escaped; an empty name is not the demo
    def one_clean_line(rc, out, err):
        bad = [ch for ch in err if (ord(ch) < 32 and ch != "\n") or ord(ch) == 127]
        return f"raw control character {bad[0]!r} on stderr" if bad else ""
    case("run a name with a newline and an escape sequence", occloc("run", "/nonexistent/a\nb\x1b[2Jc"), (),
         expect=(2,), check=one_clean_line, quick=True)
    def two_json_lines(rc, out, err):
        return _json_lines_only(rc, out, err) or ("" if len(out.splitlines()) == 2 else "no JSON lines on the pipe")
    case("run --out /dev/stdout (a pipe)", occloc("run", r, "--max-frames", "2", "--out", "/dev/stdout"),
         expect=(0,), check=two_json_lines, quick=True)
    case('run "" (an unset variable)', occloc("run", ""), (), expect=(2,), check=_says("empty source name"))
    # -- bounded work: a calibration view that is a strip (OpenCV's board search: minutes)
    for h, w in ((1, 100000), (100, 100000)):
        sd = outdir(f"strip{h}")
        cv2.imwrite(os.path.join(sd, "s.png"), np.zeros((h, w), np.uint8))
        case(f"calibrate intrinsics on one {w}x{h} PNG", occloc("calibrate", "intrinsics", sd, "--board", "chess:9x6",
                                                              "--square-mm", "20", "--out", f"{o}/strip.yaml"),
             [sd], expect=(2,), check=_says("not a camera's frame"), quick=h == 100)
    # -- settings files: seeded hostile numbers in seeded fields (one-line refusal or a clean run)
    sfile = os.path.join(tmp, "settings.json")
    subprocess.run(occloc("run", static, "--max-frames", "1", "--settings-out", sfile), cwd=ROOT,
                   capture_output=True, timeout=TIMEOUT_S)
    leaves = []

    def walk(d, path):
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, path + (k,))
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                leaves.append(path + (k,))
    settings = json.load(open(sfile, encoding="utf-8"))
    walk(settings, ())
    for key in [("receiver", "detect", "max_detect_px"), ("receiver", "ook", "pieces_jitter_us")] + rng.sample(leaves, 6):
        value = rng.choice([0, -1, 1e9 + 1, 1e300, 10 ** 12, 0.5])
        s = json.loads(json.dumps(settings))
        d = s
        for k in key[:-1]:
            d = d[k]
        d[key[-1]] = value
        sp = os.path.join(tmp, f"settings-{len(cases)}.json")
        json.dump(s, open(sp, "w", encoding="utf-8"))
        case(f"run --settings {'.'.join(key[1:])}={value:g}", occloc("run", r, "--max-frames", "3", "--settings", sp),
             [r, sp], expect=(0, 2), check=_no_nan, quick=key[-1] == "max_detect_px")
    return cases


def build_extra_cases(tmp: str, rng, quick: bool = False) -> list[Case]:
    """Cut compressed videos, hostile camera numbers, duplicate and huge maps, full devices as
    every kind of output, FIFOs and empty files as every kind of input, names in other scripts;
    `rng` draws the cut points. `quick`: the inputs only the full form uses are not made."""
    static = os.path.join(REC, "indoor-static")
    cases: list[Case] = []
    base = os.path.join(tmp, "extra")
    os.makedirs(base)
    r = os.path.join(base, "rec")
    shutil.copytree(static, r)
    cam, map_, truth = (os.path.join(r, n) for n in ("camera.yaml", "map.json", "truth.jsonl"))
    o = os.path.join(base, "outs")
    os.makedirs(o)

    def case(name, argv, inputs=(r,), **kw):
        kw.setdefault("clean", [o, r, base])
        cases.append(Case(name, argv, list(inputs), **kw))

    def write(name, text):
        pth = os.path.join(base, name)
        with open(pth, "w", encoding="utf-8") as f:
            f.write(text)
        return pth

    one_line = _clean_end
    # -- compressed videos cut at seeded points (MJPEG in AVI, H.264 in MP4)
    for codec, ext in ((("mjpeg", "avi"),) if not quick else ()) + (("h264", "mp4"),):
        made = os.path.join(base, f"synth-{codec}")
        subprocess.run(occloc("synth", "indoor-static", "--frames", "12", "--codec", codec, "--out", made), cwd=ROOT,
                       capture_output=True, timeout=TIMEOUT_S)
        video = next((os.path.join(made, n) for n in sorted(os.listdir(made)) if n.startswith("video."))
                     if os.path.isdir(made) else None, None)
        if video is None:
            continue   # this OpenCV cannot write the codec: nothing to cut
        data = open(video, "rb").read()
        for k in range(2):
            cut = rng.uniform(0.05, 0.95)
            pth = os.path.join(base, f"cut-{codec}-{k}.{ext}")
            open(pth, "wb").write(data[:int(len(data) * cut)])
            case(f"run {codec} video cut at {cut:.2f}", occloc("run", pth, "--camera", cam, "--map", map_),
                 [pth, r], expect=(0, 2), check=_all(_no_raw_decoder_text, _clean_end), quick=k == 0 and codec == "h264")
    # -- camera files: negative and non-finite numbers in every key
    cam_ok = open(cam, encoding="utf-8").read()
    for key, value in [("image_width", "-1280"), ("image_height", "0"), ("row_readout_us", "-15."),
                       ("exposure_us", "-20."), ("fps", "-30."), ("fps", ".nan"), ("focal_length_mm", "-3."),
                       ("pixel_size_um", "0.")]:
        text = re.sub(rf"(?m)^{key}:.*$", f"{key}: {value}", cam_ok)
        pth = write(f"cam-{key}{value}.yaml", text)
        case(f"run --camera {key}: {value}", occloc("run", r, "--max-frames", "2", "--camera", pth),
             [r, pth], expect=(0, 2), check=_clean_end, quick=key == "row_readout_us")
    for label, data in [("fx NaN", "[ .nan, 0., 639.5, 0., 1000., 359.5, 0., 0., 1. ]"),
                        ("fx negative", "[ -1000., 0., 639.5, 0., 1000., 359.5, 0., 0., 1. ]"),
                        ("cx infinite", "[ 1000., 0., .inf, 0., 1000., 359.5, 0., 0., 1. ]")]:
        text = re.sub(r"data: \[ 1000\.[^\]]*\]", "data: " + data, cam_ok, count=1)
        pth = write(f"cam-K-{label.replace(' ', '_')}.yaml", text)
        case(f"run --camera camera_matrix {label}", occloc("run", r, "--max-frames", "2", "--camera", pth),
             [r, pth], expect=(2,), check=one_line)
        case(f"calibrate rows --camera camera_matrix {label}",
             occloc("calibrate", "rows", r, "--camera", pth, "--ook-rate", "20000", "--max-frames", "3",
                    "--out", os.path.join(o, "k.yaml")), [r, pth], expect=(2,), check=one_line)
    # -- maps: duplicate IDs, duplicate keys, NaN coordinates, a huge one
    m = json.load(open(map_, encoding="utf-8"))
    dup = json.loads(json.dumps(m))
    dup["leds"].append(dict(dup["leds"][0]))
    case("run --map with a duplicate LED id", occloc("run", r, "--max-frames", "2", "--map",
                                                     write("map-dup.json", json.dumps(dup))),
         expect=(2,), check=one_line, quick=True)
    text = json.dumps(m).replace('"leds":', '"leds": [], "leds":', 1)
    case("run --map with a duplicate key", occloc("run", r, "--max-frames", "2", "--map", write("map-dupkey.json", text)),
         expect=(2,), check=_all(_clean_end, _says("given twice")))
    nan = json.dumps(m).replace('"x": ', '"x": NaN, "_x": ', 1)
    case("run --map with x: NaN", occloc("run", r, "--max-frames", "2", "--map", write("map-nan.json", nan)),
         expect=(2,), check=one_line)
    if quick:
        big = None
    else:
        big = {k: v for k, v in m.items() if k != "leds"}
    if big is not None:
        led0 = m["leds"][0]
        big["leds"] = [{**led0, "id": i, "x": (i % 256) * 0.1, "y": (i // 256) * 0.1} for i in range(1 << 16)]
        hp = write("map-huge.json", json.dumps(big))
        case("run --map of every ID (65,536 LEDs)", occloc("run", r, "--max-frames", "2", "--map", hp), [r, hp],
             expect=(0, 2), check=_clean_end)
        pad = json.dumps(m).replace('"leds":', '"notes": "' + "x" * (80 << 20) + '", "leds":', 1)
        pp = write("map-80mb.json", pad)
        case("run --map of 80 MB", occloc("run", r, "--max-frames", "2", "--map", pp), [r, pp], expect=(2,),
             check=_clean_end)
    # -- /dev/full as each command's file output (a device: written to, never replaced)
    run_file = os.path.join(base, "run.jsonl")
    subprocess.run(occloc("run", static, "--max-frames", "3", "--out", run_file), cwd=ROOT, capture_output=True,
                   timeout=TIMEOUT_S)
    full = "/dev/full"
    for label, argv in [("run --out", ("run", r, "--max-frames", "2", "--out", full)),
                        ("run --settings-out", ("run", r, "--max-frames", "2", "--out", os.path.join(o, "x.jsonl"),
                                                "--settings-out", full)),
                        ("eval --plot", ("eval", run_file, "--truth", truth, "--plot", full)),
                        ("export --out", ("export", run_file, "--format", "csv", "--out", full)),
                        ("calibrate rows --out", ("calibrate", "rows", r, "--camera", cam, "--ook-rate", "20000",
                                                  "--max-frames", "3", "--out", full))]:
        case(f"{label} /dev/full", occloc(*argv), [r, run_file], expect=(2,),
             check=lambda rc, out, err: "" if stat.S_ISCHR(os.stat(full).st_mode) else "/dev/full replaced",
             quick=label == "export --out")
    # -- FIFOs (no writer) and empty files as every kind of input: never a hang
    fifo = os.path.join(base, "fifo.yaml")
    os.mkfifo(fifo)
    for label, argv in [("run --camera FIFO", ("run", r, "--max-frames", "2", "--camera", fifo)),
                        ("run --map FIFO", ("run", r, "--max-frames", "2", "--map", fifo)),
                        ("run --settings FIFO", ("run", r, "--max-frames", "2", "--settings", fifo)),
                        ("eval --truth FIFO", ("eval", run_file, "--truth", fifo)),
                        ("export FIFO", ("export", fifo, "--format", "csv"))]:
        case(label, occloc(*argv), [r], expect=(2,), check=one_line, quick=label == "run --map FIFO")
    empty = os.path.join(base, "empty")
    os.makedirs(empty)
    for n in ("camera.yaml", "map.json", "video.avi", "truth.jsonl", "settings.json", "run.jsonl", "x.png"):
        open(os.path.join(empty, n), "wb").close()
    e = lambda n: os.path.join(empty, n)  # noqa: E731
    for label, argv in [("run a recording of 0-byte files", ("run", empty)),
                        ("run a 0-byte video", ("run", e("video.avi"), "--camera", cam, "--map", map_)),
                        ("run a 0-byte photo", ("run", e("x.png"), "--camera", cam, "--map", map_)),
                        ("run --settings 0-byte", ("run", r, "--max-frames", "2", "--settings", e("settings.json"))),
                        ("eval a 0-byte run", ("eval", e("run.jsonl"), "--truth", truth)),
                        ("eval --truth 0-byte", ("eval", run_file, "--truth", e("truth.jsonl"))),
                        ("export a 0-byte run", ("export", e("run.jsonl"), "--format", "tum")),
                        ("check a 0-byte video", ("check", e("video.avi"), "--camera", cam, "--map", map_)),
                        ("calibrate rows --camera 0-byte", ("calibrate", "rows", r, "--camera", e("camera.yaml"),
                                                            "--ook-rate", "20000", "--out", os.path.join(o, "e.yaml")))]:
        case(label, occloc(*argv), [r, empty], expect=(0, 2), check=_clean_end,
             quick=label == "run a recording of 0-byte files")
    # -- names in other scripts (UTF-8): every command reads and writes them
    uni = os.path.join(base, "caf\u00e9 \u6d4b\u8bd5 \U0001f4a1")
    shutil.copytree(static, uni)
    uo = os.path.join(uni, "\u00e9t\u00e9.jsonl")
    case("run a folder named in three scripts", occloc("run", uni, "--max-frames", "3", "--out", uo), [r], expect=(0,),
         check=lambda rc, out, err: "" if os.path.getsize(uo) > 0 else "no output", quick=True)
    case("eval, export, check, calibrate rows under that name",
         f"{PY} -m receiver.cli run '{uni}' --max-frames 3 --out '{uni}/r.jsonl' 2>/dev/null && "
         f"{PY} -m receiver.cli eval '{uni}/r.jsonl' --truth '{uni}/truth.jsonl' >/dev/null && "
         f"{PY} -m receiver.cli export '{uni}/r.jsonl' --format csv --out '{uni}/r.csv' && "
         f"{PY} -m receiver.cli check '{uni}' --max-frames 5 >/dev/null; test $? -le 1 && "
         f"exec {PY} -m receiver.cli calibrate rows '{uni}' --camera '{uni}/camera.yaml' --ook-rate 20000 "
         f"--max-frames 5 --out '{uni}/c.yaml' >/dev/null", [r], shell=True, expect=(0,))
    return cases


# Values every numeric field of every settings record is tried with (`settings_probe`): zero,
# the smallest and the largest magnitudes a settings file may hold, a fraction for a count, and
# one past the largest. A field either refuses a value in one line or runs with it cleanly.
PROBE_VALUES = (0, -1, 1e-9, 0.5, 1e9, 1e9 + 1)


def _leaves(d: dict, path=()) -> list[tuple]:
    """Paths of the numeric (not boolean) leaves of a settings object, and of those left unset
    (null: e.g. a tone band's limits, which a user sets to numbers)."""
    out = []
    for k, v in d.items():
        if isinstance(v, dict):
            out += _leaves(v, path + (k,))
        elif v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)):
            out.append(path + (k,))
    return out


def settings_probe(tmp: str, *, frames: int = 3, vehicle_frames: int = 40, timeout_s: int = 60,
                   only: str | None = None, values=PROBE_VALUES) -> list[dict]:
    """Every numeric or unset field of every settings record (receiver, locate on indoor-static,
    `frames` frames; vehicle and the S2-PSK decoder on the vehicle recording, `vehicle_frames`:
    a packet's worth), each of `values`, through `occloc run REC --settings FILE --max-frames N`
    in this process (a few thousand runs: a process each would
    take an hour). A row per run: field, value, exit code, first stderr line, problem ('' when
    it held: exit 0 with no NaN in the output, or exit 2 with one line of error; a traceback,
    a hang past `timeout_s` or another exit is a problem)."""
    import contextlib
    import io
    import traceback

    from receiver.cli import main as occloc_main

    class Hang(BaseException):
        pass

    def alarm(signum, frame):
        raise Hang()

    rows = []
    old = signal.signal(signal.SIGALRM, alarm)
    try:
        for rec in ("indoor-static", "vehicle"):
            src = os.path.join(REC, rec)
            base = os.path.join(tmp, f"probe-{rec}.json")
            occloc_main(["run", src, "--max-frames", "1", "--settings-out", base, "--out", os.devnull])
            settings = json.load(open(base, encoding="utf-8"))
            stages = ("receiver", "locate") if rec == "indoor-static" else ("vehicle", "receiver.s2psk")
            for path in _leaves(settings):
                name = ".".join(path)
                if not any(name.startswith(st) for st in stages) or (only and only not in name):
                    continue
                if rec == "indoor-static" and name.startswith("receiver.s2psk"):
                    continue   # no S2-PSK light there: probed on the vehicle recording
                for value in values:
                    s = json.loads(json.dumps(settings))
                    d = s
                    for k in path[:-1]:
                        d = d[k]
                    d[path[-1]] = value
                    sp, out = os.path.join(tmp, "probe.json"), os.path.join(tmp, "probe.jsonl")
                    with open(sp, "w", encoding="utf-8") as f:
                        json.dump(s, f)
                    err = io.StringIO()
                    problem, rc = "", None
                    signal.alarm(timeout_s)
                    try:
                        with contextlib.redirect_stderr(err):
                            n = frames if rec == "indoor-static" else vehicle_frames
                            rc = occloc_main(["run", src, "--max-frames", str(n), "--settings", sp, "--out", out])
                    except Hang:
                        problem = f"no end within {timeout_s} s"
                    except BaseException as e:   # a traceback a user would have seen
                        problem = f"traceback: {type(e).__name__}: {str(e)[:80]}"
                        last = traceback.extract_tb(e.__traceback__)[-1]
                        problem += f" ({os.path.relpath(last.filename, ROOT)}:{last.lineno})"
                    finally:
                        signal.alarm(0)
                    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
                    if not problem:
                        if rc == 0:
                            text = (open(out, encoding="utf-8").read() if os.path.exists(out) else "") + err.getvalue()
                            if re.search(r"\bnan\b", text, re.I):
                                problem = "nan in output"
                        elif rc == 2:
                            if not lines or not lines[-1].startswith("occloc: "):
                                problem = "exit 2 without a one-line error"
                        else:
                            problem = f"exit {rc}"
                    rows.append({"field": name, "value": value, "rc": rc, "stderr": lines[-1][:100] if lines else "",
                                 "problem": problem})
    finally:
        signal.signal(signal.SIGALRM, old)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realtime-runs", type=int, default=20, help="realtime runs of each kind (20)")
    ap.add_argument("--only", help="run only cases whose name contains this")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder")
    ap.add_argument("--quick", action="store_true", help="only the quick cases (CI)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the drawn cases (1)")
    ap.add_argument("--budget-s", type=float, default=None, help="start no case after this many seconds")
    ap.add_argument("--settings-probe", action="store_true",
                    help="instead of the cases: every numeric settings field with zero, tiny, fractional and "
                         "huge values, run in this process (--only: fields containing this)")
    args = ap.parse_args(argv)
    if args.settings_probe:
        return _main_probe(args)
    import random
    tmp = tempfile.mkdtemp(prefix="occloc-sweep-")
    bad = held = skipped = 0
    t0 = time.monotonic()
    try:
        rng = random.Random(args.seed)
        cases = [] if args.quick else build_cases(tmp, args.realtime_runs)
        cases += build_more_cases(tmp, rng)
        cases += build_extra_cases(tmp, rng, quick=args.quick)
        if args.quick:
            cases = [c for c in cases if c.quick]
        if args.only:
            cases = [c for c in cases if args.only in c.name]
        print(f"{'input':58} {'exit':>5}  {'tb':3} {'intact':6}  first line of stderr")
        for c in cases:
            if args.budget_s is not None and time.monotonic() - t0 > args.budget_s:
                skipped += 1
                continue
            r = run_case(c)
            failed = r["traceback"] or r["hung"] or not r["intact"] or r["problem"]
            bad += bool(failed)
            held += not failed
            note = f"  <-- {r['problem']}" if r["problem"] else ""
            print(f"{r['input'][:58]:58} {str(r['rc']):>5}  {'yes' if r['traceback'] else 'no':3} "
                  f"{'yes' if r['intact'] else 'NO':6}  {r['stderr']}{note}", flush=True)
    finally:
        if args.keep:
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    print(f"{bad} problem row(s)" if bad else "no traceback, hang or damaged input")
    print(f"seed {args.seed}: {held + bad} cases, {held} held" + (f", {skipped} not run (budget)" if skipped else ""))
    return 1 if bad else 0


def _main_probe(args) -> int:
    tmp = tempfile.mkdtemp(prefix="occloc-probe-")
    try:
        rows = settings_probe(tmp, only=args.only)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    bad = [r for r in rows if r["problem"]]
    for r in rows:
        if r["problem"]:
            print(f"{r['field'][:50]:50} {r['value']!s:>10} {str(r['rc']):>5}  {r['stderr'][:60]}"
                  + (f"  <-- {r['problem']}" if r["problem"] else ""), flush=True)
    fields = len({r["field"] for r in rows})
    print(f"settings probe: {fields} fields x {len(PROBE_VALUES)} values, {len(rows)} runs, "
          f"{len(rows) - len(bad)} held, {sum(r['rc'] == 2 for r in rows)} refused in one line")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
