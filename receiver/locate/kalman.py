"""Constant-velocity Kalman tracking of the camera position (thesis eqs. 35-39).

State ``x = [x, y, z, vx, vy, vz]`` (world metres and m/s, z up), covariance ``P`` (6, 6).
The motion model is a continuous white-noise acceleration of spectral density ``q``
(m^2/s^3, per axis): over dt the transition is ``F = [[I, dt I], [0, I]]`` and the process noise

    Q = q * [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]

(Bar-Shalom, "Estimation with Applications to Tracking", 6.2.2). A fix is a position measurement
``z = H x + v`` with ``H = [I 0]`` and ``v ~ N(0, R)``, R the fix's own covariance from the least
squares Jacobian, so nothing is tuned per scene except the documented acceleration density.

`PositionKalman` runs filterpy's `KalmanFilter` predict / update equations (Joseph form) as the
compiled steps of receiver/locate/_kalman.pyx on plain arrays, without filterpy's per-call
bookkeeping (deep copies, prior / posterior snapshots); its states equal filterpy's to rounding
(tests/locate/test_kalman.py runs both side by side).

filterpy is the tests' reference only: the receiver never imports it (its package imports
scipy.stats, ~1.5 s of CPU).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.locate import _kalman

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
        self._x: np.ndarray | None = None   # (6, 1) state of the current track (filterpy's shape)
        self._P: np.ndarray | None = None   # (6, 6) its covariance
        self.t_s: float | None = None
        self.t_fix_s: float | None = None
        self.rejects = 0
        self.last_accepted = False

    def reset(self) -> None:
        self._x, self._P, self.t_s, self.t_fix_s, self.rejects = None, None, None, None, 0

    @property
    def tracking(self) -> bool:
        return self._x is not None

    def _start(self, t_s: float, z: np.ndarray, R: np.ndarray) -> None:
        P = np.zeros((6, 6))
        P[:3, :3] = R
        P[3:, 3:] = self.init_vel_sigma ** 2 * np.eye(3)
        self._x, self._P = np.concatenate([z, np.zeros(3)]).reshape(6, 1), P
        self.t_s, self.t_fix_s, self.rejects = t_s, t_s, 0

    def _predict(self, dt: float) -> None:
        """x = F x, P = F P F' + Q over dt (eqs. 35-36), in place."""
        _kalman.predict(self._x, self._P, dt, self.q)

    def _update(self, z: np.ndarray, R: np.ndarray) -> None:
        """The fix z of covariance R (eqs. 37-39, Joseph form, H = [I 0]), in place."""
        if not _kalman.update(self._x, self._P, z, R):
            raise np.linalg.LinAlgError("singular innovation covariance")

    def _mahalanobis2(self, z: np.ndarray, R: np.ndarray) -> float:
        """Squared Mahalanobis distance of fix z from the current (predicted) position: r' S^-1 r
        with S = H P H' + R = P[:3, :3] + R and r = z - x[:3]."""
        m2 = _kalman.mahalanobis2(self._x, self._P, z, R)
        if math.isnan(m2):
            raise np.linalg.LinAlgError("singular innovation covariance")
        return m2

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self._x is None:
            return None
        return self._x.reshape(6).copy(), self._P.copy()

    def predict_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The prediction (x (6,), P (6, 6)) at t_s without changing the filter; None without a
        track or when t_s is before the filter's time or beyond `max_coast_s` of coasting."""
        if self._no_prediction(t_s):
            return None
        return self._predicted(t_s - self.t_s)

    def _no_prediction(self, t_s: float) -> bool:
        """No prediction at t_s: no track, t_s before the filter's time, or coasting beyond
        `max_coast_s`."""
        return not self.tracking or t_s < self.t_s or t_s - self.t_fix_s > self.max_coast_s

    def _predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(x (6,), P (6, 6)) predicted dt s ahead, the filter unchanged."""
        x, P = self._x.copy(), self._P.copy()
        _kalman.predict(x, P, dt, self.q)
        return x.reshape(6), P

    def predict_position(self, t_s: float) -> np.ndarray | None:
        """The predicted position (3,) at t_s (x + v dt, no covariance: a solver's starting
        point); None where `predict_at` is None."""
        if self._no_prediction(t_s):
            return None
        x = self._x.reshape(6)
        return x[:3] + (t_s - self.t_s) * x[3:]

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
            self._predict(dt)
            self.t_s = t_s
        if z is not None:
            z = np.asarray(z, float)
            R = np.asarray(R, float)
            if self.gate_chi2 is not None and self._mahalanobis2(z, R) > self.gate_chi2:
                self.rejects += 1
                if self.rejects >= self.max_rejects:
                    self._start(t_s, z, R)
                    self.last_accepted = True
                    return self.state
            else:
                self._update(z, R)
                self.t_fix_s, self.rejects = t_s, 0
                self.last_accepted = True
        if self.t_fix_s is not None and t_s - self.t_fix_s > self.max_coast_s:
            self.reset()
            return None
        return self.state

