"""The host vehicle's road-frame EKF (`receiver.locate.road_kalman.RoadKalman`): its linear
updates are filterpy's Kalman update (the oracle), its prediction moves a straight-driving car
exactly, and a singular innovation covariance raises numpy's LinAlgError."""

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from receiver.locate.road_kalman import RoadKalman, wrap_pi


def _filter() -> RoadKalman:
    return RoadKalman(accel_psd=2.0, yaw_accel_psd=0.05, init_speed_sigma=15.0, init_omega_sigma=0.2,
                      gate_chi2=13.8, max_rejects=3, max_coast_s=2.0)


def _filterpy_update(s, P, z, H, R):
    """(x, P) after filterpy's KalmanFilter.update (Joseph form) from state s, covariance P."""
    kf = KalmanFilter(dim_x=5, dim_z=len(z))
    kf.x, kf.P, kf.H, kf.R = s.reshape(5, 1).copy(), P.copy(), H, R
    kf.update(z.reshape(-1, 1))
    return kf.x.reshape(5), kf.P


def test_position_and_speed_updates_are_filterpys():
    rng = np.random.default_rng(4)
    kf = _filter()
    kf.start(0.0, np.array([3.0, -1.0]), np.diag([0.04, 0.09]), 0.1, 0.02, None, 0.3)
    x, y, psi = 3.0, -1.0, 0.1
    for i in range(30):
        t = (i + 1) / 30
        x, y, psi = x + 0.5 * math.cos(psi), y + 0.5 * math.sin(psi), psi + 0.002
        kf.predict(t)
        cov = np.array([[0.03, 0.004], [0.004, 0.05]]) * (1 + i % 3)
        xy = np.array([x, y]) + rng.normal(0, 0.1, 2)
        s0, P0 = kf.s.copy(), kf.P.copy()
        assert kf.update_fix(t, xy, cov, None, 0.02)
        H = np.zeros((2, 5))
        H[0, 0] = H[1, 1] = 1.0
        s1, P1 = _filterpy_update(s0, P0, xy, H, cov)
        assert np.allclose(kf.s, s1, rtol=1e-9, atol=1e-12)
        assert np.allclose(kf.P, P1, rtol=1e-9, atol=1e-14)
        s0, P0 = kf.s.copy(), kf.P.copy()
        v = 15.0 + rng.normal(0, 0.2)
        kf.update_speed(v, 0.3)
        H = np.zeros((1, 5))
        H[0, 3] = 1.0
        s1, P1 = _filterpy_update(s0, P0, np.array([v]), H, np.array([[0.3 ** 2]]))
        assert np.allclose(kf.s, s1, rtol=1e-9, atol=1e-12)
        assert np.allclose(kf.P, P1, rtol=1e-9, atol=1e-14)
    assert abs(kf.s[3] - 15.0) < 1.0       # the speed updates pulled the speed to the odometry's


def test_heading_fix_wraps_its_innovation():
    """A heading fix just across +-pi is a small innovation, not a turn of 2 pi."""
    kf = _filter()
    kf.start(0.0, np.array([0.0, 0.0]), np.diag([0.04, 0.04]), math.pi - 0.01, 0.05, 10.0, 0.3)
    assert kf.update_fix(0.0, np.array([0.0, 0.0]), np.diag([0.04, 0.04]), -math.pi + 0.01, 0.05)
    assert abs(wrap_pi(kf.s[2] - math.pi)) < 0.02


def test_prediction_of_a_straight_drive_is_exact():
    kf = _filter()
    kf.start(0.0, np.array([1.0, 2.0]), np.diag([0.01, 0.01]), 0.3, 0.01, 12.0, 0.1)
    s, P = kf.predict_at(0.5)
    assert np.allclose(s, [1.0 + 6.0 * math.cos(0.3), 2.0 + 6.0 * math.sin(0.3), 0.3, 12.0, 0.0], atol=1e-12)
    assert np.allclose(P, P.T) and np.all(np.linalg.eigvalsh(P) > 0)


def test_singular_update_raises_like_numpy():
    kf = _filter()
    kf.start(0.0, np.array([0.0, 0.0]), np.zeros((2, 2)), 0.0, 0.0, 10.0, 0.0)
    with pytest.raises(np.linalg.LinAlgError):
        kf.update_fix(0.0, np.array([0.0, 0.0]), np.zeros((2, 2)), None, 0.0)
