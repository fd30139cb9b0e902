"""Where the map's lights should appear in the next frame, from the tracked pose: the geometric
prior that lets the decoder test a light still without its ID against the one or few map IDs
that can be there (receiver.decode.pieces, `PieceAssembler.decide`'s `near`).

The positioner (`Positioner.map_prior`) predicts the pose at the frame's time stamp (the filter's
position and its covariance, the last fix's orientation turned on by the tracked angular rate),
projects every map light with the camera model and records each one's pixel position and a
pixel sigma (`MapPrior`). `near_ids` then gives the IDs whose predicted position lies within the
gate of a blob's centroid. The gate only says which IDs are worth testing: an ID is still
decided by the light's own chips against those IDs, so a wrong or loose prior makes the decision
slower, never wrong (see `receiver.decode.pieces`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

# A pose from the last fix is turned on by the tracked rate; what that leaves unknown is how the
# rate changed since: a hand-held phone turns at 10-30 deg/s, so up to TURN_SIGMA_DEG_S times the
# orientation's age, plus the fix's own orientation error (ORIENT_SIGMA_DEG, about a degree with
# one or two panels in view).
TURN_SIGMA_DEG_S = 30.0
ORIENT_SIGMA_DEG = 1.0
# Gate: squared Mahalanobis distance of a chi^2 of two degrees of freedom with a miss
# probability of 1e-4 (-2 ln 1e-4); a light outside its own gate only goes without the prior.
GATE_CHI2 = -2.0 * math.log(1e-4)


@dataclass(frozen=True)
class MapPrior:
    """The map's lights as predicted in one frame: `t_s` the frame's time stamp, `ids` (K,) the
    map IDs in front of the camera, `px` (K, 2) their predicted centres in image pixels (with the
    lens distortion, where detection sees them), `sigma_px` (K,) the isotropic pixel sigma of
    each prediction (pose covariance, orientation, and the panel's half size: a blob cut by the
    image border or still showing part of its panel has its centroid off the centre; the
    position's share is bounded by the covariance's largest eigenvalue)."""

    t_s: float
    ids: np.ndarray
    px: np.ndarray
    sigma_px: np.ndarray


def predict(camera, ids: np.ndarray, L: np.ndarray, half_m: np.ndarray, R_cw: np.ndarray, C: np.ndarray,
            C_cov: np.ndarray, orient_sigma_rad: float, t_s: float) -> MapPrior | None:
    """`MapPrior` of the lights `ids` at solving-frame positions `L` (K, 3), half sizes `half_m`
    (K,) m, for a camera at `C` (covariance `C_cov` (3, 3)) turned `R_cw` (world to camera)
    with an orientation sigma of `orient_sigma_rad`."""
    P = (np.asarray(L, float) - C) @ np.asarray(R_cw, float).T  # camera coordinates (K, 3)
    front = P[:, 2] > 1e-6
    if not front.any():
        return None
    P, ids, half_m = P[front], np.asarray(ids)[front], np.asarray(half_m, float)[front]
    z = P[:, 2]
    uv = P[:, :2] / z[:, None]
    r2 = np.einsum("ij,ij->i", uv, uv)
    # d uv / d C = -(1/z) [I2 | -uv] R, whose largest singular value is sqrt(1 + |uv|^2) / z: the
    # position's share is at most the covariance's largest eigenvalue times its square
    pos_var = float(np.linalg.eigvalsh(np.asarray(C_cov, float))[-1]) * (1.0 + r2) / (z * z)
    var = pos_var + (orient_sigma_rad * (1.0 + r2)) ** 2 + (half_m / z) ** 2  # normalized units
    px = cv2.projectPoints(np.column_stack([uv, np.ones(len(z))]), np.zeros(3), np.zeros(3), camera.K,
                           camera.dist)[0].reshape(-1, 2)
    sigma = np.sqrt(var) * camera.focal_px
    ok = np.isfinite(px).all(axis=1)
    return MapPrior(float(t_s), ids[ok], px[ok], sigma[ok])


def orient_sigma_rad(age_s: float) -> float:
    """The orientation sigma of a pose `age_s` seconds after its fix."""
    return math.radians(ORIENT_SIGMA_DEG + TURN_SIGMA_DEG_S * max(age_s, 0.0))


def near_ids(prior: MapPrior | None, cx: float, cy: float) -> tuple[int, ...]:
    """The map IDs whose predicted position lies within the gate (`GATE_CHI2`) of pixel (cx, cy),
    nearest first; () without a prior."""
    if prior is None or not len(prior.ids):
        return ()
    d2 = ((prior.px[:, 0] - cx) ** 2 + (prior.px[:, 1] - cy) ** 2) / (prior.sigma_px ** 2)
    hit = np.flatnonzero(d2 <= GATE_CHI2)
    return tuple(int(v) for v in prior.ids[hit[np.argsort(d2[hit], kind="stable")]])
