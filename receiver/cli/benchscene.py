"""The built-in synthetic scene of `occloc bench` (`receiver.cli.bench`): 1280x720, 16 OOK LEDs
(PROTOCOL.md packets at 20 kHz on a rolling shutter, drifting across the image), the frame-budget
case, with a map of real LED positions (`bench_map`) so that the whole pipeline, positioning
included, runs on it. Units: pixels, seconds, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BENCH_SIZE = (1280, 720)
BENCH_LEDS = 16
BENCH_RATE_HZ = 20000.0  # PROTOCOL.md's default chip rate, spelled out: the bench scene is fixed
BENCH_ROW_US = 20.0  # 2.5 rows per chip at 20 kHz
BENCH_FPS = 30.0
BENCH_RADIUS_PX = 40.0  # 80 rows = 32 chips: most of a packet per frame
BENCH_ON_GRAY = 220.0
BENCH_OFF_GRAY = 12.0
BENCH_NOISE_GRAY = 2.0
BENCH_CEILING_M = 3.0  # camera-to-ceiling distance of the scene's LEDs (bench_map)


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


BENCH_FOCAL_PX = 1000.0


def bench_camera(size=BENCH_SIZE, row_readout_us: float = BENCH_ROW_US, fps: float = BENCH_FPS,
                 focal_px: float = BENCH_FOCAL_PX):
    from receiver.io.camera import CameraModel
    w, h = size
    K = np.array([[focal_px, 0, (w - 1) / 2], [0, focal_px, (h - 1) / 2], [0, 0, 1]])
    return CameraModel(w, h, K, np.zeros(5), row_readout_us=row_readout_us, exposure_us=0.0, fps=fps)


def bench_map(leds: list[SceneLed], rate_hz: float = BENCH_RATE_HZ, camera=None,
              ceiling_m: float = BENCH_CEILING_M):
    """The scene's LED map with real positions: the camera (`bench_camera`, or `camera`) stands at
    the world origin looking straight up (camera axes = world axes: x image right, y image down,
    z up to the ceiling), so LED k hangs at its frame-0 pixel back-projected to the ceiling plane
    z = ceiling_m, and its disc of radius_px is a circle of diameter 2 radius_px ceiling_m / f.
    The drift of the rendered discs is then a camera moving under the ceiling (0.7 px/frame =
    2.1 mm/frame at 3 m), so positioning has a true answer on every frame."""
    from receiver.io.ledmap import parse_map
    cam = camera if camera is not None else bench_camera()
    K = np.asarray(cam.K, float)
    fx, fy, ppx, ppy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return parse_map({"units": "m", "leds": [
        {"id": led.led_id, "mode": "ook", "x": round((led.cx - ppx) * ceiling_m / fx, 6),
         "y": round((led.cy - ppy) * ceiling_m / fy, 6), "z": ceiling_m, "shape": "circle",
         "size": [round(2.0 * led.radius_px * ceiling_m / fx, 6)], "rate_hz": rate_hz} for led in leds]})


def bench_frames(n: int, *, seed: int = 0, size=BENCH_SIZE):
    """(camera, map, frames) of the built-in scene, rendered at `size` (W, H) px.

    Another size is the same scene seen by a sensor with more (or fewer) pixels: lengths in
    pixels (focal length, disc radius, drift per frame) scale with W / 1280 and the row time
    with 720 / H, so each disc spans the same chips of its packet and the map is the same."""
    from receiver.core.records import Frame
    w, h = int(size[0]), int(size[1])
    sx, sy = w / BENCH_SIZE[0], h / BENCH_SIZE[1]
    leds = bench_scene(size=(w, h), radius_px=BENCH_RADIUS_PX * sx, seed=seed)
    row_us = BENCH_ROW_US / sy
    rng = np.random.default_rng(seed)
    frames = [Frame(k, k / BENCH_FPS, render_bench_frame(leds, k, size=(w, h), row_readout_us=row_us,
                                                         drift_px=(0.7 * sx, 0.3 * sx), rng=rng))
              for k in range(n)]
    cam = bench_camera((w, h), row_readout_us=row_us, focal_px=BENCH_FOCAL_PX * sx)
    return cam, bench_map(leds, camera=cam), frames
