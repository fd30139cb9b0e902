"""Row profiles of a blob: the filled envelope mask, the mean gray per row inside it (what the
OOK and tone decoders read), the mean inside the mask (S2-PSK intensities), stripe depth.
"""

from __future__ import annotations


import cv2
import numpy as np
from receiver.core.native import load, require
from receiver.core.records import Blob

# the compiled masked sums (receiver/vision/_pixels.pyx)
_k = require("receiver.vision._pixels")
# the batched masked means of the S2-PSK pair stage (receiver/vision/_pairing.pyx), or None
_kb = load("receiver.vision._pairing")


def envelope_mask(blob: Blob) -> np.ndarray:
    """(y1 - y0, x1 - x0) uint8 mask (0/1) of the blob's filled envelope inside its bbox."""
    mask = np.zeros((blob.y1 - blob.y0, blob.x1 - blob.x0), np.uint8)
    poly = np.rint(blob.hull - (blob.x0, blob.y0)).astype(np.int32)  # np.round's numbers (half to even)
    cv2.fillConvexPoly(mask, poly, 1)
    return mask


def row_profile(gray: np.ndarray, blob: Blob) -> tuple[np.ndarray, np.ndarray, int]:
    """Row profile of one blob (the decoders' interface).

    Returns `(profile, weights, y0)`: `profile` float32 (R,) = mean gray over the blob's
    filled envelope on each image row y0..y0+R-1 (top to bottom, one sensor row apart, i.e.
    `row_readout_us`), `weights` float32 (R,) = envelope pixels on that row."""
    mask = envelope_mask(blob)
    roi = gray[blob.y0:blob.y1, blob.x0:blob.x1]
    if roi.shape != mask.shape or roi.size == 0:  # envelope on the last row/column: no pixels
        z = np.zeros(mask.shape[0], np.float32)
        return z, z.copy(), int(blob.y0)
    # per row, the envelope's pixel count and gray sum in one pass (exact integers in float32);
    # a row without envelope pixels sums to 0, so dividing it by 1 gives its 0 profile
    sums, weights = np.empty(mask.shape[0], np.float32), np.empty(mask.shape[0], np.float32)
    # (a uint8 frame; its rows made contiguous only when they are not)
    _k.masked_row_sums(roi if roi.strides[1] == 1 else np.ascontiguousarray(roi), mask, sums, weights)
    return sums / np.maximum(weights, 1.0), weights, int(blob.y0)


def mean_in_mask(gray: np.ndarray, blob: Blob) -> float:
    """Mean gray over the blob's envelope (S2-PSK intensity), also when the LED is dark."""
    mask = envelope_mask(blob)
    roi = gray[blob.y0:blob.y1, blob.x0:blob.x1]
    if roi.shape != mask.shape or not roi.size or blob.x0 < 0 or blob.y0 < 0:
        # A box past the frame's edges (a pair's emitter moved there): the part inside the frame
        roi, mask = _inside(gray, blob, mask)
        n = int(mask.sum())
        return float((roi * mask).sum()) / n if n else 0.0
    # the exact integer sum and count in one pass (S2-PSK reads ~30 of these a frame)
    total, n = _k.masked_sum(roi if roi.strides[1] == 1 else np.ascontiguousarray(roi), mask)
    return total / n if n else 0.0


def peak_in_mask(gray: np.ndarray, blob: Blob) -> float:
    """Highest gray over the blob's envelope (the part inside the frame; 0.0 without any): an
    S2-PSK emitter's intensity whatever part of its envelope it lights (a saturated emitter's
    bloom, an envelope a few px off, a clock edge cutting it during the rolling readout)."""
    roi, mask = _inside(gray, blob, envelope_mask(blob))
    return float(roi[mask != 0].max()) if mask.any() else 0.0


def _inside(gray: np.ndarray, blob: Blob, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part of the blob's box inside the frame and the mask's matching part (negative box
    starts would wrap around); both empty when the box lies wholly outside."""
    h, w = gray.shape[:2]
    x0, y0 = max(int(blob.x0), 0), max(int(blob.y0), 0)
    x1, y1 = max(min(int(blob.x1), w), x0), max(min(int(blob.y1), h), y0)
    return (gray[y0:y1, x0:x1],
            mask[y0 - int(blob.y0):y1 - int(blob.y0), x0 - int(blob.x0):x1 - int(blob.x0)])


def stripe_depth(profile: np.ndarray, weights: np.ndarray, *, background: float = 0.0,
                 min_weight_frac: float = 0.3) -> float:
    """Relative modulation (p90 - p10) / (p90 - background) of a row profile over its
    well-covered rows; 0 for a flat (unstriped) blob, about 1 for full-depth stripes."""
    good = weights >= min_weight_frac * (weights.max() if weights.size else 0)
    p = np.sort(profile[good])
    if p.size < 3:
        return 0.0
    lo, hi = float(p[int(0.1 * (p.size - 1))]), float(p[int(round(0.9 * (p.size - 1)))])
    return float((hi - lo) / (hi - background)) if hi > background else 0.0


def peak_in_masks(gray: np.ndarray, blobs: list) -> list[float]:
    """[peak_in_mask(gray, b) for b in blobs] in one kernel call (as `mean_in_masks`)."""
    return mean_in_masks(gray, blobs, peak=True)


def mean_in_masks(gray: np.ndarray, blobs: list, peak: bool = False) -> list[float]:
    """[mean_in_mask(gray, b) for b in blobs] (with `peak`: `peak_in_mask`), equal to the last
    bit, in one kernel call: the envelopes' polygons rounded at once and drawn by
    cv2.fillConvexPoly into one buffer (the masks `envelope_mask` draws), their exact pixel
    sums (maxima) in receiver/vision/_pairing.pyx."""
    if not blobs:
        return []
    if _kb is None or gray.dtype != np.uint8 or gray.ndim != 2:
        one = peak_in_mask if peak else mean_in_mask
        return [one(gray, b) for b in blobs]
    boxes = np.array([(b.x0, b.y0, b.x1, b.y1) for b in blobs], np.int64)
    h, w = boxes[:, 3] - boxes[:, 1], boxes[:, 2] - boxes[:, 0]
    if (h < 0).any() or (w < 0).any():
        return [(peak_in_mask if peak else mean_in_mask)(gray, b) for b in blobs]  # (the reference's error)
    size = h * w
    ends = np.cumsum(size)
    boxes = np.concatenate((boxes, (ends - size)[:, None]), axis=1)
    masks = np.zeros(int(ends[-1]), np.uint8)
    lens = [len(b.hull) for b in blobs]
    polys = np.rint(np.concatenate([b.hull for b in blobs])
                    - np.repeat(boxes[:, :2].astype(float), lens, axis=0)).astype(np.int32)
    start = 0
    for (o, hh, ww), n in zip(np.stack((boxes[:, 4], h, w), axis=1).tolist(), lens):
        if hh and ww:
            cv2.fillConvexPoly(masks[o:o + hh * ww].reshape(hh, ww), polys[start:start + n], 1)
        start += n
    out = np.empty(len(blobs))
    (_kb.masked_peaks if peak else _kb.masked_means)(gray, masks, boxes, out)
    return out.tolist()
