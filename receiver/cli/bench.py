"""`occloc bench`: per-stage and whole-frame median / p99 milliseconds of the receiver, frames/s,
and (`--instructions`, where valgrind is installed) instructions per frame.

Without SOURCE it runs every bundled recording (`recordings/*` of a source checkout) and the
built-in synthetic scene (`receiver.cli.benchscene`: 1280x720, 16 OOK LEDs, a map of real LED
positions); with SOURCE that recording / video / photo (camera and map as for `occloc run`).
Each case runs the WHOLE pipeline of `occloc run`: detect .. decode, report, positioning
(`make_positioner`) and the vehicle stage (`make_vehicle_locator`) where the map has one, plus
the JSON line formatting (`output`, timed separately and included in `total`). It runs on one
core (OpenCV on one thread, `receiver.core.budget.one_core`), and the frames are decoded (or
rendered) into memory before timing starts, so video decoding is not timed. Times are the main
thread's CPU time by default (`--clock cpu`: on one core all the work is on that thread, and it
does not count the time other processes take the core; `--clock wall` for elapsed time).

Instructions per frame: the same case re-runs in a child process under
`valgrind --tool=callgrind`, collecting only while the timed frames are processed (the child
processes its frames inside one `functools.reduce` call, callgrind's `--toggle-collect`), and the
count is divided by those frames; start-up, imports and decoding are not counted.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

from receiver.cli.args import whole_in

HELP = "time the whole receiver per stage (median/p99 ms, instructions/frame) on the bundled recordings or a SOURCE"

SCENE = "synthetic"          # the name of the built-in scene's case
# Scenes `--scale WxH` renders at another size; the case is named "SCENE@WxH".
SCALED_SCENES = (SCENE, "indoor-walk")
# Sizes --scale accepts (px): a few pixels up to 8K.
SCALE_MIN_PX, SCALE_MAX_PX = 64, 8192
# Default frames of --scale: they are held in memory (40 frames of 3840x2160 are 330 MB).
SCALE_FRAMES = 40
DEFAULT_FRAMES = 300         # frames per case (the bundled recordings have 30-150)
DEFAULT_INSTR_FRAMES = 5     # frames counted under callgrind per case
# Frames processed before the counted ones under callgrind (IDs decoded, trackers settled).
INSTR_WARM_FRAMES = 10
# The C function the child runs its counted frames in (CPython's functools.reduce).
INSTR_TOGGLE = "functools_reduce"

# Clocks of --clock (seconds): the main thread's CPU time, or elapsed time.
CLOCKS = {"cpu": time.thread_time, "wall": time.perf_counter}

def add_arguments(p) -> None:
    p.add_argument("source", nargs="?", metavar="SOURCE",
                   help="recording, video or photo (default: every bundled recording and the built-in "
                        "1280x720 16-LED synthetic scene)")
    p.add_argument("--frames", type=whole_in(1, 1_000_000), metavar="N",
                   help=f"frames to time per case ({DEFAULT_FRAMES}, {SCALE_FRAMES} with --scale; a recording's own "
                        f"length when shorter)")
    p.add_argument("--camera", metavar="FILE", help="camera.yaml for a bare video/photo")
    p.add_argument("--map", metavar="FILE", help="map.json for a bare video/photo")
    p.add_argument("--repeat", type=whole_in(1, 10_000), default=1, metavar="R",
                   help="process the loaded frames R times, each time with a fresh receiver (photos: 1 frame, "
                        "so e.g. 20)")
    p.add_argument("--clock", choices=tuple(CLOCKS), default="cpu",
                   help="cpu: the main thread's CPU time (default; steady on a shared machine, and with OpenCV "
                        "on one thread all the work is on that thread); wall: elapsed time")
    p.add_argument("--scene-only", action="store_true", help="only the built-in synthetic scene")
    p.add_argument("--scale", metavar="WxH",
                   help="only a synthetic scene rendered at W x H px (--scale-scene), focal length and row time "
                        "scaled so the scene is the one at 1280x720; reports ms per megapixel too")
    p.add_argument("--scale-scene", choices=SCALED_SCENES, default=SCENE,
                   help=f"the scene of --scale: {SCENE} (the built-in one, default) or indoor-walk (tools.synth's "
                        f"scene, needs a source checkout)")
    p.add_argument("--json", action="store_true", help="print one JSON object (machines) instead of the tables")
    p.add_argument("--instructions", action="store_true",
                   help=f"also count instructions per frame under valgrind's callgrind "
                        f"({DEFAULT_INSTR_FRAMES} frames after {INSTR_WARM_FRAMES}; slow: minutes per case)")
    p.add_argument("--instr-frames", type=whole_in(1, 10_000), default=DEFAULT_INSTR_FRAMES, metavar="K",
                   help=f"frames counted per case with --instructions ({DEFAULT_INSTR_FRAMES})")
    # The child of --instructions: process frames [W, W+K) of the case inside functools.reduce.
    p.add_argument("--_count", nargs=3, metavar=("CASE", "W", "K"), help=argparse.SUPPRESS)


# ---------------------------------------------------------------- cases

def bundled_recordings() -> list[str]:
    """The bundled recording folders (recordings/* with a video) of a source checkout, by name."""
    from receiver.io.sources import find_recording_files
    import receiver
    root = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(receiver.__file__))), "recordings")
    if not os.path.isdir(root):
        return []
    out = []
    for name in sorted(os.listdir(root)):
        path = os.path.join(root, name)
        if os.path.isdir(path) and find_recording_files(path).get("video"):
            out.append(path)
    return out


def load_case(spec: str, n_frames: int, camera: str | None = None, map_path: str | None = None):
    """(camera, map, frames, still) of a case: SCENE or a recording / video / photo, its frames
    decoded (rendered) into memory, turned to sensor orientation as `occloc run` does."""
    if spec == SCENE:
        from receiver.cli.benchscene import bench_frames
        cam, led_map, frames = bench_frames(n_frames)
        return cam, led_map, frames, False
    if "@" in spec and spec.split("@", 1)[0] in SCALED_SCENES:
        name, size = spec.split("@", 1)
        return scaled_scene(name, parse_scale(size), n_frames)
    import cv2
    from receiver.core.errors import InputError
    from receiver.core.records import Frame
    from receiver.io.camera import fit_camera, load_camera
    from receiver.io.ledmap import load_map
    from receiver.io.sources import find_recording_files, open_source

    if not os.path.exists(spec):
        raise InputError(f"no such file or folder: {spec}")
    rec = find_recording_files(spec) if os.path.isdir(spec) else {}
    cam_path, map_path = camera or rec.get("camera"), map_path or rec.get("map")
    if cam_path is None or map_path is None:
        raise InputError(f"{spec}: needs a camera file and a map (--camera, --map)")
    cam, led_map = load_camera(cam_path), load_map(map_path)
    src = open_source(spec, camera=cam, threads=1)
    try:
        cam, rotate = fit_camera(cam, src.size)
        frames = []
        for f in src:
            if len(frames) >= n_frames:
                break
            g = cv2.rotate(f.gray, cv2.ROTATE_90_COUNTERCLOCKWISE) if rotate else f.gray
            frames.append(Frame(f.index, f.t_s, g))
    finally:
        src.close()
    if not frames:
        raise InputError(f"{spec}: no frames")
    return cam, led_map, frames, src.is_still


def parse_scale(text: str) -> tuple[int, int]:
    """(W, H) px of a --scale value "WxH"."""
    from receiver.core.errors import InputError
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--scale needs WxH in pixels (e.g. 1920x1080), not {text!r}") from None
    if not (SCALE_MIN_PX <= w <= SCALE_MAX_PX and SCALE_MIN_PX <= h <= SCALE_MAX_PX):
        raise InputError(f"--scale: width and height must be within {SCALE_MIN_PX}..{SCALE_MAX_PX} px, not {text}")
    return w, h


def scaled_scene(name: str, size: tuple[int, int], n_frames: int):
    """(camera, map, frames, still) of synthetic scene `name` (SCALED_SCENES) rendered at `size`
    (W, H) px: the 1280x720 scene with its focal length scaled by W / 1280 and its row time by
    720 / H, so the lights cover the same angles and the same chips (as `occloc synth indoor-walk
    --set width=W --set height=H --set focal_px=... --set row_readout_us=...`)."""
    from receiver.core.records import Frame
    w, h = size
    if name == SCENE:
        from receiver.cli.benchscene import bench_frames
        cam, led_map, frames = bench_frames(n_frames, size=size)
        return cam, led_map, frames, False
    from receiver.core.errors import InputError
    try:
        from tools.synth.render import render_frames
        from tools.synth.scenes import CAMERA_DEFAULTS, make_scene
    except ImportError:
        raise InputError(f"--scale-scene {name} needs the tools package of a source checkout") from None
    base = CAMERA_DEFAULTS[name]
    # each band of 4 rows drawn at the camera pose of its own read time, as a rolling shutter reads
    # a moving camera's image (the receiver's outline fit models it)
    scene = make_scene(name, seed=1, n_frames=n_frames, width=w, height=h, focal_px=base["focal_px"] * w / 1280.0,
                       row_readout_us=base["row_readout_us"] * 720.0 / h, rs_band_rows=4)
    fps = scene.camera.fps or 30.0
    frames = [Frame(k, k / fps, img) for k, (img, _) in enumerate(render_frames(scene, n_frames=n_frames, seed=1))]
    return scene.camera, scene.led_map, frames, False


def add_per_megapixel(row: dict) -> dict:
    """The row with `mp` (the frame's megapixels) and `ms_per_mp` (median total ms per megapixel)."""
    mp = row["size"][0] * row["size"][1] / 1e6
    return dict(row, mp=mp, ms_per_mp=row["total"]["median_ms"] / mp)


def whole_receiver(camera, led_map, *, still: bool = False, clock=time.perf_counter):
    """A receiver as `occloc run` builds it: with the map's positioner and vehicle stage."""
    from receiver.cli.run import make_positioner, make_vehicle_locator
    from receiver.pipeline import Receiver
    return Receiver(camera, led_map, positioner=make_positioner(camera, led_map),
                    vehicle=make_vehicle_locator(camera, led_map), clock=clock, still=still)


def run_bench(camera, led_map, frames, *, repeat: int = 1, still: bool = False, clock=time.perf_counter,
              whole: bool = False, elapsed=time.perf_counter):
    """Process `frames` (each `repeat` times, with a fresh receiver per repetition) on one core
    (OpenCV single-threaded, `receiver.core.budget.one_core`); returns (BudgetStats, seconds
    spent in the timed frames: the `elapsed` clock around each frame's processing and line, not
    the receivers' set-up). whole: the receiver of `occloc run` (`whole_receiver`: positioning,
    vehicle stage); else the receiver alone (detect .. report)."""
    from receiver.core.budget import BudgetStats, one_core
    from receiver.io.output import frame_line
    from receiver.pipeline import Receiver

    stats = BudgetStats()
    wall = 0.0
    with one_core():
        for _ in range(max(1, repeat)):
            rx = (whole_receiver(camera, led_map, still=still, clock=clock) if whole
                  else Receiver(camera, led_map, clock=clock, still=still))
            for f in frames:
                w0 = elapsed()
                res = rx.process(f)
                t = clock()
                frame_line(res)
                out_ms = (clock() - t) * 1000.0
                wall += elapsed() - w0
                stages = dict(res.stage_ms, output=out_ms)
                stats.add(res.latency_ms + out_ms, stages)
    return stats, wall


# ---------------------------------------------------------------- instructions (callgrind)

def _count_child(args) -> int:
    """Under callgrind: process frames [0, W) of the case, then [W, W+K) inside one
    functools.reduce call, the only place callgrind collects (--toggle-collect)."""
    import functools
    from receiver.core.budget import one_core
    from receiver.io.output import frame_line

    spec, w, k = args._count[0], int(args._count[1]), int(args._count[2])
    cam, led_map, frames, still = load_case(spec, w + k, args.camera, args.map)
    w = min(w, max(0, len(frames) - k))  # a short source (a photo): fewer warm frames
    warm, counted = frames[:w], frames[w:w + k]
    with one_core():
        rx = whole_receiver(cam, led_map, still=still)
        for f in warm:
            frame_line(rx.process(f))
        functools.reduce(lambda n, f: (frame_line(rx.process(f)), n + 1)[1], counted, 0)
    print(json.dumps({"frames": len(counted)}))
    return 0


def count_instructions(spec: str, k: int, *, warm: int = INSTR_WARM_FRAMES, camera=None, map_path=None,
                       valgrind: str | None = None, keep: str | None = None) -> dict:
    """{"instructions_per_frame", "frames"} of the case's frames [warm, warm+k) under callgrind,
    or {"instructions_per_frame": None, "note": why} when valgrind is absent or fails. `keep`: a
    path to copy callgrind's output file to (for a per-function reading of the counted frames)."""
    from receiver.core.budget import BLAS_THREAD_VARS
    valgrind = valgrind or shutil.which("valgrind")
    if valgrind is None:
        return {"instructions_per_frame": None, "note": "valgrind not installed: instructions not counted"}
    with tempfile.TemporaryDirectory(prefix="occloc-cg-") as tmp:
        out = os.path.join(tmp, "callgrind.out")
        cmd = [valgrind, "--tool=callgrind", f"--callgrind-out-file={out}", "--collect-atstart=no",
               f"--toggle-collect={INSTR_TOGGLE}", sys.executable, "-m", "receiver.cli", "bench",
               "--_count", spec, str(warm), str(k)]
        if camera:
            cmd += ["--camera", camera]
        if map_path:
            cmd += ["--map", map_path]
        env = dict(os.environ)
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        env.update(dict.fromkeys(BLAS_THREAD_VARS, "1"))
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["?"])[-1]
            return {"instructions_per_frame": None, "note": f"callgrind run failed: {last}"}
        frames = json.loads(proc.stdout.strip().splitlines()[-1])["frames"]
        total = callgrind_total(out)
        if keep:
            shutil.copyfile(out, keep)
    if not frames or not total:
        return {"instructions_per_frame": None,
                "note": f"callgrind collected nothing (no {INSTR_TOGGLE} symbol in this Python?)"}
    return {"instructions_per_frame": total / frames, "frames": frames}


def callgrind_total(path: str) -> int:
    """Instructions (Ir) a callgrind output file says it collected."""
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith(("summary:", "totals:")):
                return int(line.split()[1])
    return 0


# ---------------------------------------------------------------- command

def _case_name(spec: str) -> str:
    return spec if spec == SCENE else os.path.basename(os.path.normpath(spec))


def bench_case(spec: str, args) -> dict:
    """One case's row: frames, size, frames/s (elapsed time of the timed frames), per-stage and total median / p99 ms (--clock)."""
    cam, led_map, frames, still = load_case(spec, args.frames, args.camera, args.map)
    clock = CLOCKS[getattr(args, "clock", "cpu")]
    # frames/s of the timed frames only (elapsed time), not of the receivers' set-up
    stats, wall = run_bench(cam, led_map, frames, repeat=args.repeat, still=still, whole=True, clock=clock)
    s = stats.summary()
    return {"case": _case_name(spec), "frames": s["frames"],
            "size": [int(frames[0].gray.shape[1]), int(frames[0].gray.shape[0])],
            "frames_per_s": s["frames"] / wall if wall > 0 else None,
            "total": s["total"], "stages": s["stages"]}


def _print_tables(rows: list[dict], clock: str, out) -> None:
    from receiver.core import native
    what = "main-thread CPU ms" if clock == "cpu" else "elapsed ms"
    print(f"whole pipeline (detect .. locate, vehicle, JSON line) on one core, {what}; frames decoded into "
          f"memory before timing (video decoding not timed); kernels: {native.status()}", file=out)
    for row in rows:
        fps = (f"{row['frames_per_s']:.1f} frames/s over the elapsed time of the timed frames"
               if row["frames_per_s"] else "-")
        print(f"\n{row['case']}: {row['frames']} frames {row['size'][0]}x{row['size'][1]}, {fps} (one core)",
              file=out)
        print(f"{'stage':<10}{'median ms':>11}{'p99 ms':>10}", file=out)
        for name, st in list(row["stages"].items()) + [("total", row["total"])]:
            print(f"{name:<10}{st['median_ms']:>11.3f}{st['p99_ms']:>10.3f}", file=out)
        if "instructions_per_frame" in row:
            ipf = row["instructions_per_frame"]
            print(f"instructions/frame: {ipf / 1e6:.2f} M ({row['instr_frames']} frames, callgrind)" if ipf
                  else f"instructions/frame: - ({row['instr_note']})", file=out)
    print(f"\n{'case':<16}{'frames':>7}{'median ms':>11}{'p99 ms':>9}{'M instr':>9}", file=out)
    for row in rows:
        ipf = row.get("instructions_per_frame")
        print(f"{row['case']:<16}{row['frames']:>7}{row['total']['median_ms']:>11.3f}{row['total']['p99_ms']:>9.3f}"
              f"{(f'{ipf / 1e6:.2f}' if ipf else '-'):>9}", file=out)


def main(args) -> int:
    from receiver.core.errors import InputError
    if getattr(args, "_count", None):
        return _count_child(args)
    if args.frames is None:
        args.frames = SCALE_FRAMES if args.scale is not None else DEFAULT_FRAMES
    if args.frames <= 0 or args.repeat <= 0 or args.instr_frames <= 0:
        raise InputError("--frames, --repeat and --instr-frames must be positive")
    if args.scale is not None:
        if args.source is not None or args.camera or args.map:
            raise InputError("--scale renders a synthetic scene: no SOURCE, --camera or --map")
        w, h = parse_scale(args.scale)
        specs = [f"{args.scale_scene}@{w}x{h}"]
    elif args.source is not None:
        specs = [args.source]
    else:
        if args.camera or args.map:
            raise InputError("--camera and --map need a SOURCE")
        specs = ([] if args.scene_only else bundled_recordings()) + [SCENE]
    rows = []
    for spec in specs:
        print(f"occloc bench: {_case_name(spec)} ...", file=sys.stderr, flush=True)
        row = add_per_megapixel(bench_case(spec, args))
        if args.instructions:
            c = count_instructions(spec, args.instr_frames, camera=args.camera, map_path=args.map)
            row["instructions_per_frame"] = c["instructions_per_frame"]
            row["instr_frames"] = c.get("frames")
            if "note" in c:
                row["instr_note"] = c["note"]
        rows.append(row)
    if args.json:
        from receiver.core import native
        print(json.dumps({"one_core": True, "frames_predecoded": True, "clock": args.clock,
                          "kernels": native.status(), "cases": rows}, indent=1))
    else:
        _print_tables(rows, args.clock, sys.stdout)
        for row in rows:
            print(f"{row['case']}: {row['mp']:.2f} MP, {row['ms_per_mp']:.3f} ms per megapixel (median)")
    return 0
