"""What a phone camera adds between the ceiling lights and the video file, for the synthetic
camera (`tools.synth.render`): veiling glare, vignetting, shot / read / row noise, a black
pedestal, clipping with column bloom, the tone curve and sharpening. The panel's own look
(brighter centre, dark bezel) and the in-frame motion of the phone are drawn with each emitter
(`FrameRenderer._draw_emitter`); the lens distortion is the camera's (`make_camera` dist).

`finish_frame` turns a frame's linear LED signal (DN, after the lens PSF) into the 8-bit image;
`draw_phone` draws every effect's strength from the ranges below (`PHONE_RANGES`), so that a
seed gives one phone and other seeds give other phones.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

# Ranges (uniform) of the effects of a phone camera filming a lit ceiling at a short exposure,
# and the camera's calibration (written into camera.yaml as a calibrated phone has it).
PHONE_RANGES = {
    # lens: barrel distortion of a wide phone lens, decentring of a few thousandths
    "k1": (-0.30, -0.08), "k2": (0.0, 0.15), "p1": (-0.002, 0.002), "p2": (-0.002, 0.002),
    # optics: blur, and the share of each light scattered into a wide veil
    "psf_sigma_px": (0.7, 1.5), "glare_frac": (0.005, 0.02), "glare_sigma_px": (20.0, 60.0),
    "vignetting": (0.2, 0.45),
    # sensor: a panel seen at 10-30 us still clips (its plateau up to 1.8x full scale)
    # (linear DN; the lit ceiling a few DN, lifted to 25-50 by the tone curve; the black pedestal
    # is added after the tone curve)
    "led_peak_dn": (250.0, 450.0), "ambient_dn": (2.0, 8.0), "black_level_dn": (4.0, 14.0),
    "shot_noise_alpha": (0.1, 0.5), "read_noise_dn": (0.5, 1.5), "row_noise_dn": (0.2, 0.8),
    "bloom_frac": (0.03, 0.15), "bloom_len_px": (2.0, 8.0),
    # the panel: diffuser falloff towards its edges, a dark bezel (fraction of its half size)
    "centre_gain": (0.1, 0.35), "bezel_frac": (0.04, 0.12),
    # the phone's processing
    "tone_gamma": (1.4, 2.0), "sharpen": (0.3, 0.9), "frame_jitter_us": (50.0, 300.0),
}


def draw_phone(rng: np.random.Generator) -> tuple[dict, dict]:
    """(camera keywords, RenderParams keywords) of one phone drawn from `PHONE_RANGES`, with the
    in-frame motion (a pose per band of `rs_band_rows` rows) on."""
    v = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PHONE_RANGES.items()}
    cam = {"dist": (v.pop("k1"), v.pop("k2"), v.pop("p1"), v.pop("p2"), 0.0)}
    v["rs_band_rows"] = 4
    return cam, v


def vignette_map(height: int, width: int, strength: float) -> np.ndarray:
    """(H, W) float32 gain: 1 at the image centre, 1 - strength at the corners (quadratic in
    the radius: the leading term of cos^4 fall-off and of a lens' mechanical vignetting)."""
    y = (np.arange(height, dtype=np.float32) - (height - 1) / 2) / ((height - 1) / 2)
    x = (np.arange(width, dtype=np.float32) - (width - 1) / 2) / ((width - 1) / 2)
    r2 = (y[:, None] ** 2 * (height / width) ** 2 + x[None, :] ** 2) / (1 + (height / width) ** 2)
    return (1.0 - np.float32(strength) * r2).astype(np.float32)


def bloom_reach_px(length_px: float) -> int:
    """Rows above and below a clipped pixel that `column_bloom` spills into (4 1/e lengths)."""
    return max(1, int(math.ceil(4 * length_px)))


def column_bloom(excess: np.ndarray, length_px: float) -> np.ndarray:
    """The clipped charge `excess` (H, W) spilt along each column both ways with an exponential
    tail of 1/e length `length_px` (the kernel sums to 1: the spilt charge is conserved)."""
    half = bloom_reach_px(length_px)
    k = np.exp(-np.abs(np.arange(-half, half + 1, dtype=np.float32)) / np.float32(length_px))
    k[half] = 0.0
    k /= k.sum()
    return cv2.filter2D(excess, -1, k.reshape(-1, 1), borderType=cv2.BORDER_CONSTANT)


def finish_frame(signal: np.ndarray, ambient: np.ndarray, p, rng: np.random.Generator,
                 vignette: np.ndarray | None) -> np.ndarray:
    """8-bit frame from the linear LED `signal` (H, W) float32 DN (after the PSF) and the
    `ambient` (H, W) DN (the ceiling, darkened under bezels), with the effects of `p`
    (RenderParams): glare, vignetting, noise (thesis eq. 4 plus a per-row offset), clipping at
    255 with column bloom of the excess, tone curve, black pedestal (`black_level_dn`: the
    output's black, as a phone's video keeps it), sharpening."""
    s = signal
    if p.glare_frac > 0:
        veil = cv2.GaussianBlur(s, (0, 0), p.glare_sigma_px, borderType=cv2.BORDER_CONSTANT)
        s = np.float32(1.0 - p.glare_frac) * s + np.float32(p.glare_frac) * veil
    s = s + ambient
    if vignette is not None:
        s = s * vignette
    std = np.sqrt(np.float32(p.shot_noise_alpha) * np.maximum(s, 0) + np.float32(p.read_noise_dn ** 2))
    v = s + std * rng.standard_normal(s.shape, dtype=np.float32)
    if p.row_noise_dn > 0:
        v += np.float32(p.row_noise_dn) * rng.standard_normal((s.shape[0], 1), dtype=np.float32)
    full = np.float32(255.0)
    if p.bloom_frac > 0:
        excess = np.maximum(v - full, 0)
        if excess.any():
            v = np.minimum(v, full) + np.float32(p.bloom_frac) * column_bloom(excess, p.bloom_len_px)
    v = np.clip(v, 0, full)
    if p.tone_gamma != 1.0:
        v = full * (v / full) ** np.float32(1.0 / p.tone_gamma)
    if p.black_level_dn > 0:
        v = np.float32(p.black_level_dn) + v * np.float32(1.0 - p.black_level_dn / 255.0)
    if p.sharpen > 0:
        v = v + np.float32(p.sharpen) * (v - cv2.GaussianBlur(v, (0, 0), 1.0))
    return np.clip(np.rint(v), 0, 255).astype(np.uint8)
