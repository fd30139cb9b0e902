"""Bad-input sweep: run every command of the project on damaged, hostile or wrong input and
check that it never hangs, never prints a traceback and never damages its input.

    python tools/badinput_sweep.py [--realtime-runs 20] [--only SUBSTRING] [--keep]

Prints one row per case: input, exit code, first line of stderr, traceback yes/no, input
intact yes/no. Exits 1 when any row has a traceback, a hang (timeout) or a damaged input.
Every case works on copies in a temporary folder; the bundled recordings are only read.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import signal
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
    def __init__(self, name, argv, inputs=(), shell=False, stdin=None, expect=None, signal_after=None,
                 check=None):
        self.name, self.argv, self.inputs, self.shell = name, argv, list(inputs), shell
        self.stdin, self.expect, self.signal_after, self.check = stdin, expect, signal_after, check


def run_case(c: Case) -> dict:
    before = {p: sha(p) for p in c.inputs}
    t0 = time.monotonic()
    hung = False
    stdin = open(c.stdin, "rb") if isinstance(c.stdin, str) else c.stdin
    try:
        p = subprocess.Popen(c.argv, cwd=ROOT, shell=c.shell, stdin=stdin if stdin is not None else subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                             executable="/bin/bash" if c.shell else None)
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
    if c.check is not None and not hung:
        row["problem"] = c.check(rc, out.decode("utf-8", "replace"), err_text) or ""
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realtime-runs", type=int, default=20, help="realtime runs of each kind (20)")
    ap.add_argument("--only", help="run only cases whose name contains this")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = ap.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix="occloc-sweep-")
    bad = 0
    try:
        cases = build_cases(tmp, args.realtime_runs)
        if args.only:
            cases = [c for c in cases if args.only in c.name]
        print(f"{'input':58} {'exit':>5}  {'tb':3} {'intact':6}  first line of stderr")
        for c in cases:
            r = run_case(c)
            failed = r["traceback"] or r["hung"] or not r["intact"] or r["problem"]
            bad += bool(failed)
            note = f"  <-- {r['problem']}" if r["problem"] else ""
            print(f"{r['input'][:58]:58} {str(r['rc']):>5}  {'yes' if r['traceback'] else 'no':3} "
                  f"{'yes' if r['intact'] else 'NO':6}  {r['stderr']}{note}", flush=True)
    finally:
        if args.keep:
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    print(f"{bad} problem row(s)" if bad else "no traceback, hang or damaged input")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
