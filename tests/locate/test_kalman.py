"""Kalman tracking: the stage runs filterpy's predict / update (the oracle), the filter is consistent
(NEES) on a simulated constant-velocity track, it coasts and it gates outliers."""

import numpy as np
import pytest

from receiver.locate.kalman import PositionKalman


def transition(dt):
    """The constant-velocity transition F = [[I, dt I], [0, I]] over dt s."""
    return np.block([[np.eye(3), dt * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])


def process_noise(dt, q):
    """filterpy's process noise of white acceleration of density q over dt, state [x, y, z, v]."""
    from filterpy.common import Q_continuous_white_noise
    return Q_continuous_white_noise(dim=2, dt=dt, spectral_density=q, block_size=3, order_by_dim=False)


def simulate(rng, n=400, dt=0.05, q=0.5, sigma=0.03):
    """Truth drawn from the filter's own motion model (white acceleration of density q) and
    position fixes with known covariance sigma^2 I (seeded)."""
    F, Q = transition(dt), process_noise(dt, q)
    L = np.linalg.cholesky(Q)
    x = np.array([1.0, 2.0, 1.2, 0.5, -0.3, 0.0])
    truth, fixes = [], []
    for _ in range(n):
        x = F @ x + L @ rng.normal(size=6)
        truth.append(x.copy())
        fixes.append(x[:3] + rng.normal(0, sigma, 3))
    return np.array(truth), np.array(fixes)


def test_process_noise_is_the_integral_of_white_acceleration():
    dt, q = 0.2, 0.7
    # Q = int_0^dt F(s) G q G^T F(s)^T ds with G = [0, I]^T, by the midpoint rule.
    s = (np.arange(2000) + 0.5) * dt / 2000
    G = np.vstack([np.zeros((3, 3)), np.eye(3)])
    Qn = sum(transition(si) @ G @ G.T @ transition(si).T for si in s) * q * dt / 2000
    assert np.allclose(process_noise(dt, q), Qn, atol=1e-8)


def test_stage_equals_filterpy():
    """PositionKalman runs filterpy's KalmanFilter predict / update (compiled, without filterpy):
    the same state and covariance to rounding, through starts, fixes of varying covariance and
    coasts."""
    from filterpy.kalman import KalmanFilter

    rng = np.random.default_rng(5)
    _, fixes = simulate(rng, n=80)
    kf = PositionKalman(accel_psd=0.5, gate_chi2=None)
    ref = None
    t = 0.0
    for k, z in enumerate(fixes):
        t += 0.02 + 0.05 * rng.random()              # irregular frame times
        A = rng.normal(0, 0.02, (3, 3))
        R = A @ A.T + 1e-4 * np.eye(3)               # a full fix covariance, as the solver gives
        coast = k % 9 == 4
        out = kf.step(t, None if coast else z, None if coast else R)
        if ref is None:
            ref = KalmanFilter(dim_x=6, dim_z=3)
            ref.x = np.concatenate([z, np.zeros(3)]).reshape(6, 1)
            ref.P = np.zeros((6, 6))
            ref.P[:3, :3] = R
            ref.P[3:, 3:] = kf.init_vel_sigma ** 2 * np.eye(3)
            ref.H = np.hstack([np.eye(3), np.zeros((3, 3))])
            t_ref = t
        else:
            ref.F, ref.Q = transition(t - t_ref), process_noise(t - t_ref, 0.5)
            ref.predict()
            t_ref = t
            if not coast:
                ref.update(z.reshape(3, 1), R=R)
        assert np.allclose(out[0], ref.x.reshape(6), rtol=1e-12, atol=1e-12)
        assert np.allclose(out[1], ref.P, rtol=1e-10, atol=1e-15)


def test_nees_consistency_on_constant_velocity_track():
    rng = np.random.default_rng(11)
    runs, nees = 20, []
    for _ in range(runs):
        truth, fixes = simulate(rng, n=200)
        kf = PositionKalman(accel_psd=0.5, gate_chi2=None)
        for k, z in enumerate(fixes):
            x, P = kf.step(0.05 * k, z, 0.03 ** 2 * np.eye(3))
            if k >= 20:                           # past the start-up transient
                e = x - truth[k]
                nees.append(e @ np.linalg.solve(P, e))
    # Average NEES of a consistent 6-state filter is 6; 95 % band for 3600 correlated samples is
    # far narrower than +-15 %.
    assert np.mean(nees) == pytest.approx(6.0, rel=0.15)


def test_coasting_grows_covariance_then_forgets():
    kf = PositionKalman(max_coast_s=1.0)
    R = 0.01 ** 2 * np.eye(3)
    for k in range(10):
        kf.step(0.1 * k, np.array([0.1 * k, 0, 1]), R)
    _, P0 = kf.state
    x1, P1 = kf.step(1.2)
    assert P1[0, 0] > P0[0, 0]
    assert x1[0] == pytest.approx(1.2, abs=0.05)          # kept walking at 1 m/s
    assert kf.step(2.5) is None                            # silent too long: track dropped


def test_gate_rejects_outlier_and_restarts_after_repeats():
    kf = PositionKalman(max_rejects=3)
    R = 0.01 ** 2 * np.eye(3)
    for k in range(10):
        kf.step(0.1 * k, np.array([0.0, 0, 1]), R)
    x, _ = kf.step(1.0, np.array([3.0, 0, 1]), R)
    assert not kf.last_accepted and abs(x[0]) < 0.05
    kf.step(1.1, np.array([3.0, 0, 1]), R)
    x, _ = kf.step(1.2, np.array([3.0, 0, 1]), R)         # third in a row: the person did move
    assert kf.last_accepted and x[0] == pytest.approx(3.0)


def test_predict_at_is_filterpys_prediction_and_leaves_the_filter_alone():
    from filterpy.kalman import KalmanFilter

    kf = PositionKalman(accel_psd=0.5)
    kf.step(0.0, np.array([1.0, 2.0, 1.0]), 0.01 * np.eye(3))
    kf.step(0.1, np.array([1.1, 2.0, 1.0]), 0.01 * np.eye(3))
    x, P = kf.state
    xp, Pp = kf.predict_at(0.25)
    ref = KalmanFilter(dim_x=6, dim_z=3)
    ref.x, ref.P, ref.F, ref.Q = x.reshape(6, 1), P.copy(), transition(0.15), process_noise(0.15, 0.5)
    ref.predict()
    xe, Pe = ref.x.reshape(6), ref.P
    assert np.allclose(xp, xe, rtol=1e-12, atol=1e-12) and np.allclose(Pp, Pe, rtol=1e-12, atol=1e-15)
    xp0, Pp0 = xp.copy(), Pp.copy()
    xp[:] = 0.0                                                   # the caller's own arrays
    Pp[:] = 0.0
    assert np.array_equal(kf.predict_at(0.25)[0], xp0) and np.array_equal(kf.predict_at(0.25)[1], Pp0)
    x2, P2 = kf.state
    assert np.array_equal(x, x2) and np.array_equal(P, P2)
    assert kf.predict_at(0.05) is None                     # before the filter's time
    assert kf.predict_at(0.1 + kf.max_coast_s + 0.01) is None
