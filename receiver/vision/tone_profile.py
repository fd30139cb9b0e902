"""Row profile for tone decoding: the LED's whole striped extent, log intensity.

`receiver.vision.profile.row_profile` averages over the half-maximum envelope, which on real phone
photos (Luxapose, Lumia 1020) covers only the saturated core of an LED: 67-97 rows of a light
whose stripes span 110-160 rows, i.e. 3-4 stripe periods instead of 5-7. The stripe
frequency estimate of such a short record is biased by the envelope (up to 4 % on a 2000 Hz
LED). Rows are sampled at their own instants (rolling shutter), so every row where the LED's
glow is visible is a valid sample of its ON/OFF state, however dim: optical blur spreads the
light across rows but all of it was emitted at that row's instant.

The tone profile therefore
- widens the row band by `extend_frac` of the envelope height on both sides, then trims it to
  the first and last rows that are lit (above the background by `lit_gray` or `lit_frac` of the
  brightest row, whichever is larger);
- averages only the central `core_frac` of the envelope's columns (the glow's outer columns
  belong to one stripe row at a time but add little light and more noise; a neighbouring
  light beside the LED stays out);
- takes the log of (mean - background + `log_offset_gray`), so the saturated bright core does
  not dominate the spectrum over the dim striped rows above and below it: the ON level then
  varies slowly (log of the glow's envelope) while the OFF level stays at log(offset).

Image coordinates: px, x right, y down (rows = rolling-shutter rows, one `row_readout_us` apart).
"""

from __future__ import annotations

import cv2
import numpy as np

from receiver.core.records import Blob


def tone_profile(gray: np.ndarray, blob: Blob, *, extend_frac: float = 0.6, core_frac: float = 0.8,
                 lit_gray: float = 3.0, lit_frac: float = 0.02, log_offset_gray: float = 1.0
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Tone row profile of one blob in an (H, W) uint8 frame.

    Returns `(profile, weights, y0)`: `profile` float32 (R,) = log(mean gray over the core
    columns - blob.background + log_offset_gray) on image rows y0..y0+R-1 (top to bottom);
    `weights` float32 (R,) = pixels averaged per row (constant: the band is a rectangle).
    Tunables (defaults in brackets):
      extend_frac [0.6]: rows added above and below the envelope, as a fraction of its height
        (the striped glow of a saturated LED reaches ~0.3-0.5 envelope heights beyond it).
      core_frac [0.8]: central fraction of the envelope's width whose columns are averaged.
      lit_gray [3], lit_frac [0.02]: a row is lit when its mean exceeds the background by
        max(lit_gray, lit_frac * brightest row's excess); the band is trimmed to the outermost
        lit rows (dark stripes inside stay: they are half of the signal).
      log_offset_gray [1]: added before the log, about the sensor noise in dark rows (keeps
        the OFF level finite; larger values let the bright core weigh more).
    An empty band (blob on the image edge) gives empty arrays.
    """
    h, w = gray.shape[:2]
    env_h = blob.y1 - blob.y0
    ext = int(round(extend_frac * env_h))
    y0, y1 = max(blob.y0 - ext, 0), min(blob.y1 + ext, h)
    cx = 0.5 * (blob.x0 + blob.x1)
    half = max(0.5, 0.5 * core_frac * (blob.x1 - blob.x0))
    x0, x1 = max(int(round(cx - half)), 0), min(int(round(cx + half)), w)
    if y1 <= y0 or x1 <= x0:
        z = np.zeros(0, np.float32)
        return z, z.copy(), int(y0)
    # band.mean(axis=1, dtype=np.float32): each row's sum is an integer below 2^24, exact in
    # float32 and int32 alike, so OpenCV's integer row sums divided in float64 and rounded to
    # float32 are numpy's numbers (its float32 sum divided by the np.intp count)
    sums = cv2.reduce(gray[y0:y1, x0:x1], 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).reshape(-1)
    mean = (sums / float(x1 - x0)).astype(np.float32)
    mean -= np.float32(blob.background)
    level = max(lit_gray, lit_frac * float(np.maximum.reduce(mean)))
    lit = (mean > level).nonzero()[0]
    if lit.size:
        a, b = int(lit[0]), int(lit[-1]) + 1
        mean, y0 = mean[a:b], y0 + a
    # log(max(mean, 0) + offset) in float32, in place
    np.maximum(mean, np.float32(0.0), out=mean)
    mean += np.float32(log_offset_gray)
    profile = np.log(mean, out=mean)
    weights = np.full(profile.size, float(x1 - x0), np.float32)
    return profile, weights, int(y0)
