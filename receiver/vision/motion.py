"""The camera's frame-to-frame image shift, from the blobs of two frames (S2-PSK road scenes).

Road vibration turns the camera by a few tenths of a degree in pitch and yaw at 2-17 Hz: with a
1200 px focal length every far light jumps by up to ~6 px from one frame to the next, in both
directions, more than the 4-10 px between the two halves of a far street-light head. No track's
or pair's own velocity predicts that. A rotation moves all far lights alike, so the shift is the
mode of the displacements between this frame's and the previous frame's blob centroids: every
blob pair within `radius_px` votes for its displacement in a 2D histogram of `bin_px` cells,
the (3 x 3 smoothed) peak is taken if at least `min_votes` displacements agree within one cell,
and refined by the mean of the displacements within `refine_px` of it. Blinking emitters and
lights entering or leaving the view only add scattered votes. Cost: one histogram of at most
N x M displacements (N, M ~ 10-50 blobs).
"""

from __future__ import annotations

import numpy as np

from receiver.core.native import load

# Compiled `vertical_shift` (one call per frame); None: its numpy form below (the reference).
_k = load("receiver.vision._motion")
_NO_VOTES = np.zeros((0, 2))


def _rows2(a) -> np.ndarray:
    """`a` as a C-contiguous float64 (K, 2) array (the kernel's input; no copy when it is one)."""
    if isinstance(a, np.ndarray) and a.dtype == np.float64 and a.ndim == 2 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(np.asarray(a, float).reshape(-1, 2))


def frame_shift(prev_xy: np.ndarray, xy: np.ndarray, *, radius_px: float = 14.0, bin_px: float = 1.0,
                refine_px: float = 2.0, min_votes: int = 3, extra: np.ndarray | None = None
                ) -> tuple[float, float] | None:
    """(dx, dy) px, the common image shift from the previous frame's blob centroids `prev_xy`
    (N, 2) to this frame's `xy` (M, 2); None when fewer than `min_votes` displacements agree.
    `extra` (K, 2): further displacement votes (the pairs' hypotheses, `Pairer.shift_votes`)."""
    d = (xy[None, :, :] - prev_xy[:, None, :]).reshape(-1, 2)
    if extra is not None and len(extra):
        d = np.concatenate((d, np.asarray(extra, float).reshape(-1, 2)))
    if len(d) == 0:
        return None
    d = d[(np.abs(d[:, 0]) <= radius_px) & (np.abs(d[:, 1]) <= radius_px)]
    if len(d) < min_votes:
        return None
    nb = int(np.ceil(radius_px / bin_px))
    idx = np.clip(np.floor(d / bin_px + 0.5).astype(np.int64) + nb, 0, 2 * nb)
    hist = np.zeros((2 * nb + 1, 2 * nb + 1))
    np.add.at(hist, (idx[:, 1], idx[:, 0]), 1.0)
    sm = hist.copy()
    sm[1:, :] += hist[:-1, :]
    sm[:-1, :] += hist[1:, :]
    sm2 = sm.copy()
    sm2[:, 1:] += sm[:, :-1]
    sm2[:, :-1] += sm[:, 1:]
    iy, ix = np.unravel_index(int(np.argmax(sm2)), sm2.shape)
    peak = np.array([(ix - nb) * bin_px, (iy - nb) * bin_px])
    near = d[np.hypot(d[:, 0] - peak[0], d[:, 1] - peak[1]) <= refine_px + 0.5 * bin_px]
    if len(near) < min_votes:
        return None
    near = near[np.hypot(*(near - near.mean(axis=0)).T) <= refine_px] if len(near) > min_votes else near
    if len(near) < min_votes:
        return None
    m = near.mean(axis=0)
    return float(m[0]), float(m[1])


def vertical_shift(prev_xy: np.ndarray, xy: np.ndarray, *, radius_px: float = 14.0, bin_px: float = 0.5,
                   refine_px: float = 1.0, min_votes: int = 3, extra: np.ndarray | None = None) -> float | None:
    """dy px, the common vertical image shift (pitch) alone: the mode of the vertical parts of
    the displacements within `radius_px` (as `frame_shift`). Street-light heads are horizontal,
    so whichever half of a head is lit in either frame, its displacement's vertical part is the
    shift: every head votes right, unlike the horizontal part (ambiguous by the baseline)."""
    if _k is not None and min_votes >= 1:
        ex = _NO_VOTES if extra is None or not len(extra) else _rows2(extra)
        return _k.vertical_shift(_rows2(prev_xy), _rows2(xy), ex, float(radius_px), float(bin_px),
                                 float(refine_px), int(min_votes))
    d = (xy[None, :, :] - prev_xy[:, None, :]).reshape(-1, 2)
    if extra is not None and len(extra):
        d = np.concatenate((d, np.asarray(extra, float).reshape(-1, 2)))
    d = d[(np.abs(d[:, 0]) <= radius_px) & (np.abs(d[:, 1]) <= radius_px)]
    if len(d) < min_votes:
        return None
    nb = int(np.ceil(radius_px / bin_px))
    idx = np.clip(np.floor(d[:, 1] / bin_px + 0.5).astype(np.int64) + nb, 0, 2 * nb)
    h = np.bincount(idx, minlength=2 * nb + 1).astype(float)
    sm = h.copy()
    sm[1:] += h[:-1]
    sm[:-1] += h[1:]
    peak = (int(np.argmax(sm)) - nb) * bin_px
    near = d[np.abs(d[:, 1] - peak) <= refine_px, 1]
    if len(near) < min_votes:
        return None
    return float(np.median(near))



def yaw_pitch_shift(ref_xy: np.ndarray, xy: np.ndarray, *, radius_px: float = 14.0, bin_px: float = 0.5,
                    refine_px: float = 1.0, row_px: float = 1.0, min_votes: int = 3,
                    extra: np.ndarray | None = None) -> tuple[float, float] | None:
    """(dx, dy) px from this frame's blob centroids `xy` (M, 2) and the last frames' `ref_xy`
    (N, 2, all in the previous frame's view). The vertical shift first (`vertical_shift`: every
    head votes right whichever half is lit), then the horizontal one: each blob of this frame
    votes once per 'bin_px' cell for the horizontal parts of its displacements to the
    reference blobs whose vertical part is within `row_px` of dy (the same half or the whole
    head seen in one of the last frames: these agree; the head's other half: these scatter by
    each head's own baseline). None when fewer than `min_votes` agree."""
    dy = vertical_shift(ref_xy, xy, radius_px=radius_px, bin_px=bin_px, refine_px=refine_px,
                        min_votes=min_votes, extra=extra)
    if dy is None or not len(ref_xy) or not len(xy):
        return None
    d = xy[:, None, :] - ref_xy[None, :, :]  # (M, N, 2)
    owner = np.broadcast_to(np.arange(len(xy))[:, None], d.shape[:2]).reshape(-1)
    d = d.reshape(-1, 2)
    ok = (np.abs(d[:, 0]) <= radius_px) & (np.abs(d[:, 1] - dy) <= row_px)
    d, owner = d[ok], owner[ok]
    if len(d) < min_votes:
        return None
    nb = int(np.ceil(radius_px / bin_px))
    idx = np.clip(np.floor(d[:, 0] / bin_px + 0.5).astype(np.int64) + nb, 0, 2 * nb)
    n = 2 * nb + 1
    # one vote per blob and cell, spread to the two neighbour cells (the smoothing)
    cells = np.unique(np.concatenate([owner * (n + 2) + idx + k for k in (0, 1, 2)]))
    h = np.bincount(cells % (n + 2), minlength=n + 2)[1:n + 1].astype(float)
    peak = (int(np.argmax(h)) - nb) * bin_px
    sel = np.abs(d[:, 0] - peak) <= refine_px
    if len(np.unique(owner[sel])) < min_votes:
        return None
    return float(np.median(d[sel, 0])), dy


def pair_dx(offsets: list, *, radius_px: float = 14.0, sigma_px: float = 1.5, step_px: float = 0.25,
            zero_rel: float = 0.15, min_score: float = 1.0) -> float | None:
    """dx px, the horizontal image shift (yaw) that best puts the frame's blobs where the S2-PSK
    pairs expect them (`Pairer.dx_offsets`): `offsets` holds per blob near a pair the shifts
    (1-D array, px) that would put it on a place it may be (the midpoint for a blob both lit,
    A or B for one emitter's). Each blob adds exp(-(dx - offset)^2 / (2 sigma_px^2)) of its
    best offset to the score of every dx on a `step_px` grid within +-`radius_px`: a blob
    counts once whichever place it fits, so the baseline ambiguity of one head (which half is
    lit) is settled by the other heads, whose baselines differ. 0 when its score is within
    `zero_rel` of the best (a scene without yaw keeps dx 0, not a few px of noise); None
    when the best score is under `min_score` (no pair saw a blob). `offsets` may also be one
    (K, M) array, a blob's unused places +inf. Cost: blobs x grid."""
    if len(offsets) == 0:
        return None
    grid = np.arange(-radius_px, radius_px + 0.5 * step_px, step_px)
    # every blob at once: its offsets padded with +inf (exp(-inf) = 0 never wins the max), the
    # blobs' best values summed in order (numpy's reduction along the first axis)
    if isinstance(offsets, np.ndarray):
        off = offsets.reshape(len(offsets), -1)
    else:
        off = np.full((len(offsets), max(len(c) for c in offsets)), np.inf)
        for k, c in enumerate(offsets):
            off[k, :len(c)] = c
    score = np.exp(-0.5 * ((grid[None, :, None] - off[:, None, :]) / sigma_px) ** 2).max(axis=2).sum(axis=0)
    i = int(np.argmax(score))
    if score[i] < min_score:
        return None
    if float(np.interp(0.0, grid, score)) >= (1.0 - zero_rel) * score[i]:
        return 0.0
    return float(grid[i])
