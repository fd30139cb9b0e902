"""One camera-motion estimate per frame, from all blobs, independent of any pairing.

A dash camera shakes: yaw and pitch of a few tenths of a degree as slow correlated swings
(0.5-2.5 Hz) plus frame-to-frame jitter, and some roll. With a 1200-1500 px focal length every
far light moves by several px from one frame to the next, more than the gap between the two
emitters of a far head. That motion is common to the whole image, so it is measured on all of
the frame's blobs at once, never from where the pairs expect their blobs (a wrong pair would
then make a wrong shift, and the wrong shift keep the pair wrong).

`CameraMotion.step` registers this frame's blob centroids on those of the last
`MotionSettings.history_frames` frames (a blinking emitter dark in the previous frame is found
in an older one, moved by the motion since):

1. votes: every displacement between a blob of this frame and a blob of an earlier frame within
   `radius_px`. The true motion gets a vote from every light lit in both frames; a wrong
   match (the other emitter of a head, another light) scatters by the baselines, which differ
   from light to light. The vote mode is the translation; a half vote at the motion model's
   prediction settles a tie (one head alone, its halves in turn).
2. matches: per blob, its displacement nearest the mode, within `match_px`, and only between
   blobs of like area (a head with one emitter lit is not matched on itself with both lit, which
   would vote for half its baseline); then the translation by RANSAC
   (cv2.estimateTranslation2D) and the roll about the matches' mean place by least squares,
   kept when significant. Lights near the host, which the forward motion moves faster than the
   shake, do not vote for the mode and are left out; their own motion is their track's velocity
   (receiver.vision.track). No scale is fitted for the same reason: the forward motion is not
   the camera's turn.
3. smoothing: the translation at the principal point is one measurement of a Kalman filter
   (filterpy) whose state is the per-frame shift, a random walk of `process_px` per frame (the
   shake is a sum of slow swings: one frame's shift is the best guess of the next; the jitter
   is the walk's step). Without enough matches (every blob dark, fewer than `min_matches`),
   the filter's prediction stands and its uncertainty grows by `process_px` per frame.

`MotionEstimate.var_sum_px2` accumulates each frame's variance: the uncertainty of the summed
shifts over the frames a track or pair was dark is the square root of the difference between
its values at the two frames (`CameraMotion.sigma_since`), which is what a gate should widen by
instead of a fixed pixel per dark frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class MotionSettings:
    """The camera-motion estimate's knobs.

    radius_px [14 px]: the largest frame-to-frame image shift searched (0.5 degrees of shake at a
        1500 px focal length).
    match_px [1.5 px]: how far from the common motion a blob may be and still count as matched
        (blur and centroid noise of a far half, about 0.5 px, plus the roll and forward motion
        left between blobs).
    history_frames [3 frames]: earlier frames with blobs that this frame's are registered on (an
        S2-PSK emitter is dark for runs of up to three frames).
    max_area_ratio [1.6]: a blob matches an earlier one only if their areas (each plus
        `area_slack_px2`) differ by less than this factor: a head seen with one emitter lit is
        not matched on the same head with both lit, a blob of about twice the area (which would
        vote for a shift of half the head's baseline).
    area_slack_px2 [2 px^2]: added to both areas before the ratio (a far half of 1-3 px^2 varies
        by a pixel from frame to frame).
    min_matches [3 blobs]: fewer matched blobs than this is no measurement (one head alone is
        ambiguous by its baseline).
    process_px [1.5 px]: 1-sigma change of the per-frame shift from one frame to the next (the
        jitter of about 0.05 degrees plus the swings' curvature at a 1500 px focal length).
    prior_votes [0.5 blobs]: what the motion model's prediction weighs in the vote, as this many
        blobs at the predicted shift spread by its uncertainty (settles ties, never outvotes a
        blob).
    measure_floor_px [0.3 px]: the smallest 1-sigma error of a measured shift (the blobs' centroid
        noise, shared by every blob of a compressed frame).
    max_roll_deg [0.5 degrees]: a fitted frame-to-frame roll beyond this is not camera motion (a
        fit on matches bunched in one place): the translation alone is kept.
    """

    radius_px: float = 14.0
    match_px: float = 1.5
    history_frames: int = 3
    max_area_ratio: float = 1.6
    area_slack_px2: float = 2.0
    min_matches: int = 3
    process_px: float = 1.5
    measure_floor_px: float = 0.3
    prior_votes: float = 0.5
    max_roll_deg: float = 0.5

    def __post_init__(self):
        # a count of frames or blobs below one has no meaning (zero would act as one)
        for name in ("history_frames", "min_matches"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"{name} must be at least 1, not {getattr(self, name)!r}")


@dataclass(frozen=True)
class MotionEstimate:
    """The camera's image motion from the previous frame to this one.

    A point at p in the previous frame is at c + R(roll_rad) (p - c) + (dx_px, dy_px) in this
    one, c = `center_px` (the principal point): (dx_px, dy_px) is the shift of the image centre
    (yaw and pitch), `roll_rad` the turn about it (+: from the x axis toward the y axis, image
    coordinates). `sigma_px`: 1-sigma error of (dx_px, dy_px) per axis; `var_sum_px2`: the sum
    of every frame's sigma_px^2 so far (see `CameraMotion.sigma_since`); `matches`: blobs
    registered this frame (0: the motion model's prediction alone)."""

    dx_px: float
    dy_px: float
    roll_rad: float
    sigma_px: float
    var_sum_px2: float
    matches: int
    center_px: tuple[float, float]

    @property
    def measured(self) -> bool:
        return self.matches > 0

    def at(self, x: float, y: float) -> tuple[float, float]:
        """The image displacement (px) of a point at (x, y) of the previous frame."""
        cx, cy = self.center_px
        u, v = x - cx, y - cy
        c, s = math.cos(self.roll_rad), math.sin(self.roll_rad)
        return (c * u - s * v - u + self.dx_px, s * u + c * v - v + self.dy_px)

    def apply(self, xy: np.ndarray) -> np.ndarray:
        """(K, 2) points of the previous frame moved into this frame's view."""
        cx, cy = self.center_px
        c, s = math.cos(self.roll_rad), math.sin(self.roll_rad)
        u, v = xy[:, 0] - cx, xy[:, 1] - cy
        return np.stack((cx + c * u - s * v + self.dx_px, cy + s * u + c * v + self.dy_px), axis=1)


def _kalman(s: MotionSettings):
    """State (dx, dy): the per-frame shift, a random walk of `process_px` per frame (a slow
    swing's shift of one frame is the next frame's best guess; the jitter is the walk's step)."""
    from filterpy.kalman import KalmanFilter  # only runs with shake="motion": a photo never imports filterpy
    kf = KalmanFilter(dim_x=2, dim_z=2)
    kf.F = np.eye(2)
    kf.H = np.eye(2)
    kf.Q = np.eye(2) * s.process_px ** 2
    kf.x = np.zeros((2, 1))
    # at rest until the first measurement: the shift is within the search radius
    kf.P = np.eye(2) * s.radius_px ** 2 / 4
    return kf


class CameraMotion:
    """The per-frame camera-motion estimate (see the module docstring): `step(xy)` once per frame
    with the frame's blob centroids."""

    def __init__(self, center_px: tuple[float, float], settings: MotionSettings = MotionSettings()):
        self.settings = settings
        self.center_px = (float(center_px[0]), float(center_px[1]))
        self.kf = _kalman(settings)
        # the last frames' (centroids, areas), each already moved into the latest frame's view
        self._history: list[tuple[np.ndarray, np.ndarray]] = []
        self.var_sum_px2 = 0.0
        self.frames = 0

    def sigma_since(self, var_sum_then_px2: float) -> float:
        """1-sigma error (px per axis) of the shifts summed since the frame whose estimate had
        `var_sum_px2` = `var_sum_then_px2` (a track's last sighting) up to the latest frame."""
        return math.sqrt(max(self.var_sum_px2 - var_sum_then_px2, 0.0))

    def step(self, xy: np.ndarray, area_px: np.ndarray | None = None) -> MotionEstimate:
        """This frame's estimate from its (N, 2) blob centroids (px) and, when given, their (N,)
        areas (px^2; only blobs of like size are matched; NaN: a blob matched whatever its
        area)."""
        s = self.settings
        xy = np.asarray(xy, float).reshape(-1, 2)
        area = (np.ones(len(xy)) if area_px is None else np.asarray(area_px, float).reshape(-1))
        kf = self.kf
        kf.predict()
        pred = (float(kf.x[0, 0]), float(kf.x[1, 0]))
        fit = self._register(xy, area, pred, self._history) if self._history else None
        roll, n = 0.0, 0
        if fit is not None:
            (tx, ty), roll, n, rms = fit
            r = max(rms / math.sqrt(n), s.measure_floor_px)
            kf.update(np.array([[tx], [ty]]), R=np.eye(2) * r * r)
        sigma = math.sqrt(max(kf.P[0, 0], kf.P[1, 1]))
        self.var_sum_px2 += sigma * sigma
        est = MotionEstimate(dx_px=float(kf.x[0, 0]), dy_px=float(kf.x[1, 0]), roll_rad=roll,
                             sigma_px=sigma, var_sum_px2=self.var_sum_px2, matches=n, center_px=self.center_px)
        moved = [(est.apply(old), a) for old, a in self._history]
        # a frame without blobs adds nothing to register on: the lit frames before it stay
        self._history = ([(xy, area)] + moved[:s.history_frames - 1]) if len(xy) else moved
        self.frames += 1
        return est

    # -- registration ----------------------------------------------------------------------

    def _register(self, xy: np.ndarray, area: np.ndarray, pred: tuple[float, float], history: list):
        """((tx, ty) at the principal point, roll rad, matches, residual rms px) of this
        frame's blobs on the history, or None when fewer than `min_matches` blobs match."""
        s = self.settings
        r = s.radius_px
        if len(xy) == 0:
            return None
        # every displacement within the radius, to each earlier frame (blob index kept)
        cand_d, cand_src, cand_j = [], [], []
        slack = s.area_slack_px2
        for old, old_area in history:
            d = xy[:, None, :] - old[None, :, :]
            big = np.fmax(area[:, None], old_area[None, :]) + slack
            small = np.fmin(area[:, None], old_area[None, :]) + slack
            like = (big <= s.max_area_ratio * small) | np.isnan(area)[:, None] | np.isnan(old_area)[None, :]
            ok = (np.abs(d[..., 0]) <= r) & (np.abs(d[..., 1]) <= r) & like
            j, i = np.nonzero(ok)
            cand_d.append(d[j, i])
            cand_src.append(old[i])
            cand_j.append(j)
        if not cand_d:
            return None
        d = np.concatenate(cand_d)
        src = np.concatenate(cand_src)
        jj = np.concatenate(cand_j)
        if len(d) < s.min_matches:
            return None
        peak = self._mode(d, jj, pred)
        # per blob of this frame, its displacement nearest the mode (within match_px)
        err = np.hypot(d[:, 0] - peak[0], d[:, 1] - peak[1])
        order = np.lexsort((err, jj))
        first = np.ones(len(order), bool)
        first[1:] = jj[order][1:] != jj[order][:-1]
        best = order[first]
        best = best[err[best] <= s.match_px]
        n = len(best)
        if n < s.min_matches:
            return None
        p0, p1 = src[best], xy[jj[best]]
        # the translation by RANSAC (a blob matched to another light's blob is an outlier)
        t, inl = cv2.estimateTranslation2D(p0.astype(np.float32), p1.astype(np.float32), method=cv2.RANSAC,
                                           ransacReprojThreshold=s.match_px)
        if t is None or inl is None or int(inl.sum()) < s.min_matches:
            return None
        keep = inl.ravel().astype(bool)
        p0, p1 = p0[keep], p1[keep]
        n = len(p0)
        # the roll about the matches' mean place m, by least squares on what the translation
        # leaves, kept when it is over twice its standard error (else the noise of a few
        # bunched blobs would turn into a shift far from them)
        m = p0.mean(axis=0)
        u = p0 - m
        res = (p1 - p0) - (p1 - p0).mean(axis=0)
        uu = float(np.sum(u * u))
        roll = float(np.sum(u[:, 0] * res[:, 1] - u[:, 1] * res[:, 0]) / uu) if uu > 0 else 0.0
        rot = roll * np.column_stack((-u[:, 1], u[:, 0]))
        rms = float(np.sqrt(np.sum((res - rot) ** 2) / max(2 * n - 3, 1)))
        if uu <= 0 or abs(roll) <= 2.0 * rms / math.sqrt(uu) or abs(math.degrees(roll)) > s.max_roll_deg:
            roll, rot = 0.0, 0.0 * rot
            rms = float(np.sqrt(np.sum(res ** 2) / max(2 * n - 2, 1)))
        # the translation at m, moved to the principal point c by the roll
        tm = (p1 - p0).mean(axis=0)
        c = np.array(self.center_px)
        t_c = tm - roll * np.array((-(m[1] - c[1]), m[0] - c[0]))
        return (float(t_c[0]), float(t_c[1])), roll, n, rms

    def _mode(self, d: np.ndarray, jj: np.ndarray, pred: tuple[float, float]) -> tuple[float, float]:
        """The displacement most blobs agree on: a 2-D histogram of `d` (each blob of this frame
        one vote, shared by the bins of its displacements), smoothed over `match_px`, plus
        `prior_votes` at the prediction."""
        s = self.settings
        step = 0.5
        nb = int(math.ceil(s.radius_px / step))
        ix = np.clip(np.floor(d[:, 0] / step + 0.5).astype(np.int64) + nb, 0, 2 * nb)
        iy = np.clip(np.floor(d[:, 1] / step + 0.5).astype(np.int64) + nb, 0, 2 * nb)
        side = 2 * nb + 1
        key = np.unique(jj * side * side + iy * side + ix)
        blob, cell = key // (side * side), key % (side * side)
        # a blob's one vote shared among the places it may have come from: a lone light votes
        # whole, a far head in a row of like heads (any of which it might be) little
        share = 1.0 / np.bincount(blob)[blob]
        h = np.bincount(cell, weights=share, minlength=side * side).reshape(side, side)
        w = max(1, int(round(s.match_px / step)))
        sm = cv2.boxFilter(h, -1, (2 * w + 1, 2 * w + 1), normalize=False, borderType=cv2.BORDER_CONSTANT)
        g = (np.arange(side) - nb) * step
        sig = max(math.sqrt(max(self.kf.P[0, 0], self.kf.P[1, 1])), s.match_px)
        sm += s.prior_votes * np.exp(-0.5 * (((g[None, :] - pred[0]) ** 2 + (g[:, None] - pred[1]) ** 2) / sig ** 2))
        iy0, ix0 = np.unravel_index(int(np.argmax(sm)), sm.shape)
        gx, gy = g[ix0], g[iy0]
        near = d[np.hypot(d[:, 0] - gx, d[:, 1] - gy) <= s.match_px]
        if len(near):
            return float(np.median(near[:, 0])), float(np.median(near[:, 1]))
        return float(gx), float(gy)
