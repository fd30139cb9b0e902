"""Road-frame tracking of the host vehicle (HV): an extended Kalman filter on a
constant-velocity / constant-turn-rate model, and a 1-D constant-velocity filter for the
distance to a forward vehicle.

Road (map) frame: metres, x along the road, y to the left, z up; heading psi in radians from
+x towards +y (counter-clockwise seen from above).

`RoadKalman` state ``s = [x, y, psi, v, omega]`` (m, m, rad, m/s, rad/s). Prediction over dt
(first order in dt, exact when omega = 0)::

    x += v cos(psi) dt,  y += v sin(psi) dt,  psi += omega dt

with white-noise longitudinal acceleration (spectral density `accel_psd`, m^2/s^3) driving v and
white yaw acceleration (`yaw_accel_psd`, rad^2/s^3) driving omega; their effect on position and
heading over the step is included through the integrated noise gain. Measurements:
position (x, y) with its 2x2 covariance (a street-light fix), heading psi (the camera's yaw
from the pose, assumed mounted straight ahead), and speed v (odometry, thesis eq. 48's V_HV).
The heading innovation is wrapped to (-pi, pi].

`RangeKalman`: state ``[d, d_dot]`` with white acceleration noise; d_dot is the range rate
(negative = closing).
"""

from __future__ import annotations

import math

import numpy as np

_H_SPEED = np.array([[0.0, 0.0, 0.0, 1.0, 0.0]])      # the speed's measurement row (`update_speed`)


def wrap_pi(a: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    return -((-a + math.pi) % (2 * math.pi) - math.pi)


class RoadKalman:
    """EKF of the HV in the road frame (module doc). `None` state until the first fix."""

    def __init__(self, *, accel_psd: float, yaw_accel_psd: float, init_speed_sigma: float,
                 init_omega_sigma: float, gate_chi2: float, max_rejects: int, max_coast_s: float):
        self.accel_psd = accel_psd
        self.yaw_accel_psd = yaw_accel_psd
        self.init_speed_sigma = init_speed_sigma
        self.init_omega_sigma = init_omega_sigma
        self.gate_chi2 = gate_chi2
        self.max_rejects = max_rejects
        self.max_coast_s = max_coast_s
        self.reset()

    def reset(self) -> None:
        self.s: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.t: float | None = None
        self.t_fix: float | None = None
        self.rejects = 0
        self._pred = None        # (t_s, t, s, P, prediction) of the last predict_at

    @property
    def started(self) -> bool:
        return self.s is not None

    def start(self, t_s: float, xy: np.ndarray, cov_xy: np.ndarray, psi: float, psi_sigma: float,
              speed: float | None, speed_sigma: float) -> None:
        self.s = np.array([xy[0], xy[1], psi, 0.0 if speed is None else speed, 0.0])
        P = np.zeros((5, 5))
        P[:2, :2] = cov_xy
        P[2, 2] = psi_sigma ** 2
        P[3, 3] = (self.init_speed_sigma if speed is None else speed_sigma) ** 2
        P[4, 4] = self.init_omega_sigma ** 2
        self.P = P
        self.t = self.t_fix = t_s
        self.rejects = 0

    @staticmethod
    def _model(s: np.ndarray, P: np.ndarray, dt: float, qa: float, qw: float):
        x, y, psi, v, w = s
        c, sn = math.cos(psi), math.sin(psi)
        s2 = np.array([x + v * c * dt, y + v * sn * dt, psi + w * dt, v, w])
        F = np.eye(5)
        F[0, 2], F[0, 3] = -v * sn * dt, c * dt
        F[1, 2], F[1, 3] = v * c * dt, sn * dt
        F[2, 4] = dt
        # White accelerations a (on v) and alpha (on omega), integrated over dt.
        G = np.array([[0.5 * c * dt * dt, 0.0], [0.5 * sn * dt * dt, 0.0], [0.0, 0.5 * dt * dt],
                      [dt, 0.0], [0.0, dt]])
        Q = G @ np.diag([qa / dt, qw / dt]) @ G.T if dt > 0 else np.zeros((5, 5))
        return s2, F @ P @ F.T + Q

    def predict_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """State and covariance predicted to t_s (the filter itself is unchanged). The last
        prediction is kept until the state changes: the locator asks for the frame's prediction
        (the pose solve's warm start) before it predicts the filter to the same time."""
        if self.s is None:
            return None
        key = (t_s, self.t, self.s, self.P)
        c = self._pred
        if c is not None and c[0] == t_s and c[1] == self.t and c[2] is self.s and c[3] is self.P:
            return c[4]
        dt = max(0.0, t_s - self.t)
        out = self._model(self.s, self.P, dt, self.accel_psd, self.yaw_accel_psd)
        self._pred = (*key, out)
        return out

    def predict(self, t_s: float) -> None:
        if self.s is None:
            return
        s, P = self.predict_at(t_s)
        self.s, self.P = s.copy(), P.copy()      # the kept prediction stays unchanged by updates
        self.t = max(self.t, t_s)

    def coast_s(self, t_s: float) -> float:
        return math.inf if self.t_fix is None else t_s - self.t_fix

    def position_std_m(self, t_s: float) -> float:
        """2D position std (m, sqrt of the x, y variances' sum) predicted to t_s."""
        P = self.predict_at(t_s)[1]
        return math.sqrt(max(float(P[0, 0] + P[1, 1]), 0.0))

    def expired(self, t_s: float) -> bool:
        return self.s is None or self.coast_s(t_s) > self.max_coast_s

    def _update(self, z: np.ndarray, H: np.ndarray, R: np.ndarray, angle_rows=()) -> float:
        y = z - H @ self.s
        for i in angle_rows:
            y[i] = wrap_pi(y[i])
        S = H @ self.P @ H.T + R
        Si = np.linalg.inv(S)
        m2 = float(y @ Si @ y)
        K = self.P @ H.T @ Si
        self.s = self.s + K @ y
        self.s[2] = wrap_pi(self.s[2])
        IKH = np.eye(5) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        return m2

    def gate(self, xy: np.ndarray, cov_xy: np.ndarray) -> float:
        """Mahalanobis^2 of a position fix against the current (predicted) state."""
        (c00, c01), (c10, c11) = np.asarray(cov_xy, float).tolist()
        (p00, p01, *_), (p10, p11, *_) = self.P[:2].tolist()
        a, b, c, d = p00 + c00, p01 + c01, p10 + c10, p11 + c11
        y0, y1 = float(xy[0]) - float(self.s[0]), float(xy[1]) - float(self.s[1])
        det = a * d - b * c
        if det == 0.0:
            raise np.linalg.LinAlgError("Singular matrix")
        # S^-1 y by Cramer's rule (2 x 2): scalars, not a LAPACK call.
        return y0 * ((d * y0 - b * y1) / det) + y1 * ((a * y1 - c * y0) / det)

    def set_speed(self, v: float, sigma: float) -> None:
        """Speed set from outside (m/s, 1-sigma), its cross-covariances cleared."""
        self.s[3] = v
        self.P[3, :] = 0.0
        self.P[:, 3] = 0.0
        self.P[3, 3] = sigma * sigma

    def update_fix(self, t_s: float, xy: np.ndarray, cov_xy: np.ndarray, psi: float | None,
                   psi_sigma: float, held_speed: bool = False) -> bool:
        """Position (+ heading) fix; returns False when gated out (then nothing changes).
        `held_speed`: the speed is not learned from this fix (its cross-covariances are
        cleared first, so the gain on it is 0; the caller sets it later, `set_speed`)."""
        if self.gate(xy, cov_xy) > self.gate_chi2:
            self.rejects += 1
            return False
        self.rejects = 0
        if held_speed:
            p33 = self.P[3, 3]
            self.P[3, :] = 0.0
            self.P[:, 3] = 0.0
            self.P[3, 3] = p33
        if psi is None:
            H = np.zeros((2, 5))
            H[0, 0] = H[1, 1] = 1.0
            self._update(np.asarray(xy, float), H, cov_xy)
        else:
            H = np.zeros((3, 5))
            H[0, 0] = H[1, 1] = H[2, 2] = 1.0
            R = np.zeros((3, 3))
            R[:2, :2] = cov_xy
            R[2, 2] = psi_sigma ** 2
            self._update(np.array([xy[0], xy[1], psi]), H, R, angle_rows=(2,))
        self.t_fix = t_s
        return True

    def update_observation(self, t_s: float, z: np.ndarray, h, R: np.ndarray, gate_chi2: float,
                           eps=(1e-3, 1e-3, 1e-5)) -> bool:
        """EKF update with any measurement z (m,) of the pose: `h(x, y, psi) -> (m,)` predicts it,
        R (m, m) its noise covariance (nuisances folded in by the caller). The Jacobian on x, y,
        psi by central differences (steps `eps`: m, m, rad). Gated at `gate_chi2` on the
        innovation's Mahalanobis^2 (then nothing changes and `rejects` counts it, but a gated
        observation never restarts the filter: that is the caller's). Returns whether taken."""
        x, y, psi = (float(v) for v in self.s[:3])
        z = np.asarray(z, float)
        H = np.zeros((len(z), 5))
        for j, e in enumerate(eps):
            d = np.zeros(3)
            d[j] = e
            H[:, j] = (np.asarray(h(x + d[0], y + d[1], psi + d[2])) - np.asarray(h(x - d[0], y - d[1], psi - d[2]))) / (2 * e)
        y_ = z - np.asarray(h(x, y, psi), float)
        S = H @ self.P @ H.T + R
        if not np.all(np.isfinite(S)) or not np.all(np.isfinite(y_)):
            return False
        m2 = float(y_ @ np.linalg.solve(S, y_))
        if m2 > gate_chi2:
            self.rejects += 1
            return False
        self.rejects = 0
        K = np.linalg.solve(S, H @ self.P).T
        self.s = self.s + K @ y_
        self.s[2] = wrap_pi(self.s[2])
        IKH = np.eye(5) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self.t_fix = t_s
        return True

    def update_speed(self, speed: float, sigma: float) -> None:
        self._update(np.array([speed]), _H_SPEED, np.array([[sigma ** 2]]))


class RangeKalman:
    """Constant-velocity filter of one distance (module doc), in scalars (2 states: numpy's
    per-call overhead would dominate). `update` gates the innovation at `gate_chi2` (None: no
    gate) and returns whether the range was taken; `rejects` counts consecutive gated ones."""

    def __init__(self, t_s: float, d: float, sigma: float, rate_sigma: float, accel_psd: float,
                 gate_chi2: float | None = None):
        self.d, self.v = float(d), 0.0
        self.p00, self.p01, self.p11 = sigma * sigma, 0.0, rate_sigma * rate_sigma
        self.t = t_s
        self.t_meas = t_s
        self.q = accel_psd
        self.gate = gate_chi2
        self.rejects = 0

    @property
    def x(self) -> np.ndarray:
        return np.array([self.d, self.v])

    @property
    def P(self) -> np.ndarray:
        return np.array([[self.p00, self.p01], [self.p01, self.p11]])

    def predict(self, t_s: float) -> None:
        dt = t_s - self.t
        if dt > 0:
            q = self.q
            self.d += self.v * dt
            p00 = self.p00 + 2 * dt * self.p01 + dt * dt * self.p11 + q * dt ** 3 / 3
            p01 = self.p01 + dt * self.p11 + q * dt * dt / 2
            self.p00, self.p01, self.p11 = p00, p01, self.p11 + q * dt
            self.t = t_s

    def update(self, t_s: float, d: float, sigma: float) -> bool:
        S = self.p00 + sigma * sigma
        y = d - self.d
        if self.gate is not None and y * y > self.gate * S:
            self.rejects += 1
            return False
        k0, k1 = self.p00 / S, self.p01 / S
        self.d += k0 * y
        self.v += k1 * y
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.p00, self.p01, self.p11 = p00 - k0 * p00, p01 - k0 * p01, p11 - k1 * p01
        self.t_meas = t_s
        self.rejects = 0
        return True
