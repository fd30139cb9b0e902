"""Constant-velocity Kalman tracking of the camera position (thesis eqs. 35-39).

State ``x = [x, y, z, vx, vy, vz]`` (world metres and m/s, z up), covariance ``P`` (6, 6).
The motion model is a continuous white-noise acceleration of spectral density ``q``
(m^2/s^3, per axis): over dt the transition is ``F = [[I, dt I], [0, I]]`` and the process noise

    Q = q * [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]

(Bar-Shalom, "Estimation with Applications to Tracking", 6.2.2). A fix is a position measurement
``z = H x + v`` with ``H = [I 0]`` and ``v ~ N(0, R)``, R the fix's own covariance from the least
squares Jacobian, so nothing is tuned per scene except the documented acceleration density.

`PositionKalman` (the streaming stage, on filterpy's KalmanFilter) and the pure functions
`cv_predict` / `cv_update` (same maths on arrays) must agree; a test checks it.

filterpy is imported when a track first needs a prediction or an update, not at the first fix:
importing it runs its whole package, scipy.stats included (~1.5 s CPU here), and a single photo
only ever starts a track, whose state is the fix itself.
"""

from __future__ import annotations

import math

import numpy as np

# A walking person holding a phone: accelerations of about 1 m/s^2 that persist for ~0.5 s,
# i.e. q ~ sigma_a^2 * tau = 0.5 m^2/s^3 (white-noise-acceleration equivalent).
DEFAULT_ACCEL_PSD = 0.5
# Initial velocity uncertainty: walking speed, 1.5 m/s per axis.
DEFAULT_INIT_VEL_SIGMA = 1.5
# chi-square 3 dof, 99.9 %: a fix further than this (Mahalanobis^2) from the prediction is rejected.
DEFAULT_GATE_CHI2 = 16.27
# After this many consecutive rejected fixes the filter restarts from the fix.
DEFAULT_MAX_REJECTS = 3
# Coasting longer than this without a fix makes the filter forget the track.
DEFAULT_MAX_COAST_S = 2.0

H = np.hstack([np.eye(3), np.zeros((3, 3))])


def transition(dt: float) -> np.ndarray:
    """(6, 6) constant-velocity transition over dt seconds."""
    F = np.eye(6)
    F[:3, 3:] = dt * np.eye(3)
    return F


def process_noise(dt: float, q: float) -> np.ndarray:
    """(6, 6) process noise of white acceleration with spectral density q (m^2/s^3) over dt s."""
    I3 = np.eye(3)
    return q * np.block([[dt ** 3 / 3 * I3, dt ** 2 / 2 * I3], [dt ** 2 / 2 * I3, dt * I3]])


def cv_predict(x: np.ndarray, P: np.ndarray, dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Pure prediction (eqs. 35-36): returns (x (6,), P (6, 6)) after dt seconds."""
    F = transition(dt)
    return F @ x, F @ P @ F.T + process_noise(dt, q)


def cv_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pure measurement update (eqs. 37-39) with a position fix z (3,) of covariance R (3, 3).
    Joseph form, as filterpy uses, so P stays symmetric positive definite."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    x = x + K @ (z - H @ x)
    IKH = np.eye(6) - K @ H
    return x, IKH @ P @ IKH.T + K @ R @ K.T


def mahalanobis2(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray) -> float:
    """Squared Mahalanobis distance of fix z from the predicted position."""
    S = H @ P @ H.T + R
    r = z - H @ x
    return float(r @ np.linalg.solve(S, r))


class PositionKalman:
    """Streaming constant-velocity filter over position fixes.

    `accel_psd`: q above, m^2/s^3. `init_vel_sigma_mps`: initial velocity 1-sigma.
    `gate_chi2`: fixes with a larger Mahalanobis^2 are rejected as outliers (None: no gate);
    `max_rejects` consecutive rejections restart the filter from the newest fix.
    `max_coast_s`: coasting (predict-only) longer than this drops the track.

    ``step(t_s, z=None, R=None)`` returns the filtered (x (6,), P (6, 6)) or None when there is no
    track; without z it only predicts (the covariance grows).
    """

    def __init__(self, *, accel_psd: float = DEFAULT_ACCEL_PSD,
                 init_vel_sigma_mps: float = DEFAULT_INIT_VEL_SIGMA,
                 gate_chi2: float | None = DEFAULT_GATE_CHI2,
                 max_rejects: int = DEFAULT_MAX_REJECTS,
                 max_coast_s: float = DEFAULT_MAX_COAST_S):
        self.q = accel_psd
        self.init_vel_sigma = init_vel_sigma_mps
        self.gate_chi2 = gate_chi2
        self.max_rejects = max_rejects
        self.max_coast_s = max_coast_s
        self.kf = None  # filterpy KalmanFilter, made from `_init` when first needed
        self._init: tuple[np.ndarray, np.ndarray] | None = None  # (x (6,), P (6, 6)) of a new track
        self.t_s: float | None = None
        self.t_fix_s: float | None = None
        self.rejects = 0
        self.last_accepted = False

    def reset(self) -> None:
        self.kf, self._init, self.t_s, self.t_fix_s, self.rejects = None, None, None, None, 0

    @property
    def tracking(self) -> bool:
        return self.kf is not None or self._init is not None

    def _start(self, t_s: float, z: np.ndarray, R: np.ndarray) -> None:
        P = np.zeros((6, 6))
        P[:3, :3] = R
        P[3:, 3:] = self.init_vel_sigma ** 2 * np.eye(3)
        self.kf, self._init = None, (np.concatenate([z, np.zeros(3)]), P)
        self.t_s, self.t_fix_s, self.rejects = t_s, t_s, 0

    def _filter(self):
        """The filterpy filter of the current track, made from the track's start on first use."""
        if self.kf is None:
            from filterpy.kalman import KalmanFilter
            x, P = self._init
            kf = KalmanFilter(dim_x=6, dim_z=3)
            kf.x = x.reshape(6, 1)
            kf.P = P
            kf.H = H.copy()
            self.kf, self._init = kf, None
        return self.kf

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self.kf is not None:
            return self.kf.x.reshape(6).copy(), self.kf.P.copy()
        if self._init is not None:
            return self._init[0].copy(), self._init[1].copy()
        return None

    def predict_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The prediction (x (6,), P (6, 6)) at t_s without changing the filter; None without a
        track or when t_s is before the filter's time or beyond `max_coast_s` of coasting."""
        if not self.tracking or t_s < self.t_s or t_s - self.t_fix_s > self.max_coast_s:
            return None
        x, P = self.state
        return cv_predict(x, P, t_s - self.t_s, self.q)

    def step(self, t_s: float, z: np.ndarray | None = None, R: np.ndarray | None = None):
        self.last_accepted = False
        if not self.tracking:
            if z is None:
                return None
            self._start(t_s, np.asarray(z, float), np.asarray(R, float))
            self.last_accepted = True
            return self.state
        dt = t_s - self.t_s
        if dt < 0:
            # Time went backwards (new source, looped recording): start over.
            self.reset()
            return self.step(t_s, z, R)
        if dt > 0:
            kf = self._filter()
            kf.F = transition(dt)
            kf.Q = process_noise(dt, self.q)
            kf.predict()
            self.t_s = t_s
        if z is not None:
            z = np.asarray(z, float)
            R = np.asarray(R, float)
            x, P = self.state
            if self.gate_chi2 is not None and mahalanobis2(x, P, z, R) > self.gate_chi2:
                self.rejects += 1
                if self.rejects >= self.max_rejects:
                    self._start(t_s, z, R)
                    self.last_accepted = True
                    return self.state
            else:
                self._filter().update(z.reshape(3, 1), R=R)
                self.t_fix_s, self.rejects = t_s, 0
                self.last_accepted = True
        if self.t_fix_s is not None and t_s - self.t_fix_s > self.max_coast_s:
            self.reset()
            return None
        return self.state


def preload() -> None:
    """Import filterpy now (~1.5 s CPU: its package imports scipy.stats), so that a stream's
    second frame does not pay for it; a single photo never needs it (see the module doc)."""
    import filterpy.kalman  # noqa: F401


def position_std(P: np.ndarray) -> list[float]:
    """1-sigma of x, y, z from a (>=3, >=3) covariance."""
    return [math.sqrt(max(0.0, float(P[i, i]))) for i in range(3)]
