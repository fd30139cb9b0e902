"""The camera's frame-to-frame image shift (S2-PSK road scenes).

Road vibration turns the camera by a few tenths of a degree in pitch and yaw: with a 1200 px
focal length every far light jumps by up to ~6 px from one frame to the next, in both
directions, more than the 4-10 px between the two halves of a far street-light head. No track's
or pair's own velocity predicts that. `vertical_shift`: the pitch, the mode of the vertical
parts of the displacements between this frame's and the last frames' blob centroids (heads are
horizontal: whichever half is lit, its vertical part is the shift). `pair_dx`: the yaw, the
horizontal shift that best puts this frame's blobs where the S2-PSK pairs expect them.
Cost: one histogram of at most N x M displacements (N, M ~ 10-50 blobs).
"""

from __future__ import annotations

import numpy as np


def vertical_shift(prev_xy: np.ndarray, xy: np.ndarray, *, radius_px: float = 14.0, bin_px: float = 0.5,
                   refine_px: float = 1.0, min_votes: int = 3, extra: np.ndarray | None = None) -> float | None:
    """dy px, the common vertical image shift (pitch) alone: the mode of the vertical parts of
    the displacements within `radius_px`. Street-light heads are horizontal,
    so whichever half of a head is lit in either frame, its displacement's vertical part is the
    shift: every head votes right, unlike the horizontal part (ambiguous by the baseline)."""
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
    # a blob's best place is its nearest offset (the weight falls with the distance): one exp per
    # blob and grid point, of the smallest distance
    # (np.minimum column by column: a reduction over the short axis costs more)
    near = np.abs(grid[None, :] - off[:, :1])
    for j in range(1, off.shape[1]):
        np.minimum(near, np.abs(grid[None, :] - off[:, j:j + 1]), out=near)
    score = np.exp(-0.5 * (near / sigma_px) ** 2).sum(axis=0)
    i = int(np.argmax(score))
    if score[i] < min_score:
        return None
    if float(np.interp(0.0, grid, score)) >= (1.0 - zero_rel) * score[i]:
        return 0.0
    return float(grid[i])
