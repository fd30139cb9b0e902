"""LED blob detection on one gray frame: threshold, merge rolling-shutter stripes, envelope.

Stages (each a plain function on numpy arrays):

1. `detect_scale`: frames bigger than `max_detect_px` are searched on an INTER_AREA
   downsampled copy (integer factor, `search_image`), envelopes are refined in
   full-resolution ROIs.
2. `auto_level`: one global threshold from the (subsampled) gray histogram,
   `median + k_mad * 1.4826 * MAD`, floored at `median + min_contrast`. The median and MAD
   follow ambient light and sensor noise; LEDs cover a small part of the frame so they do not
   move the median.
3. Threshold + morphological close with a vertical line of `stripe_gap_px + 1` rows: the
   dark stripes of one LED (an OFF run of chips, or the low half-period of a tone) are bridged,
   two LEDs side by side are not (the kernel is one column wide). The closed mask's 8-connected
   components (findContours' outer contours) are labelled from its pixel runs
   (`_pixels.label_runs`: boxes, first points and the outer contours' exact areas without
   tracing them); the outlines are traced only where they are needed (a downsampled search,
   boxes that overlap, a component with a hole).
4. Per blob, in a full-resolution ROI: a blob level `background + REFINE_FRAC * (peak -
   background)` (half-maximum edge for REFINE_FRAC = 0.5; clipped blobs use a level just
   above the background, see `detect`), the lit pixels of this blob only,
   and their convex hull = the filled envelope of the stripes. Its area is the LED's
   projected area eta of thesis eq. 18 (not the lit pixels); the hull runs through pixel
   centres, so `area_px` adds the half-pixel rim (perimeter / 2 + pi / 4, exact for a disc and
   an axis-aligned square). The centroid comes from the polygon moments of the hull.
   Isolated blobs (the common case) are refined together: their boxes are stacked into one
   strip so the per-pixel work is a few array operations per frame, not per blob.
   Limitation: when the LED's top or bottom cap falls in a dark stripe, the envelope stops at
   the last lit row (up to one stripe gap short).
5. Rejections: specks (`min_area_px`), regions too big to be a light (MAX_AREA_FRAC),
   implausible shapes (`max_aspect`), and, when stripes are expected (rolling shutter with
   OOK/tone lights), flat saturated regions whose row profile shows no stripes.

Image coordinates: px, x right, y down, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import math
import operator

import cv2
import numpy as np
from receiver.core.native import require
from receiver.core.records import Blob
from receiver.vision.profile import row_profile, stripe_depth
from receiver.vision.settings import DetectSettings
from receiver.core.settings import resolve_settings

# the compiled pixel scans (receiver/vision/_pixels.pyx): the one implementation of the frame's
# histogram, threshold masks, run labelling, mosaic and the isolated blobs' envelopes
_k = require("receiver.vision._pixels")

# 1.4826 * MAD estimates sigma for Gaussian noise.
MAD_TO_SIGMA = 1.4826

# The detector's constants (DetectSettings holds what a user sets).
# Horizontal gaps (full-resolution columns; at least one search pixel) bridged, so a stripe
# broken by a dark spot of the diffuser stays one light.
JOIN_X_PX = 2
# A blob's edge level between background (0) and peak (1): half maximum is the edge of a
# blurred sharp-edged light (symmetric PSF), so the hull through the outermost lit pixel centres
# lies half a pixel inside it on average.
REFINE_FRAC = 0.5
# A blob whose peak reaches this gray is clipped (a saturated core in a dimmer, still striped
# glow): its edge level is background + max(SATURATED_FRAC * (255 - background),
# MIN_REFINE_CONTRAST), which keeps the glow and gives the decoders more stripe rows. Also the
# sensor's white level the pipeline reports.
SATURATED_GRAY = 250.0
SATURATED_FRAC = 0.03
MIN_REFINE_CONTRAST = 6.0
# Envelopes larger than this fraction of the frame are a window or a lamp, not a transmitter.
MAX_AREA_FRAC = 0.05
# The stripe-bridged component's contour fills at least this fraction of its box (a disc 0.79,
# a 45-degree square 0.5, a thin diagonal bar almost nothing); border blobs are exempt.
MIN_FILL = 0.25
# A flat blob (`DetectSettings.stripe_check_rows`): its row profile's stripe depth is under this.
MIN_STRIPE_DEPTH = 0.8
# At full resolution with stripes to bridge (stripe_gap_px >= 4), components are searched on the
# maximum of every 2 rows: the close and contour pass cost half as much. Every gap the
# full-resolution search bridges is bridged, the boxes are the full-resolution search's and the
# envelopes are taken in full resolution within them, so the blobs are the same (a frame where
# component boxes overlap is searched in full resolution), except that the pooled rows may join
# lights the full-resolution search keeps apart: stacked up to 4 rows closer than
# stripe_gap_px, touching diagonally (within JOIN_X_PX columns) across a pair of pooled rows, or
# within a row or two of each other at the top or bottom edge; and the MIN_FILL test uses the
# pooled component's area (times 2). 1 = full resolution. Only 1 and 2: with 3 rows the pooled
# close can reach the bottom edge from a row less far than the full-resolution one.
ROW_POOL = 2


def detect_scale(shape: tuple[int, int], max_detect_px: int = 1_200_000) -> int:
    """Integer downsampling factor so that the search image has at most `max_detect_px` pixels;
    3 is taken up to 4, which `search_image` makes by two halvings on OpenCV's SIMD 2 x 2 path
    (a 3840 x 2160 frame: ~0.4 ms against ~3.7 ms for the scalar 3 x 3 block sums)."""
    h, w = shape[:2]
    f = max(1, math.ceil(math.sqrt(h * w / max_detect_px)))
    return 4 if f == 3 else f


def search_image(gray: np.ndarray, f: int) -> np.ndarray:
    """The (H // f, W // f) uint8 search image of an (H, W) uint8 frame: the mean of each f x f
    block, rounded (for f a power of two: of its 2 x 2 blocks' rounded means, recursively; search pixel (i, j) is full-resolution rows [i f, (i + 1) f) and columns
    [j f, (j + 1) f), as `_refine` maps it back). The last H mod f rows and W mod f columns, less
    than one block, are left out: at an exact integer factor OpenCV's INTER_AREA takes its fast
    block-sum path (a 33 MP photo at f = 6: ~11 ms, 0.16 G instructions), while the frame's own
    size (a scale of e.g. 7712 / 1285 = 6.0016) takes the general area resampler, ~4x the work,
    whose blocks drift up to a pixel from [i f, (i + 1) f)."""
    if f == 1:
        return gray
    h, w = gray.shape[:2]
    small = gray[:h // f * f, :w // f * f]
    if f & (f - 1) == 0:
        # a power of two: halvings (OpenCV's SIMD path serves only 2 x 2 blocks), each mean
        # rounded, so the result is within log2(f) / 2 gray levels of the f x f block's mean
        while f > 1:
            small = cv2.resize(small, (small.shape[1] // 2, small.shape[0] // 2), interpolation=cv2.INTER_AREA)
            f //= 2
        return small
    return cv2.resize(small, (w // f, h // f), interpolation=cv2.INTER_AREA)


def auto_level(gray: np.ndarray, *, k_mad: float = 8.0, min_contrast: float = 24.0,
               sample_step: int = 4, fine_noise: bool = False) -> tuple[float, float]:
    """(threshold level, background level) in gray values for an (H, W) uint8 image.

    Uses every `sample_step`-th pixel in both directions (the histogram statistics do not need
    all of them). `k_mad`: noise sigmas above the median; `min_contrast`: the level is at
    least this far above the median (a clean dark frame has MAD 0). `fine_noise`: sigma by
    `noise_sigma` (sub-gray-level noise, a background clipped at 0) instead of 1.4826 MAD, and
    at least the noise next to the lights (`near_light_sigma`: a compressed camera's flat
    background understates it)."""
    hist = np.empty(256, np.float32)
    # the sampled pixels' histogram, their median and MAD (integers) in one pass
    med, mad = _k.sample_stats(_as_frame(gray), max(int(sample_step), 1), hist)
    sigma = noise_sigma(hist, med, mad) if fine_noise else MAD_TO_SIGMA * mad
    level = max(med + k_mad * sigma, med + min_contrast)
    if fine_noise and med + k_mad * med > level:
        # a background flattened below the sensor's noise (see `near_light_sigma`) is not the
        # noise the lights' neighbourhoods carry: the larger of the two sets the level. That
        # noise is at most the background itself (pixels below it deviate by at most its
        # value), so it is measured only where it could raise the level (not on a black one).
        near = near_light_sigma(gray, min(level, 254.0), med)
        level = max(level, med + k_mad * near)
    return float(min(level, 254.0)), float(med)


# Pixels within this many px of a lit one are a light's neighbourhood (`near_light_sigma`):
# its blur skirt and what the camera's processing did next to an edge (a compressed camera's
# 8 x 8 blocks, a sharpening kernel's few px).
NEAR_LIGHT_PX = 4
# Fewer samples below the background than this in those neighbourhoods say nothing about noise.
NEAR_LIGHT_MIN_SAMPLES = 64


def near_light_sigma(gray: np.ndarray, level: float, background: float) -> float:
    """Noise sigma (gray levels) next to the lights of an (H, W) uint8 image: the RMS of the
    deviations below `background` of the pixels within `NEAR_LIGHT_PX` of a pixel above `level`
    (and not above it themselves); 0 when the lights' neighbourhoods hold fewer than
    `NEAR_LIGHT_MIN_SAMPLES` pixels at or below the background.

    A camera that compresses or denoises its frames flattens an empty background far below its
    sensor's noise (MJPEG: a flat 8 gray, sigma 0.25, where the sensor had 1.4), while the
    blocks that hold a light keep an error of the sensor's size and ring around the light's
    edges: a threshold from the flat background's sigma then cuts the ringing into specks and
    joins them to the light. Light only adds to a pixel, so the deviations below the background
    next to a light are noise alone (a bright light's blur, halo or bloom raise pixels, never
    lower them) and measure that error where it matters; on a sensor that does not flatten
    its background they measure its noise again."""
    if not math.isfinite(level) or level >= 255 or gray.size == 0:
        return 0.0
    # the mask (> level, 0 / 255) and its lit pixels' box in one pass
    gray = _as_frame(gray)
    lit = np.empty_like(gray)
    x, y, w, h = _k.search_mask(gray, 1, min(max(math.floor(level) + 1, 0), 256), lit)
    if w == 0:
        return 0.0
    # only the lit pixels' box and its rim are read (lights cover a small part of the frame)
    r = NEAR_LIGHT_PX
    x0, y0 = max(x - r, 0), max(y - r, 0)
    x1, y1 = min(x + w + r, gray.shape[1]), min(y + h + r, gray.shape[0])
    g, lit = gray[y0:y1, x0:x1], lit[y0:y1, x0:x1]
    near = cv2.subtract(cv2.dilate(lit, _ones_kernel(2 * r + 1, 2 * r + 1)), lit)
    bg = int(math.floor(background))
    if bg < 0:
        return 0.0
    below = cv2.bitwise_and(near, cv2.compare(g, bg, cv2.CMP_LE))
    n = cv2.countNonZero(below)
    if n < NEAR_LIGHT_MIN_SAMPLES:
        return 0.0
    # d = bg - v >= 0 on those pixels; the deviation from `background` is d + its fraction
    mean, std = cv2.meanStdDev(cv2.subtract(np.full_like(g, bg), g), mask=below)
    m, sd, frac = float(mean[0, 0]), float(std[0, 0]), background - bg
    return float(math.sqrt(sd * sd + (m + frac) ** 2))


def _native_frame(gray: np.ndarray) -> bool:
    """A frame the compiled scans take: (H, W) uint8, C-contiguous."""
    return gray.ndim == 2 and gray.dtype == np.uint8 and gray.flags.c_contiguous


def _as_frame(gray: np.ndarray) -> np.ndarray:
    """`gray` as the compiled scans take it ((H, W) uint8, C-contiguous; a copy only when it is
    not); TypeError for another kind of image."""
    if _native_frame(gray):
        return gray
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise TypeError(f"expected an (H, W) uint8 image, got {gray.dtype} {gray.shape}")
    return np.ascontiguousarray(gray)


def noise_sigma(hist: np.ndarray, med: int, mad: int) -> float:
    """Gaussian noise sigma (gray levels) of a background with histogram `hist` (256,), median
    `med` and MAD `mad` (integers), resolved below one gray level.

    A MAD of 0 or 1 gray level says little (8-bit rounding: a dark sensor's noise of a fraction
    of a level gives MAD 0, one of 0.5-1.5 levels MAD 1), and a background clipped at black has
    no lower half to measure. The upper tail does: the fraction f of samples at or above med + 1
    (raw value >= med + 0.5) is Q(0.5 / sigma) for noise centred on the median, so sigma =
    0.5 / Q^-1(f). Lights (a small fraction of the frame) barely move f while noise makes it a
    few % or more. From MAD 2 on, 1.4826 * MAD as usual."""
    if mad >= 2:
        return MAD_TO_SIGMA * mad
    n = float(hist.sum())
    if n <= 0:
        return 0.0
    f = float(hist[med + 1:].sum()) / n
    f = min(max(f, 1e-6), 0.49)
    # Half the samples lie within mad + 1/2 of the median (8-bit rounding or truncation), so sigma
    # is at most 1.4826 (mad + 1/2): near f = 1/2 the tail estimate alone explodes (truncated noise
    # of ~2 gray gave 20, a threshold over the lights).
    return min(0.5 / _q_inverse(f), MAD_TO_SIGMA * (mad + 0.5))


def _q_inverse(f: float) -> float:
    """z with P(N(0, 1) > z) = f, for 0 < f < 0.5 (bisection on erfc)."""
    lo, hi = 0.0, 8.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if 0.5 * math.erfc(mid / math.sqrt(2.0)) > f:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _close(mask: np.ndarray, gap_y_px: int, gap_x_px: int, scratch: "Scratch | None" = None) -> np.ndarray:
    """Bridge vertical gaps up to `gap_y_px` rows and horizontal gaps up to `gap_x_px` columns
    (a morphological close: dilate, then erode, into `scratch` buffers when given)."""
    if gap_y_px < 1 and gap_x_px < 1:
        return mask
    kernel = _ones_kernel(_close_size(gap_y_px), _close_size(gap_x_px))
    if scratch is None:
        return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    # the same as MORPH_CLOSE (the same default borders), without frame-sized temporaries
    dil = cv2.dilate(mask, kernel, dst=scratch.get("dilate", mask.shape))
    return cv2.erode(dil, kernel, dst=scratch.get("close", mask.shape))


_KERNELS: dict = {}


def _ones_kernel(h: int, w: int) -> np.ndarray:
    k = _KERNELS.get((h, w))
    if k is None:
        k = _KERNELS[(h, w)] = np.ones((h, w), np.uint8)
    return k


class Scratch:
    """Work buffers kept from frame to frame (one per receiver, `detect(..., scratch=)`), so a
    frame allocates no frame-sized temporaries (each would cost its page faults again).
    `get(name, shape)` is an uninitialised C-contiguous uint8 array of that shape, a view of
    a buffer that is only reallocated when a larger one is needed."""

    def __init__(self):
        self._bufs: dict[str, np.ndarray] = {}
        self._views: dict[str, np.ndarray] = {}  # the last view of each buffer (frames keep their shape)

    def get(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        view = self._views.get(name)
        if view is not None and view.shape == shape:
            return view
        n = 1
        for d in shape:
            n *= int(d)
        buf = self._bufs.get(name)
        if buf is None or buf.size < n:
            buf = self._bufs[name] = np.empty(max(n, 1), np.uint8)
        view = self._views[name] = buf[:n].reshape(shape)
        return view


def _close_size(gap_px: int) -> int:
    """Kernel size (px) of `_close` bridging gaps up to `gap_px`: gap + 1, made odd so the
    kernel stays centred (it then bridges one more when gap + 1 is even)."""
    size = gap_px + 1
    return size + (size + 1) % 2


def _row_extremes(lit: np.ndarray) -> np.ndarray | None:
    """(N, 1, 2) int32 leftmost and rightmost nonzero pixel of every row of the uint8 mask
    `lit`: the same convex hull
    as all lit pixels, from at most 2 points per row."""
    first = lit.argmax(axis=1)  # 0 also for an empty row: told apart by the pixel value
    rows = np.flatnonzero(lit[np.arange(lit.shape[0]), first])
    if rows.size == 0:
        return None
    left = first[rows]
    right = lit.shape[1] - 1 - lit[rows, ::-1].argmax(axis=1)
    pts = np.empty((2 * rows.size, 1, 2), np.int32)
    pts[:rows.size, 0, 0], pts[:rows.size, 0, 1] = left, rows
    pts[rows.size:, 0, 0], pts[rows.size:, 0, 1] = right, rows
    return pts


def _hull_geometry(pts: np.ndarray) -> tuple[float, float, float, np.ndarray]:
    """(cx, cy, area_px, hull (K, 2) float64) of integer pixel-centre points (N, 1, 2)."""
    hull = cv2.convexHull(pts)
    cx, cy, area = _hull_stats_many([hull])
    return float(cx[0]), float(cy[0]), float(area[0]), hull.reshape(-1, 2).astype(np.float64)


def _hull_stats_many(hulls: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cx, cy, area_px), each (N,) float64, of N convex polygons (cv2.convexHull outputs
    (K_i, 1, 2), vertices in order, int or float): the polygon's centroid (Green's theorem, the
    moments cv2.moments gives) and its area plus the half-pixel rim, perimeter / 2 + pi / 4 (each
    vertex is a pixel centre standing for a disc of radius 1/2: the Minkowski sum with it). A
    polygon of no area (a line, a point) has the mean of its vertices as centroid. All N at
    once: a few array operations instead of two OpenCV calls and a 24-entry dict per polygon."""
    return _hull_stats_points(hulls)[:3]


def _hull_stats_points(hulls: list[np.ndarray]):
    """`_hull_stats_many`'s (cx, cy, area_px) and the polygons' vertices: all of them in one
    (sum K_i, 2) float64 array `p` and each polygon's first row in it, `starts` (N,) int64."""
    n = len(hulls)
    k = np.fromiter((len(hh) for hh in hulls), np.int64, n)
    starts = np.zeros(n, np.int64)
    np.cumsum(k[:-1], out=starts[1:])
    p = np.concatenate(hulls).reshape(-1, 2).astype(np.float64)
    nxt = np.arange(1, p.shape[0] + 1)
    nxt[starts + k - 1] = starts  # each polygon closes on its first vertex
    x, y = p[:, 0], p[:, 1]
    xn, yn = x[nxt], y[nxt]
    cross = x * yn - xn * y
    a2 = np.add.reduceat(cross, starts)  # twice the signed area
    sx = np.add.reduceat((x + xn) * cross, starts)
    sy = np.add.reduceat((y + yn) * cross, starts)
    perim = np.add.reduceat(np.hypot(xn - x, yn - y), starts)
    m00 = 0.5 * np.abs(a2)
    flat = m00 <= 1e-6
    safe = np.where(flat, 1.0, a2)
    cx, cy = sx / (3.0 * safe), sy / (3.0 * safe)
    if flat.any():
        cx[flat] = np.add.reduceat(x, starts)[flat] / k[flat]
        cy[flat] = np.add.reduceat(y, starts)[flat] / k[flat]
    return cx, cy, m00 + 0.5 * perim + math.pi / 4.0, p, starts


def detect(gray: np.ndarray, *, settings: DetectSettings | None = None, scratch: Scratch | None = None,
           **overrides) -> list[Blob]:
    """LED blobs of an (H, W) uint8 frame, sorted top to bottom.

    Tunables: `DetectSettings` (receiver.vision.settings), given as `settings=` or as keyword
    overrides of its fields. `scratch`: work buffers kept across frames (`Scratch`, one per
    stream; the results never refer to them), or None.
    """
    s = resolve_settings(settings, DetectSettings, overrides)
    gray = _as_frame(gray)
    h, w = gray.shape[:2]
    f = detect_scale(gray.shape, s.max_detect_px)
    small = search_image(gray, f)
    level, bg = auto_level(small, k_mad=s.k_mad, min_contrast=s.min_contrast, fine_noise=s.fine_noise)
    # Downsampling averages the stripes with their gaps: the LED's mean is about half its peak,
    # so the coarse search uses a level halfway down to the background.
    coarse = level if f == 1 else bg + 0.5 * (level - bg)
    pool = ROW_POOL if f == 1 and ROW_POOL > 1 and s.stripe_gap_px >= 2 * ROW_POOL else 1
    # the components' outlines are needed to map a downsampled search back (f > 1) and to mask
    # a component whose box it shares with another; isolated ones need only boxes and areas
    outlines = f > 1
    contours, rects, areas, alone = _search(small, coarse, s.stripe_gap_px, JOIN_X_PX, f, pool, scratch, outlines)
    if alone is None:
        alone = _isolated(rects)
    if pool > 1 and not alone.all():
        # overlapping boxes are refined within their component's mask, which must be the
        # full-resolution one for the same envelopes: search this frame in full resolution
        pool = 1
        contours, rects, areas, _ = _search(small, coarse, s.stripe_gap_px, JOIN_X_PX, f, pool, scratch, outlines)
        alone = _isolated(rects)
    if contours is None and not alone.all():
        # the same components (boxes, order), now with their outlines
        contours, rects, areas, _ = _search(small, coarse, s.stripe_gap_px, JOIN_X_PX, f, pool, scratch, True)
        alone = _isolated(rects)
    max_area = MAX_AREA_FRAC * h * w
    rect_l, alone_l = rects.tolist(), alone.tolist()
    area_l = areas.tolist() if areas is not None else None
    # boxes (full-resolution px) that can hold an envelope of min_area_px .. max_area
    lo_px, hi_px, ff = s.min_area_px * 0.5, 4 * max_area, f * f
    keep = [i for i, r in enumerate(rect_l) if lo_px <= r[2] * r[3] * ff <= hi_px]
    sat_kw = dict(saturated_gray=SATURATED_GRAY, saturated_frac=SATURATED_FRAC,
                  min_refine_contrast=MIN_REFINE_CONTRAST)
    # Isolated components (the common case) are refined together in one vectorised pass
    # (`_refine_alone_batch`) in their full-resolution boxes; the rest one by one (`_refine`).
    if f == 1:
        batch = [i for i in keep if alone_l[i]]
        batch_rects = rects if len(batch) == len(rect_l) else rects[batch]
    else:
        # a downsampled search: each box mapped back with the rim `_refine` gives its mask, and
        # batched where that box overlaps no other component's (it then holds no foreign lit
        # pixels, and the mask would take nothing away from the box's envelope)
        full = _full_res_boxes(rects, f, w, h)
        iso = _isolated(full).tolist()
        batch = [i for i in keep if iso[i]]
        batch_rects = full[batch]
        gray_b = _masked_boxes(gray, small.shape, [contours[i] for i in batch], batch_rects, f, scratch)
    done = _refine_alone_batch(gray if f == 1 else gray_b, batch_rects, bg, level, REFINE_FRAC,
                               **sat_kw)
    refined = dict(zip(batch, done)) if done is not None else {}
    blobs = []
    min_area_px, max_aspect, shape_min_rows, min_fill = s.min_area_px, s.max_aspect, s.shape_min_rows, MIN_FILL
    for i in keep:
        c, (bx, by, bw, bh) = contours[i] if contours is not None else None, rect_l[i]
        blob = refined[i] if i in refined else _refine(gray, c, (bx, by, bw, bh), f, bg, level,
                                                       REFINE_FRAC, alone_l[i], **sat_kw)
        if blob is None or blob.area_px < min_area_px or blob.area_px > max_area:
            continue
        # Shape test on the stripe-bridged component (one lit stripe alone may be a thin bar):
        # a long box, or a thin diagonal bar filling little of its square box (boxes in search
        # pixels: the full-resolution box over the pooling factor). Components under
        # `shape_min_rows` rows are exempt (a sub-pixel-tall panel is one row several px wide,
        # and a one-row contour has no area to fill its box with).
        if not blob.border and max_aspect and bh >= shape_min_rows and (max(bw, bh) > max_aspect * min(bw, bh)
                                             or pool * (cv2.contourArea(c) if area_l is None else area_l[i])
                                             < min_fill * bw * bh):
            continue
        if s.stripe_check_rows and blob.y1 - blob.y0 >= max(s.stripe_check_rows, 3):
            prof, wts, _ = row_profile(gray, blob)
            if stripe_depth(prof, wts, background=blob.background) < MIN_STRIPE_DEPTH:
                continue
        blobs.append(blob)
    if s.min_rel_area > 0 and blobs:
        biggest = max(b.area_px for b in blobs)
        blobs = [b for b in blobs if b.area_px >= s.min_rel_area * biggest]
    blobs.sort(key=_TOP_TO_BOTTOM)
    return blobs


# the blobs' order: by centre row, then column
_TOP_TO_BOTTOM = operator.attrgetter("cy", "cx")


def _components(image: np.ndarray, level: float, stripe_gap_px: int, join_x_px: int, f: int,
                pool: int = 1, scratch: Scratch | None = None) -> tuple[list, np.ndarray]:
    """Stripe-bridged components of the search image (`detect` steps 2-3): their outer
    contours (search pixels) and bounding boxes (N, 4) x, y, w, h. `pool` > 1: `image` is the
    full-resolution frame, searched on the maxima of each `pool` rows (pool 1 or 2: maxima,
    threshold and the lit box are one pass, `_pixels.search_mask_cells`, and the close and
    contour search run on a mosaic of the lit groups, `_search_mosaic`); the boxes
    are those of the full-resolution search (`_pooled_boxes_exact`), the contours' rows are
    pooled rows. `scratch`: reused work buffers (`Scratch`), or None (fresh ones)."""
    return _search(image, level, stripe_gap_px, join_x_px, f, pool, scratch)[:2]


def _search(image, level, stripe_gap_px, join_x_px, f, pool=1, scratch: Scratch | None = None,
            outlines: bool = True):
    """`_components`, the contours' areas (N,) float64 (cv2.contourArea's), or None for
    the areas (then the caller asks cv2.contourArea), and `_isolated` of the boxes, or None (the
    caller's to ask). `outlines` False: the contours are not needed, None may stand for them
    (the compiled run labelling, `_label`, then gives the boxes, areas and isolation in
    findContours' order without tracing the outlines)."""
    if pool not in (1, 2) or not math.isfinite(level):
        raise ValueError(f"row pooling {pool} (1 or 2) at level {level} (finite)")
    image = _as_frame(image)
    # pooled maximum, threshold, the lit box and the lit 32-column cells in one pass
    ho, w = -(-image.shape[0] // pool), image.shape[1]
    mask = _buf(scratch, "mask", (ho, w))
    cells = _buf(scratch, "cells", (ho, -(-w // 32)))
    on = min(max(math.floor(level) + 1, 0), 256)  # > level for uint8 (cv2.threshold's floor)
    box = _k.search_mask_cells(image, pool, on, mask, cells)
    found = _search_mosaic(mask, cells, box, stripe_gap_px, join_x_px, f, pool, scratch, outlines, image, level)
    if found is None:
        return _components_of_mask(image, mask, box, level, stripe_gap_px, join_x_px, f, pool, scratch,
                                   outlines)
    contours, rects, areas, alone = found
    if pool > 1 and len(rects) and alone is None:
        rects = _pooled_boxes_exact(image, rects, level, pool, _close_reach(stripe_gap_px))
    return contours, rects, areas, alone


def _buf(scratch: Scratch | None, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialised uint8 work array: a `scratch` buffer when given, else a new one."""
    return scratch.get(name, shape) if scratch is not None else np.empty(shape, np.uint8)


# At most this many groups of lit pixels are packed into one mosaic (`_search_mosaic`); more
# (a noise storm) are searched in the lit box as a whole.
MOSAIC_MAX_GROUPS = 256
# Nor when more than this fraction of the lit box's cells hold lit pixels (large lights filling
# the frame, recordings/indoor-walk: 0.55-0.67 of them, the other recordings 0.02-0.2): the
# mosaic would save little of the close and cost more in packing (walk: 0.37 M instructions
# per frame, failing on 39 of 54 frames).
MOSAIC_MAX_FILL = 0.4


def _search_mosaic(mask, cells, box, stripe_gap_px, join_x_px, f, pool, scratch, outlines=True, image=None,
                   level=0.0):
    """(contours, boxes (N, 4), areas (N,), alone) of `_components_of_mask`, searched in a mosaic of the
    lit groups instead of the whole lit box (`_pixels.mosaic`), or None where the kernel does not
    pack (then `_components_of_mask` searches the box).

    Why it is exact: the groups are sets of cells (kernel rows x 32 columns) holding lit pixels,
    8-connected, so the lit pixels of two groups are at least a kernel height or width apart:
    their dilations neither overlap nor touch, so each pixel's dilation and erosion (a window
    inside the dilated pixels, a connected rectangle, lies inside one group's) and each
    component's outer contour depend on one group's pixels only. Each crop keeps a kernel's
    size of empty rows and columns around its group (as the box of `_components_of_mask` does),
    and its sides at the mask's edges on the mosaic's edges (the erosion treats the outside of
    the image as lit). Contours are traced from their first pixel in raster order, the same
    pixel wherever the group lies; `_pixels.place_contours` moves them back and they are
    ordered as findContours orders them (by descending first point). `outlines` False: see
    `_search` (`image`, `level`: the frame and threshold, for `_label`'s full-resolution boxes
    when pool > 1)."""
    gap_y, gap_x = _search_gaps(stripe_gap_px, join_x_px, f, pool)
    if box[2] == 0 or (gap_y < 1 and gap_x < 1):
        return None
    crops = np.empty((MOSAIC_MAX_GROUPS, 7), np.int64)
    out = _buf(scratch, "mosaic", (mask.size,))
    n, hm, wm = _k.mosaic(mask, cells, *box, _close_size(gap_y), _close_size(gap_x), crops, out, MOSAIC_MAX_FILL)
    if n < 0:
        return None
    closed = _close(out[:hm * wm].reshape(hm, wm), gap_y, gap_x, scratch)
    if not outlines:
        found = _label(closed, crops, n, 0, 0, image, level, pool, _close_reach(stripe_gap_px))
        if found is not None:
            return (None,) + found
    contours, _ = cv2.findContours(closed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    nc = len(contours)
    if nc == 0:
        return [], np.zeros((0, 4), np.int64), np.zeros(0), None
    pts = np.concatenate(contours)
    starts = np.zeros(nc + 1, np.int64)
    np.cumsum(np.fromiter(map(len, contours), np.int64, nc), out=starts[1:])
    rects, areas, keys = np.empty((nc, 4), np.int64), np.empty(nc), np.empty(nc, np.int64)
    _k.place_contours(pts.reshape(-1, 2), starts, crops, n, rects, areas, keys)
    order = np.argsort(keys)[::-1]
    st = starts.tolist()
    return [pts[st[i]:st[i + 1]] for i in order.tolist()], rects[order], areas[order], None


def _search_gaps(stripe_gap_px: int, join_x_px: int, f: int, pool: int) -> tuple[int, int]:
    """(rows, columns) of the gaps the close bridges in the search image (`_components`)."""
    if pool > 1:
        # The full-resolution close bridges gaps of up to 2 * reach rows (its odd kernel can
        # be one row taller than stripe_gap_px + 1). A gap of g rows leaves at most
        # floor(g / pool) empty pooled rows, so bridging ceil((g + 1) / pool) - 1 of them
        # bridges every such gap (and, with the odd kernel, some up to 3 * pool - 2 longer).
        gap_y = math.ceil((2 * _close_reach(stripe_gap_px) + 1) / pool) - 1
    else:
        gap_y = math.ceil(stripe_gap_px / f)
    return gap_y, math.ceil(join_x_px / f)


def _components_of_mask(image, mask, box, level, stripe_gap_px, join_x_px, f, pool, scratch, outlines=True):
    """`_search` after the threshold: `mask` the thresholded search image (0 / 255), `box`
    its lit pixels' bounding box (x, y, w, h); the same four results."""
    gap_y, gap_x = _search_gaps(stripe_gap_px, join_x_px, f, pool)
    # The close and the contour search run on the box of the lit pixels grown by the kernel
    # size (clipped to the frame): outside it the closed mask is 0, and within it the close
    # is the whole frame's (a pixel within half a kernel of the box's inner edge is more than
    # half a kernel from any lit pixel, so its dilation and its erosion are 0 either way).
    bx, by, bw, bh = box
    if bw == 0:
        return [], np.zeros((0, 4), np.int64), None, None
    my, mx = (_close_size(gap_y), _close_size(gap_x)) if gap_y >= 1 or gap_x >= 1 else (1, 1)
    y0, x0 = max(by - my, 0), max(bx - mx, 0)
    y1, x1 = min(by + bh + my, mask.shape[0]), min(bx + bw + mx, mask.shape[1])
    closed = _close(mask[y0:y1, x0:x1], gap_y, gap_x, scratch)
    found = _label(closed, None, 0, x0, y0, image, level, pool, _close_reach(stripe_gap_px)) if not outlines else None
    if found is not None:
        return (None,) + found
    # findContours + one small fill per blob is several times faster here than
    # connectedComponentsWithStats, which labels the whole frame.
    contours, _ = cv2.findContours(closed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE, offset=(x0, y0))
    rects = np.array([cv2.boundingRect(c) for c in contours], np.int64).reshape(-1, 4)
    if pool > 1 and len(rects):
        rects = _pooled_boxes_exact(image, rects, level, pool, _close_reach(stripe_gap_px))
    return contours, rects, None, None


# At most this many components are labelled by runs (`_label`); more (a noise storm) are traced.
LABEL_MAX_COMPONENTS = 2048


def _label(closed: np.ndarray, crops: np.ndarray | None, n_crops: int, ox: int, oy: int, image=None,
           level: float = 0.0, pool: int = 1, reach: int = 0):
    """(boxes (N, 4) x, y, w, h, areas (N,) float64, alone (N,) bool) of the outer
    contours findContours(closed, RETR_EXTERNAL) would find, in its order, from the compiled run
    labelling of the closed mask (`_pixels.label_boxes`, no outline traced); coordinates moved
    by (ox, oy), or by the `mosaic` crops when n_crops > 0; with pool > 1 the boxes are the
    full-resolution search's (`_pooled_boxes_exact` of the frame `image` at `level`, `reach`),
    and alone is `_isolated` of the boxes. None where it does not answer: a component with a hole (its outer
    contour's area covers the hole, and a component inside it would have no outer contour of
    its own), more than LABEL_MAX_COMPONENTS components, a mask that is not C-contiguous."""
    if not _native_frame(closed) or (pool > 1 and (image is None or not _native_frame(image))):
        return None
    out = np.empty((LABEL_MAX_COMPONENTS, 7), np.int64)
    on = min(math.floor(level) + 1, 255) if pool > 1 else 0
    n = _k.label_boxes(closed, _NO_CROPS if crops is None else crops, n_crops, ox, oy, image, on, pool, reach, out)
    if n == -2:  # a box without a lit pixel: `_pooled_boxes_exact` decides
        n = _k.label_boxes(closed, _NO_CROPS if crops is None else crops, n_crops, ox, oy, None, 0, 1, 0, out)
        rects = _pooled_boxes_exact(image, out[:n, :4], level, pool, reach)
        return rects, out[:n, 4] * 0.5, _isolated(rects)
    if n < 0:
        return None
    return out[:n, :4], out[:n, 4] * 0.5, out[:n, 5].astype(bool)


_NO_CROPS = np.zeros((0, 7), np.int64)


def _close_reach(gap_y_px: int) -> int:
    """Rows the full-resolution close (`_close`) reaches beyond a component towards the image's
    top or bottom edge: half its (odd) kernel height. The close treats the outside of the
    image as lit, so a component this close to the edge is extended to it."""
    return _close_size(gap_y_px) // 2


def _pooled_boxes_exact(gray: np.ndarray, rects: np.ndarray, level: float, pool: int,
                        reach: int) -> np.ndarray:
    """The full-resolution search's boxes (N, 4) x, y, w, h for boxes found on `pool`-row
    maxima (`rects`, rows in pooled rows): columns are the same; the rows run from the
    component's first to its last row with a pixel above `level`, extended to the image's top
    or bottom row when that is within `reach` rows (`_close_reach`). Those rows are among a box's
    first and last `pool` rows (its top and bottom pooled rows hold a lit pixel), except where
    the pooled close itself reached the image edge: such boxes are searched whole."""
    # the compiled pass, and numpy where it declines (a box with no lit pixel in its first or last
    # `pool` rows, or past the frame)
    out = np.empty((len(rects), 4), np.int64)
    on = min(math.floor(level) + 1, 255)
    if _k.pooled_boxes(_as_frame(gray), np.ascontiguousarray(rects, np.int64), on, pool, reach, out):
        return out
    h = gray.shape[0]
    x, w = rects[:, 0], rects[:, 2]
    y = rects[:, 1] * pool
    hh = np.minimum((rects[:, 1] + rects[:, 3]) * pool, h) - y
    on = np.uint8(min(math.floor(level) + 1, 255))
    n = len(rects)
    cols = np.minimum(x[:, None] + np.arange(int(w.max())), gray.shape[1] - 1)  # (N, max w)
    inside = np.arange(cols.shape[1]) < w[:, None]
    k = np.arange(pool)
    ends = []
    for rows in (np.minimum(y[:, None] + k, y[:, None] + hh[:, None] - 1),  # first rows, down
                 np.maximum(y[:, None] + hh[:, None] - 1 - k, y[:, None])):  # last rows, up
        # np.take of flat indices: the same pixels as gray[rows, cols], a cheaper gather
        px = gray.ravel().take(rows[:, :, None] * gray.shape[1] + cols[:, None, :])
        lit = ((px >= on) & inside[:, None, :]).any(axis=2)
        ends.append((rows[np.arange(n), lit.argmax(axis=1)], lit.any(axis=1)))
    (top, ok_top), (bottom, ok_bottom) = ends
    for i in np.flatnonzero(~(ok_top & ok_bottom)).tolist():
        yi, xi = int(y[i]), int(x[i])
        lit_rows = np.flatnonzero((gray[yi:yi + int(hh[i]), xi:xi + int(w[i])] >= on).any(axis=1))
        top[i], bottom[i] = yi + lit_rows[0], yi + lit_rows[-1]
    top = np.where(top <= reach, 0, top)
    bottom = np.where(h - 1 - bottom <= reach, h - 1, bottom)
    return np.stack((x, top, w, bottom - top + 1), axis=1)


def _full_res_boxes(rects: np.ndarray, f: int, w: int, h: int, pad: int = 1) -> np.ndarray:
    """(N, 4) int64 x, y, w, h: search-image boxes `rects` (factor `f`) in full-resolution
    pixels of a (h, w) frame, grown by `pad` search pixels (the rim of `_refine`'s mask: the
    coarse edge is blurred) and clipped to the frame. Search pixel i covers full-resolution
    pixels [i f, (i + 1) f)."""
    r = np.asarray(rects, np.int64).reshape(-1, 4)
    x0 = np.maximum((r[:, 0] - pad) * f, 0)
    y0 = np.maximum((r[:, 1] - pad) * f, 0)
    x1 = np.minimum((r[:, 0] + r[:, 2] + pad) * f, w)
    y1 = np.minimum((r[:, 1] + r[:, 3] + pad) * f, h)
    return np.stack((x0, y0, x1 - x0, y1 - y0), axis=1)


def _masked_boxes(gray, small_shape, contours, boxes, f, scratch: Scratch | None) -> np.ndarray:
    """A frame-sized uint8 image that, within each of `boxes` (`_full_res_boxes` of the
    components' search boxes), is `gray` where the component's mask of `_refine` is set (its
    filled outer contour at search scale, dilated by one search pixel, each search pixel an
    f x f block) and 0 elsewhere (never lit, never a peak); outside the boxes it is undefined.
    So `_refine_alone_batch` on it refines every box as `_refine` does with the mask. The boxes
    overlap no other component's, so one fill and one dilation serve them all."""
    n = len(contours)
    out = _buf(scratch, "masked", gray.shape)
    if n == 0:
        return out
    hs, ws = small_shape[:2]
    pad = 1  # the mask has a one search pixel border: the rim around a box at the image's edge
    comp = _buf(scratch, "refine_comp", (hs + 2 * pad, ws + 2 * pad))
    comp.fill(0)
    cv2.drawContours(comp, contours, -1, 255, thickness=cv2.FILLED, offset=(pad, pad))
    comp = cv2.dilate(comp, _ones_kernel(3, 3), dst=_buf(scratch, "refine_comp_dilated", comp.shape))
    for x0, y0, bw, bh in boxes.tolist():
        # search pixel j of the padded mask covers full-resolution pixels [(j - pad) f, (j - pad + 1) f)
        j0, i0 = x0 // f + pad, y0 // f + pad
        j1, i1 = -(-(x0 + bw) // f) + pad, -(-(y0 + bh) // f) + pad
        crop = comp[i0:i1, j0:j1]
        if cv2.countNonZero(crop) == crop.size:  # the mask covers the box (a panel): a plain copy
            out[y0:y0 + bh, x0:x0 + bw] = gray[y0:y0 + bh, x0:x0 + bw]
            continue
        g, o = gray[y0:y0 + bh, x0:x0 + bw], out[y0:y0 + bh, x0:x0 + bw]
        ox, oy = x0 - (j0 - pad) * f, y0 - (i0 - pad) * f
        if f in _WIDE and bh * bw >= WIDE_MIN_PX and ox == 0 and oy == 0:
            _and_blocks(g, crop, f, o)
            continue
        up = cv2.resize(crop, ((j1 - j0) * f, (i1 - i0) * f), interpolation=cv2.INTER_NEAREST)
        cv2.bitwise_and(g, up[oy:oy + bh, ox:ox + bw], dst=o)
    return out


# Factors whose f x f blocks `_and_blocks` makes without a resize: the unsigned type of f bytes
# and the multiplier that repeats a 0 / 255 byte f times in it.
_WIDE = {2: (np.uint16, 0x0101), 4: (np.uint32, 0x01010101), 8: (np.uint64, 0x0101010101010101)}
# Boxes of at least this many pixels are masked by `_and_blocks`; on smaller ones its f calls
# cost more than the resize saves (crossover measured at 10-14 k px for f = 2 and 4).
WIDE_MIN_PX = 12_000


def _and_blocks(g: np.ndarray, crop: np.ndarray, f: int, out: np.ndarray) -> None:
    """out = g AND the 0 / 255 mask `crop` with each pixel an f x f block (f in `_WIDE`), for a
    box `g` starting on a block corner: the INTER_NEAREST resize's result without its per-pixel
    table (each mask byte widened to f bytes by one multiplication, and the mask row shared by
    the box rows i, i + f, i + 2 f, ... of each phase i)."""
    bh, bw = g.shape
    kind, ones = _WIDE[f]
    wide = (crop.astype(kind) * kind(ones)).view(np.uint8)
    for i in range(min(f, bh)):
        cv2.bitwise_and(g[i::f], wide[:(bh - i + f - 1) // f, :bw], dst=out[i::f])


def _isolated(rects: np.ndarray) -> np.ndarray:
    """(N,) bool: bounding box (x, y, w, h) i overlaps no other box."""
    if len(rects) > 2000:  # a noise storm: skip the O(N^2) test, mask every blob
        return np.zeros(len(rects), bool)
    out = np.empty(len(rects), bool)
    _k.isolated(np.ascontiguousarray(rects, np.int64), out.view(np.uint8))
    return out


def _refine_alone_batch(gray, rects, bg, level, refine_frac, *, saturated_gray=250.0,
                        saturated_frac=0.03, min_refine_contrast=6.0) -> list[Blob | None] | None:
    """`_refine` for N isolated full-resolution components (boxes (N, 4) x, y, w, h) at once, by
    one call of the compiled kernel (`_pixels.refine_alone_blobs`: peaks, levels, the leftmost /
    rightmost lit pixel of every row, their convex hull and its stats, the Blob records): the
    same hull as `_refine`'s cv2.convexHull (vertices and orientation), its stats within float
    rounding. None where the kernel does not answer (a box outside the frame, a negative or NaN
    level): the caller then refines one by one."""
    if len(rects) == 0:
        return []
    return _k.refine_alone_blobs(_as_frame(gray), np.ascontiguousarray(rects, np.int64), float(bg), float(level),
                                 float(refine_frac), float(saturated_gray), float(saturated_frac),
                                 float(min_refine_contrast), Blob, np.empty)


def _refine(gray, contour, rect, f, bg, level, refine_frac, alone=False, *, saturated_gray=250.0,
            saturated_frac=0.03, min_refine_contrast=6.0) -> Blob | None:
    """Envelope of one coarse component (outer `contour` at search scale), in full resolution.
    `alone`: no other component's box overlaps this one's (at full resolution the bounding
    box then holds no foreign pixels above the level, and the component mask is skipped)."""
    h, w = gray.shape[:2]
    bx, by, bw, bh = rect
    if f == 1 and alone:
        comp = None
        x0c, y0c, x1c, y1c = bx, by, bx + bw, by + bh
    elif f == 1:
        comp = np.zeros((bh, bw), np.uint8)
        cv2.drawContours(comp, [contour], -1, 1, thickness=cv2.FILLED, offset=(-bx, -by))
        x0c, y0c, x1c, y1c = bx, by, bx + bw, by + bh
    else:
        # The component's filled mask with a one search pixel rim (the coarse edge is blurred);
        # search pixel i covers full-res pixels [i*f, (i+1)*f).
        pad = 1
        comp = np.zeros((bh + 2 * pad, bw + 2 * pad), np.uint8)
        cv2.drawContours(comp, [contour], -1, 1, thickness=cv2.FILLED, offset=(pad - bx, pad - by))
        comp = cv2.dilate(comp, np.ones((3, 3), np.uint8))
        comp = cv2.resize(comp, (comp.shape[1] * f, comp.shape[0] * f), interpolation=cv2.INTER_NEAREST)
        x0, y0 = (bx - pad) * f, (by - pad) * f
        x0c, y0c = max(x0, 0), max(y0, 0)
        x1c, y1c = min(x0 + comp.shape[1], w), min(y0 + comp.shape[0], h)
        comp = comp[y0c - y0:y1c - y0, x0c - x0:x1c - x0]
    roi = gray[y0c:y1c, x0c:x1c]
    _, peak, _, _ = cv2.minMaxLoc(roi, mask=comp)
    if peak >= saturated_gray:
        # Clipped: the true peak is unknown and a fraction of the clipped value would cut into
        # the light; its edge is taken where it rises out of the background.
        blob_level = bg + max(saturated_frac * (255.0 - bg), min_refine_contrast)
    else:
        blob_level = max(bg + refine_frac * (peak - bg), min(level, peak - 1))
    _, lit = cv2.threshold(roi, blob_level, 1, cv2.THRESH_BINARY)
    pts = _row_extremes(lit if comp is None else cv2.bitwise_and(lit, comp))
    if pts is None:
        return None
    cx, cy, area, poly = _hull_geometry(pts)
    poly += (x0c, y0c)
    px0, py0 = np.floor(poly.min(axis=0)).astype(int)
    px1, py1 = np.floor(poly.max(axis=0)).astype(int) + 1
    border = px0 <= 0 or py0 <= 0 or px1 >= w or py1 >= h
    return Blob(cx + x0c, cy + y0c, area, poly, int(px0), int(py0), int(px1), int(py1),
                bool(border), float(peak), float(blob_level), float(bg))
