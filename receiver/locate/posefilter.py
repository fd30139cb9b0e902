"""One device's positioning state: solve a frame's fix (`receiver.locate.pose.solve_fix`) in the
map's frame or its mirror (map handedness), then the constant-velocity Kalman filter
(`receiver.locate.kalman`) that coasts between fixes. Used by the local indoor positioner and,
one per device, by the lighting server.
"""

from __future__ import annotations

import math

import numpy as np

import cv2

from receiver.locate import _position
from receiver.locate.kalman import DEFAULT_ACCEL_PSD, DEFAULT_MAX_COAST_S, PositionKalman
from receiver.locate.ranging import R_LOOKING_UP
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS
from receiver.locate.lsq import Fix
from receiver.locate.pose import (DEFAULT_TILT_SIGMA_DEG, SOLVERS, WarmProblem, _is_collinear_cached,
                                  solve_fix, solve_warm_batch, warm_problem)
from receiver.locate.pose import preload as preload_solvers


# Mirror of the world's y axis and of the camera's x axis (image columns reversed): a map drawn in
# a left-handed frame is solved in its mirror P = MIRROR_WORLD @ M, and the pose reported back in
# the map's frame as R = MIRROR_CAM @ R_P @ MIRROR_WORLD, the only way for it to stay a rotation.
MIRROR_WORLD = np.diag([1.0, -1.0, 1.0])
MIRROR_CAM = np.diag([-1.0, 1.0, 1.0])
# With the map's handedness unknown, a frame with this many non-collinear LEDs decides it: the
# cyclic order of 3+ LEDs seen from below differs between a map and its mirror.
HANDEDNESS_MIN_LEDS = 3
# ... when the fit in the chosen frame is this much better (chi^2 ratio) than in the other one,
# and good in itself: chi^2 per degree of freedom at most this (residuals within ~10 sigma RMS;
# the Luxapose photo's mirror fit has 22, the bundled walk's first decisive frame 6).
HANDEDNESS_CHI2_RATIO = 10.0
HANDEDNESS_MAX_CHI2_DOF = 100.0
# The camera's angular rate is taken from two orientations at most this far apart (s): a phone
# turns at tens of degrees per second, so over a few frames the rate is about constant.
RATE_MAX_GAP_S = 0.15
# A turn between two orientations faster than this (deg/s) is not the camera's: a hand swings a
# phone at up to a few hundred deg/s, while a lone symmetric panel's fits (a rect seen from
# below fits equally turned by 180 degrees) or a wrong branch jump by 90-180 degrees within a
# frame or two. Such a jump starts the orientation history afresh (`keep_orientation`): the
# angular rate across it would derotate the next frames' points by radians (`derotate_rows`).
MAX_TURN_RATE_DEG_S = 720.0


def _turn_rad(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """The angle (rad) of the rotation between two world-to-camera rotations."""
    c = (float(np.trace(np.asarray(Ra, float) @ np.asarray(Rb, float).T)) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))


def is_mirror_fit_better(good: Fix | None, other: Fix | None) -> bool:
    """True when `good` explains the frame (chi^2 per dof at most `HANDEDNESS_MAX_CHI2_DOF`) and
    `other` (the same data in the mirrored world) does not: no fix there (camera above the LEDs),
    or a chi^2 `HANDEDNESS_CHI2_RATIO` times worse."""
    if good is None or good.chi2 > HANDEDNESS_MAX_CHI2_DOF * max(good.dof, 1):
        return False
    if other is None:
        return True
    return other.chi2 > HANDEDNESS_CHI2_RATIO * max(good.chi2, float(good.dof), 1.0)


class PoseFilter:
    """One receiver's positioning state: per frame, the map positions, undistorted image points
    and ranges of its decoded LEDs -> a fix (`solve_fix`) -> the Kalman filter -> the INTERFACES.md
    `position` object. `Positioner` holds one; the lighting server holds one per device.

    The map's handedness (`LedMap.handedness`): "right" is solved as it is; "left" in its mirror
    (`MIRROR_WORLD`), with positions mapped back and the orientation reported against the mirrored
    camera (`MIRROR_CAM`, image x reversed) so that it is a rotation. A map that does not say is
    taken as right-handed until the first frame with `HANDEDNESS_MIN_LEDS` non-collinear LEDs,
    which is solved both ways: when only the mirror explains it (e.g. the Luxapose rig map, whose
    photo has no pose below the LEDs as surveyed), the map is left-handed for the rest of the run
    (`handedness`, "detected" in `handedness_source`), and the filter restarts in that frame.
    All state (filter, priors) lives in the solving frame.
    `warm_start`: a frame with 3+ LEDs off one line starts its solve from the orientation prior
    it is given (`R_prior`, the last fix's) and the filter's predicted position (else the last
    fix's centre) when both are recent
    (`receiver.locate.pose.solve_warm_batch`: a few solver iterations, no PnP); the lighting
    server's per-device filters use it. The same minimum within the solver's tolerance (on the
    bundled sparse walk's warm frames 0.1-0.15 um from the cold fix, with a lower chi^2).
    """

    def __init__(self, *, handedness: str | None = None, sigma_uv: float, solver: str = "auto",
                 kalman: bool = True, accel_psd: float = DEFAULT_ACCEL_PSD,
                 max_coast_s: float = DEFAULT_MAX_COAST_S, loss: str = DEFAULT_LOSS,
                 f_scale: float = DEFAULT_F_SCALE, tilt_prior: str = "up",
                 tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG, track_prior: bool = False,
                 warm_start: bool = False):
        if solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}")
        if handedness not in (None, "right", "left"):
            raise ValueError(f"unknown handedness {handedness!r}")
        self.handedness = handedness or "right"
        self.handedness_source = "map" if handedness else "default"
        self.sigma_uv, self.solver = sigma_uv, solver
        self.loss, self.f_scale = loss, f_scale
        self.max_coast_s = max_coast_s
        self.tilt_prior, self.tilt_sigma_deg, self.track_prior = tilt_prior, tilt_sigma_deg, track_prior
        self.warm_start = warm_start
        self._kalman_args = dict(accel_psd=accel_psd, max_coast_s=max_coast_s) if kalman else None
        self.n_fixes = 0
        # The last frame that could tell the map from its mirror told neither (both fits poor):
        # a frame without a fix then says "handedness undecided" (`Positioner.last_reason`).
        self.handedness_undecided = False
        self._restart()
        preload_solvers()      # before the first frame, not inside a cold-start frame's latency

    def _restart(self) -> None:
        self.kf = PositionKalman(**self._kalman_args) if self._kalman_args is not None else None
        self._R_cw: np.ndarray | None = None
        self._t_R: float | None = None
        self._C: np.ndarray | None = None
        self._t_C: float | None = None
        self._w_cam: np.ndarray | None = None
        self._R_hist: list = []     # (t_s, R_cw) of the fixes of the last RATE_MAX_GAP_S

    @property
    def mirrored(self) -> bool:
        return self.handedness == "left"

    def to_solving(self, L_map: np.ndarray) -> np.ndarray:
        """(N, 3) map-frame points -> the solving frame."""
        L = np.asarray(L_map, float).reshape(-1, 3)
        return L @ MIRROR_WORLD if self.mirrored else L

    def R_prior(self, t_s: float) -> np.ndarray | None:
        """World-to-camera rotation (solving frame) of the last fix, if recent enough."""
        if self._t_R is not None and 0 <= t_s - self._t_R <= self.max_coast_s:
            return self._R_cw
        return None

    def orientation_age_s(self, t_s: float) -> float | None:
        """Seconds from the orientation `R_prior` gives to t_s, or None without one."""
        return None if self._t_R is None else t_s - self._t_R

    def keep_orientation(self, t_s: float, R_cw: np.ndarray) -> None:
        """Remember a fix's world-to-camera rotation (solving frame) of time t_s for `R_prior`,
        and the angular rate over the orientations of the last `RATE_MAX_GAP_S` (`angular_rate`)."""
        if self._t_R is not None and not 0 <= t_s - self._t_R <= RATE_MAX_GAP_S:
            self._R_hist = []
        elif self._R_hist and _turn_rad(R_cw, self._R_cw) > math.radians(MAX_TURN_RATE_DEG_S) * max(t_s - self._t_R, 1e-3):
            self._R_hist = []
        self._R_hist = [(t, R) for t, R in self._R_hist if t_s - t <= RATE_MAX_GAP_S] + [(t_s, R_cw)]
        t0, R0 = self._R_hist[0]
        if t_s - t0 > 0:
            # X_cam(t) = R_cw(t) (X - C): R_new R_old^T = Exp(dt w), w in the camera frame. The
            # oldest orientation in the window: the longest baseline, the least noise per rad/s.
            self._w_cam = cv2.Rodrigues(np.asarray(R_cw, float) @ np.asarray(R0, float).T)[0].ravel() / (t_s - t0)
        else:
            self._w_cam = None
        self._R_cw, self._t_R = R_cw, t_s

    def angular_rate(self, t_s: float) -> np.ndarray | None:
        """The camera's angular rate (rad/s, camera frame: a fixed world point's camera
        coordinates turn as X' = Exp(dt w) X) from the recent orientations, while recent
        (`RATE_MAX_GAP_S` after the last), else None."""
        if self._w_cam is not None and 0 <= t_s - self._t_R <= RATE_MAX_GAP_S:
            return self._w_cam
        return None

    def _kw(self) -> dict:
        return dict(sigma_uv=self.sigma_uv, solver=self.solver, tilt_sigma_deg=self.tilt_sigma_deg,
                    tilt_prior_R=R_LOOKING_UP if self.tilt_prior == "up" else None)

    def warm_problem(self, t_s: float, L_map: np.ndarray, uv: np.ndarray | None, d: np.ndarray,
                     sigma_d: np.ndarray, R_prior: np.ndarray | None = None) -> WarmProblem | None:
        """The warm-started refinement `solve` would run for this frame (`warm_start`: the
        orientation prior and the filter's predicted position, else the last fix's centre), or
        None where it solves the frame from scratch."""
        if not self.warm_start or R_prior is None or self.handedness_source == "default" or self.track_prior:
            return None     # the warm refinement has no rows for the tracked-position prior
        C0 = self.kf.predict_position(t_s) if self.kf is not None else None
        if C0 is None and self._t_C is not None and 0 <= t_s - self._t_C <= self.max_coast_s:
            C0 = self._C
        if C0 is None:
            return None
        L = self.to_solving(L_map)
        return warm_problem(L, uv, d, sigma_d, R_prior, C0, **self._kw())

    def solve(self, t_s: float, L_map: np.ndarray, uv: np.ndarray | None, d: np.ndarray,
              sigma_d: np.ndarray, R_prior: np.ndarray | None = None) -> Fix | None:
        """One frame's fix in the solving frame (no state change except the handedness decision).
        L_map (N, 3) map m; uv (N, 2) undistorted normalized image points or None; d, sigma_d (N,)
        ranges and their 1-sigma, m (NaN where unknown). R_prior: solving-frame orientation guess."""
        return solve_batch([(self, t_s, L_map, uv, d, sigma_d, R_prior)])[0]

    def solve_cold(self, t_s: float, L_map: np.ndarray, uv: np.ndarray | None, d: np.ndarray,
                   sigma_d: np.ndarray, R_prior: np.ndarray | None = None) -> Fix | None:
        """`solve` without the warm start (`solve_fix` from scratch)."""
        pred = None if self.kf is None or not self.track_prior else self.kf.predict_at(t_s)
        if pred is not None:
            C_prior, C_prior_cov = pred[0][:3], pred[1][:3, :3]
        else:
            recent = self._t_C is not None and 0 <= t_s - self._t_C <= self.max_coast_s
            C_prior, C_prior_cov = (self._C if recent else None), None
        kw = dict(self._kw(), loss=self.loss, f_scale=self.f_scale)
        L_map = np.asarray(L_map, float).reshape(-1, 3)
        fix = solve_fix(self.to_solving(L_map), uv, d, sigma_d, R_prior=R_prior, C_prior=C_prior,
                        C_prior_cov=C_prior_cov, **kw)
        if (self.handedness_source == "default" and uv is not None and self.solver != "multilateration"
                and len(L_map) >= HANDEDNESS_MIN_LEDS and not _is_collinear_cached(L_map.tobytes())):
            # Undecided map: this frame can tell the map from its mirror.
            other = "left" if self.handedness == "right" else "right"
            L_other = L_map @ MIRROR_WORLD if other == "left" else L_map
            fix_other = solve_fix(L_other, uv, d, sigma_d, **kw)
            self.handedness_undecided = True
            if is_mirror_fit_better(fix_other, fix):
                self.handedness, self.handedness_source = other, "detected"
                self.handedness_undecided = False
                self._restart()
                return fix_other
            if is_mirror_fit_better(fix, fix_other):
                self.handedness_source = "detected"
                self.handedness_undecided = False
        return fix

    def _step(self, t_s: float, fix: Fix | None):
        """One frame's fix (or None) into the filter: its state (x (6,), P (6, 6)) or None."""
        if fix is not None:
            self.n_fixes += 1
            self._C, self._t_C = fix.C, t_s
            if fix.R_cw is not None:
                self.keep_orientation(t_s, fix.R_cw)
        if self.kf is None:
            return None
        return self.kf.step(t_s, None if fix is None else fix.C, None if fix is None else fix.cov)

    def _position_args(self, state, fix: Fix | None, n_leds: int) -> tuple:
        """The arguments of receiver/locate/_position.pyx's `position` (and `position_json`): the
        filter state and the fix in the map's frame (a left-handed map's mirrored back: sign
        flips, exact), the fix's method ("kalman-coast" without one), the LED count and the
        handedness (None while undecided)."""
        x, P = (None, None) if state is None else state
        C, cov, R = (None, None, None) if fix is None else (fix.C, fix.cov, fix.R_cw)
        if self.mirrored:
            if x is not None:
                x = np.concatenate([MIRROR_WORLD @ x[:3], MIRROR_WORLD @ x[3:]])
                P = P.copy()
                P[:3, :3] = MIRROR_WORLD @ P[:3, :3] @ MIRROR_WORLD
            if C is not None:
                C = MIRROR_WORLD @ C
            if R is not None:
                R = MIRROR_CAM @ R @ MIRROR_WORLD
        return (x, P, C, cov, R, "kalman-coast" if fix is None else fix.method, n_leds,
                None if self.handedness_source == "default" else self.handedness)

    def update(self, t_s: float, fix: Fix | None, n_leds: int) -> dict | None:
        """Feed one frame's fix (or None) to the filter; the INTERFACES.md `position` object
        (map frame) or None. Its numbers: position, raw fix and their 1-sigma to 5 decimals (m),
        covariance to 8, velocity to 4 (m/s), R_wc (camera-to-world, columns = camera axes) to
        6, yaw / pitch / roll (`receiver.locate.pose.rotation_to_ypr_deg`) to 3 (deg)."""
        state = self._step(t_s, fix)
        if fix is None and state is None:
            return None
        return _position.position(*self._position_args(state, fix, n_leds))


def solve_batch(frames) -> list[Fix | None]:
    """`PoseFilter.solve` of many frames, each (pose_filter, t_s, L_map, uv, d, sigma_d, R_prior),
    at most one per filter: the warm-started ones (`PoseFilter.warm_problem`) in one batched
    solve per loss setting (`receiver.locate.pose.solve_warm_batch`), the others -- and any warm
    fix that does not explain its frame -- from scratch (`PoseFilter.solve_cold`)."""
    fixes: list[Fix | None] = [None] * len(frames)
    groups: dict[tuple, list[tuple[int, WarmProblem]]] = {}
    cold = []
    for i, (pf, *args) in enumerate(frames):
        q = pf.warm_problem(*args)
        if q is None:
            cold.append(i)
        else:
            groups.setdefault((pf.loss, pf.f_scale), []).append((i, q))
    for (loss, f_scale), items in groups.items():
        for (i, _), fix in zip(items, solve_warm_batch([q for _, q in items], loss=loss, f_scale=f_scale)):
            if fix is None:
                cold.append(i)
            else:
                fixes[i] = fix
    for i in sorted(cold):
        pf, *args = frames[i]
        fixes[i] = pf.solve_cold(*args)
    return fixes
