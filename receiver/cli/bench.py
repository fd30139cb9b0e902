"""`occloc bench`: per-stage and total median / p99 milliseconds of the receiver, frames/s.

Without SOURCE it runs the built-in synthetic scene (`bench_scene`): 1280x720, 16 OOK LEDs
(PROTOCOL.md packets at 20 kHz on a rolling shutter, drifting across the image), the budget
case of issue 4. With SOURCE it runs that recording / video / photo (camera and map as for
`occloc run`). Frames are decoded from the source (or rendered) before timing starts, so the
numbers are receiver processing only; `output` is the JSON line formatting, timed separately
and included in `total`.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass

import numpy as np

HELP = "time the receiver per stage (median/p99 ms, frames/s) on a synthetic scene or a SOURCE"

BENCH_SIZE = (1280, 720)
BENCH_LEDS = 16
BENCH_RATE_HZ = 20000.0  # PROTOCOL.md's default chip rate, spelled out: the bench scene is fixed
BENCH_ROW_US = 20.0  # 2.5 rows per chip at 20 kHz
BENCH_FPS = 30.0
BENCH_RADIUS_PX = 40.0  # 80 rows = 32 chips: most of a packet per frame
BENCH_ON_GRAY = 220.0
BENCH_OFF_GRAY = 12.0
BENCH_NOISE_GRAY = 2.0


@dataclass(frozen=True)
class SceneLed:
    led_id: int
    cx: float  # px at frame 0
    cy: float
    radius_px: float
    phase_s: float  # the LED's packet start relative to t = 0


def bench_ids(n: int = BENCH_LEDS) -> list[int]:
    """n distinct 16-bit IDs spread over the code space."""
    return [(0x0101 + 0x1F13 * i) & 0xFFFF for i in range(n)]


def bench_scene(n_leds: int = BENCH_LEDS, size=BENCH_SIZE, radius_px: float = BENCH_RADIUS_PX,
                seed: int = 0) -> list[SceneLed]:
    """LEDs on a jittered grid (px), random packet phases."""
    rng = np.random.default_rng(seed)
    w, h = size
    cols = int(np.ceil(np.sqrt(n_leds * w / h)))
    rows = int(np.ceil(n_leds / cols))
    leds = []
    for i, led_id in enumerate(bench_ids(n_leds)):
        r, c = divmod(i, cols)
        cx = (c + 0.5) * w / cols + rng.uniform(-0.1, 0.1) * w / cols
        cy = (r + 0.5) * h / rows + rng.uniform(-0.1, 0.1) * h / rows
        leds.append(SceneLed(led_id, cx, cy, radius_px, rng.uniform(0, 1.0)))
    return leds


def render_bench_frame(leds: list[SceneLed], k: int, *, size=BENCH_SIZE, fps: float = BENCH_FPS,
                       rate_hz: float = BENCH_RATE_HZ, row_readout_us: float = BENCH_ROW_US,
                       drift_px: tuple[float, float] = (0.7, 0.3), on_gray: float = BENCH_ON_GRAY,
                       off_gray: float = BENCH_OFF_GRAY, noise_gray: float = BENCH_NOISE_GRAY,
                       rng: np.random.Generator | None = None) -> np.ndarray:
    """(H, W) uint8 frame k: discs striped by their OOK chip stream sampled per row (instant
    exposure at t_k + row * t_row), moving by `drift_px` per frame, with Gaussian noise."""
    from firmware_tx.framing import ook_packet
    w, h = size
    img = np.full((h, w), off_gray, np.float32)
    t_k = k / fps
    yy = np.arange(h)
    for led in leds:
        chips = np.frombuffer(bytes(ook_packet(led.led_id)), np.uint8)
        cx, cy = led.cx + drift_px[0] * k, led.cy + drift_px[1] * k
        r = led.radius_px
        y0, y1 = max(int(cy - r) - 1, 0), min(int(cy + r) + 2, h)
        x0, x1 = max(int(cx - r) - 1, 0), min(int(cx + r) + 2, w)
        if y1 <= y0 or x1 <= x0:
            continue
        t_rows = t_k + yy[y0:y1] * row_readout_us * 1e-6 + led.phase_s
        chip = chips[np.floor(t_rows * rate_hz).astype(np.int64) % len(chips)]
        ys, xs = np.mgrid[y0:y1, x0:x1]
        inside = (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r
        level = np.where(chip[:, None] > 0, on_gray, off_gray)
        img[y0:y1, x0:x1] = np.where(inside, level, img[y0:y1, x0:x1])
    if noise_gray > 0:
        rng = rng if rng is not None else np.random.default_rng(k)
        img += rng.normal(0.0, noise_gray, img.shape).astype(np.float32)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def bench_camera(size=BENCH_SIZE, row_readout_us: float = BENCH_ROW_US, fps: float = BENCH_FPS):
    from receiver.io.camera import CameraModel
    w, h = size
    K = np.array([[1000.0, 0, (w - 1) / 2], [0, 1000.0, (h - 1) / 2], [0, 0, 1]])
    return CameraModel(w, h, K, np.zeros(5), row_readout_us=row_readout_us, exposure_us=0.0, fps=fps)


def bench_map(leds: list[SceneLed], rate_hz: float = BENCH_RATE_HZ):
    from receiver.io.ledmap import parse_map
    return parse_map({"units": "m", "leds": [
        {"id": led.led_id, "mode": "ook", "x": float(i), "y": 0.0, "z": 3.0, "shape": "circle",
         "size": [0.1], "rate_hz": rate_hz} for i, led in enumerate(leds)]})


def bench_frames(n: int, *, seed: int = 0):
    """(camera, map, frames) of the built-in scene."""
    from receiver.core.records import Frame
    leds = bench_scene(seed=seed)
    rng = np.random.default_rng(seed)
    frames = [Frame(k, k / BENCH_FPS, render_bench_frame(leds, k, rng=rng)) for k in range(n)]
    return bench_camera(), bench_map(leds), frames


def add_arguments(p) -> None:
    p.add_argument("source", nargs="?", metavar="SOURCE",
                   help="recording, video or photo (default: built-in 1280x720 16-LED synthetic scene)")
    p.add_argument("--frames", type=int, default=300, metavar="N", help="frames to time (300)")
    p.add_argument("--camera", metavar="FILE", help="camera.yaml for a bare video/photo")
    p.add_argument("--map", metavar="FILE", help="map.json for a bare video/photo")
    p.add_argument("--repeat", type=int, default=1, metavar="R",
                   help="process each loaded frame R times (photos: 1 frame, so e.g. 20)")


def _load_source(args):
    from receiver.io.camera import load_camera
    from receiver.io.ledmap import load_map
    from receiver.core.errors import InputError
    from receiver.core.records import Frame
    from receiver.io.camera import fit_camera
    from receiver.io.sources import find_recording_files, open_source
    import cv2

    rec = find_recording_files(args.source) if os.path.isdir(args.source) else {}
    cam_path, map_path = args.camera or rec.get("camera"), args.map or rec.get("map")
    if cam_path is None or map_path is None:
        raise InputError(f"{args.source}: needs a camera file and a map (--camera, --map)")
    cam, led_map = load_camera(cam_path), load_map(map_path)
    src = open_source(args.source, camera=cam)
    try:
        cam, rotate = fit_camera(cam, src.size)
        frames = []
        for f in src:
            if len(frames) >= args.frames:
                break
            g = cv2.rotate(f.gray, cv2.ROTATE_90_COUNTERCLOCKWISE) if rotate else f.gray
            frames.append(Frame(f.index, f.t_s, g))
    finally:
        src.close()
    return cam, led_map, frames, src.is_still


def run_bench(camera, led_map, frames, *, repeat: int = 1, still: bool = False, clock=time.perf_counter):
    """Process `frames` (each `repeat` times with a fresh receiver per repetition of a still)
    on one core (OpenCV single-threaded, `receiver.core.budget.one_core`); returns (BudgetStats,
    wall seconds)."""
    from receiver.core.budget import BudgetStats, one_core
    from receiver.io.output import frame_line
    from receiver.pipeline import Receiver

    stats = BudgetStats()
    with one_core():
        t0 = clock()
        for _ in range(max(1, repeat)):
            rx = Receiver(camera, led_map, clock=clock, still=still)
            for f in frames:
                res = rx.process(f)
                t = clock()
                frame_line(res)
                out_ms = (clock() - t) * 1000.0
                stages = dict(res.stage_ms, output=out_ms)
                stats.add(res.latency_ms + out_ms, stages)
        wall = clock() - t0
    return stats, wall


def main(args) -> int:
    from receiver.core.errors import InputError
    if args.frames <= 0 or args.repeat <= 0:
        raise InputError("--frames and --repeat must be positive")
    if args.source is None:
        print(f"occloc bench: rendering {args.frames} frames of the built-in scene "
              f"({BENCH_SIZE[0]}x{BENCH_SIZE[1]}, {BENCH_LEDS} OOK LEDs)", file=sys.stderr)
        cam, led_map, frames = bench_frames(args.frames)
        still = False
    else:
        cam, led_map, frames, still = _load_source(args)
        if not frames:
            raise InputError(f"{args.source}: no frames")
    stats, wall = run_bench(cam, led_map, frames, repeat=args.repeat, still=still)
    s = stats.summary()
    n = s["frames"]
    print(f"{n} frames {frames[0].gray.shape[1]}x{frames[0].gray.shape[0]}, "
          f"{n / wall:.1f} frames/s (one core)")
    print(f"{'stage':<10}{'median ms':>11}{'p99 ms':>10}")
    for name, st in list(s["stages"].items()) + [("total", s["total"])]:
        print(f"{name:<10}{st['median_ms']:>11.3f}{st['p99_ms']:>10.3f}")
    return 0
