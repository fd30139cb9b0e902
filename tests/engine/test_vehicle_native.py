"""The vehicle stage's compiled host-pose solve (receiver.locate._vehicle_pose), the one
implementation of it: its residual rows against the geometry they stand for (projection,
ranges, priors, receiver.locate.pose's yaw / pitch / roll), its Jacobian against finite
differences (scipy.optimize.approx_fprime), its solution against the truth of noise-free
problems and against scipy.optimize.least_squares with the same soft-L1 loss on noisy ones."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.optimize import approx_fprime, least_squares

import receiver.locate.vehicle as V
from receiver.locate import _vehicle_pose as k
from receiver.locate import vehicle_host as VH
from receiver.locate.lsq import LM_FTOL, LM_LAMBDA0, LM_LAMBDA_MAX
from receiver.locate.pose import rotation_to_ypr_deg, ypr_to_rotation
from tests.vehicle.test_vehicle import CAM, SETTINGS

F_SCALE = VH.POSE_F_SCALE


def _problem(seed: int, n_heads: int = 3, n_pairs: int | None = None, px_sigma: float = 0.0,
             range_rel: float = 0.0, attitude: bool = True, outlier: bool = False) -> dict:
    """A host-pose problem: a dash camera (1.3 m high, yawed, pitched, rolled a little) and
    `n_heads` street-light heads (7 m high, 15-80 m ahead, either side) of two emitters 0.6 m
    apart across the road; the emitters' normalized image points (plus `px_sigma` px noise at
    f = 1000 px) and ranges (relative noise `range_rel`; `outlier`: the first one 30 % long);
    the tilt and position priors at the truth; yaw, pitch, roll and midpoint-range rows."""
    rng = np.random.default_rng(seed)
    yaw, pitch, roll = rng.uniform(-20, 20), rng.uniform(0, 5), rng.uniform(-1, 1)
    R = ypr_to_rotation(yaw, pitch, roll)
    C = np.array([rng.uniform(-50, 50), rng.uniform(-3, 3), 1.3])
    h = np.array([math.cos(math.radians(yaw)), math.sin(math.radians(yaw)), 0.0])
    left = np.array([-h[1], h[0], 0.0])
    L = []
    for j in range(n_heads):
        head = C + h * rng.uniform(15, 80) + left * (6.0 if j % 2 else -6.0) * rng.uniform(0.8, 1.2)
        head[2] = 7.0
        L += [head - 0.3 * left, head + 0.3 * left]
    L = np.array(L)
    X = (L - C) @ R.T
    uv = X[:, :2] / X[:, 2:] + rng.normal(0, px_sigma / 1000.0, (len(L), 2))
    d = np.linalg.norm(L - C, axis=1) * (1 + rng.normal(0, range_rel, len(L)))
    d[1::2] = np.nan                        # one range per head (the other emitter's: none)
    if outlier:
        d[0] *= 1.3
    sd = np.where(np.isfinite(d), 0.02 * np.nan_to_num(d), 1.0)
    cov = np.diag([1e8, 1e8, 0.3 ** 2])
    W = np.ascontiguousarray(np.linalg.cholesky(np.linalg.inv(cov)).T)
    att = np.zeros((0, 8))
    if attitude:
        M = L[:2].mean(0)
        att = np.array([[0.0, math.radians(yaw), math.radians(3.0), 0, 0, 0, 0, 1.0],
                        [1.0, math.radians(pitch), math.radians(0.5), 0, 0, 0, 0, 1.0],
                        [2.0, math.radians(roll), math.radians(1.0), 0, 0, 0, 0, 1.0],
                        [3.0, 0.0, 1.0, *M, float(np.linalg.norm(M - C)), 0.05]])
    rvec = cv2.Rodrigues(R)[0].ravel()
    return dict(L=L, uv=np.ascontiguousarray(uv), sigma_uv=0.2 / 1000.0, d=d, sd=sd,
                up=np.ascontiguousarray(R[:, 2]), up_sigma=math.radians(10.0), C_prior=C.copy(), W=W,
                n_pairs=n_heads if n_pairs is None else n_pairs, sep_gain=0.5, att=att,
                truth=np.concatenate([rvec, C]))


def _rows(q) -> int:
    return k.rows(len(q["L"]), int(np.isfinite(q["d"]).sum()), len(q["att"]))


def _run(q, p, max_iter, rot_tol=1e-13, pos_tol=1e-13, ftol=0.0):
    """The kernel's `solve` from p: (solution, residuals, Jacobian)."""
    x = np.array(p, float)
    r = np.empty(_rows(q))
    J = np.empty((len(r), 6))
    k.solve(q["L"], q["uv"], q["sigma_uv"], q["d"], q["sd"], q["up"], q["up_sigma"], q["C_prior"], q["W"],
            q["n_pairs"], q["sep_gain"], q["att"], F_SCALE, x, max_iter, rot_tol, pos_tol, ftol, LM_LAMBDA0,
            LM_LAMBDA_MAX, r, J)
    return x, r, J


def _residuals(q, p):
    """The kernel's residuals at p (no step taken)."""
    return _run(q, p, 0)[1]


def _start(q, seed, rot=0.03, pos=1.5):
    rng = np.random.default_rng(seed)
    return q["truth"] + np.r_[rng.normal(0, rot, 3), rng.normal(0, pos, 2), 0.0]


@pytest.mark.parametrize("n_pairs", [0, 2])
def test_pose_kernel_residuals_are_the_geometry(n_pairs):
    """Each residual row at a pose off the truth, computed from the geometry it stands for:
    the reprojection error (each of the first `n_pairs` pairs as its midpoint and its centroid
    difference times sep_gain, 1/sqrt 2 each), the range errors, the tilt and position priors,
    and the yaw / pitch / roll (receiver.locate.pose.rotation_to_ypr_deg) and midpoint-range
    rows, each over its sigma."""
    q = _problem(1, n_heads=3, n_pairs=n_pairs, px_sigma=0.5, range_rel=0.01)
    p = _start(q, 2)
    r = _residuals(q, p)
    R = cv2.Rodrigues(p[:3].reshape(3, 1))[0]
    C = p[3:]
    X = (q["L"] - C) @ R.T
    ang = (X[:, :2] / X[:, 2:] - q["uv"]) / q["sigma_uv"]          # (M, 2)
    h, g = 1 / math.sqrt(2), q["sep_gain"]
    want = []
    for j in range(len(q["L"]) // 2):
        a, b = ang[2 * j], ang[2 * j + 1]
        if j < n_pairs:
            want += [h * (a + b), g * h * (b - a)]
        else:
            want += [a, b]
    want = [np.concatenate(want)]
    fin = np.isfinite(q["d"])
    want.append((np.linalg.norm(q["L"][fin] - C, axis=1) - q["d"][fin]) / q["sd"][fin])
    want.append((R[:, 2] - q["up"]) / q["up_sigma"])
    want.append(q["W"] @ (C - q["C_prior"]))
    yaw, pitch, roll = (math.radians(v) for v in rotation_to_ypr_deg(R))
    a = q["att"]
    want.append([(yaw - a[0, 1]) / a[0, 2], (pitch - a[1, 1]) / a[1, 2], (roll - a[2, 1]) / a[2, 2],
                 (np.linalg.norm(a[3, 3:6] - C) - a[3, 6]) / a[3, 7]])
    want = np.concatenate([np.ravel(w) for w in want])
    assert len(r) == len(want)
    assert np.allclose(r, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_pose_kernel_jacobian_is_the_residuals_derivative(seed):
    """The analytic Jacobian against scipy's finite differences of the kernel's own residuals."""
    q = _problem(seed, px_sigma=0.3, range_rel=0.01)
    p = _start(q, seed + 10)
    J = _run(q, p, 0)[2]
    num = approx_fprime(p, lambda x: _residuals(q, x), 1e-7)
    assert np.allclose(J, num, rtol=1e-4, atol=1e-5 * np.abs(num).max())


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
@pytest.mark.parametrize("n_heads", [2, 3])
def test_pose_kernel_finds_the_true_pose_of_a_noise_free_problem(seed, n_heads):
    """No noise, priors at the truth: from a start 0.03 rad and 1.5 m off, the truth to 1e-6 m
    and 1e-8 rad; with the solver's own stopping rule (`POSE_ROT_TOL_RAD`, `POSE_POS_TOL_M`), to
    the output's resolution."""
    q = _problem(seed, n_heads=n_heads)
    x = _run(q, _start(q, seed), 50)[0]
    assert np.max(np.abs(x[3:] - q["truth"][3:])) < 1e-6
    assert np.max(np.abs(x[:3] - q["truth"][:3])) < 1e-8
    x = _run(q, _start(q, seed), VH.POSE_MAX_ITER, VH.POSE_ROT_TOL_RAD, VH.POSE_POS_TOL_M, LM_FTOL)[0]
    assert np.max(np.abs(x[3:] - q["truth"][3:])) < 2e-3


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("outlier", [False, True])
def test_pose_kernel_solution_is_scipys_soft_l1_minimum(seed, outlier):
    """Noisy problems (0.3 px, 1 % ranges; `outlier`: one range 30 % long, which the soft-L1
    loss discounts): the kernel's minimum is scipy.optimize.least_squares' (loss "soft_l1", the
    same f_scale) on the same residuals to 1e-5 m and 1e-7 rad, at the same cost."""
    q = _problem(seed, px_sigma=0.3, range_rel=0.01, outlier=outlier)
    p0 = _start(q, seed + 20)
    x, r, _ = _run(q, p0, 200)
    ref = least_squares(lambda p: _residuals(q, p), p0, jac=lambda p: _run(q, p, 0)[2], loss="soft_l1",
                        f_scale=F_SCALE, xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)

    def cost(res):
        z = (res / F_SCALE) ** 2
        return 0.5 * F_SCALE ** 2 * float(np.sum(2 * (np.sqrt(1 + z) - 1)))

    assert cost(r) <= ref.cost * (1 + 1e-9) + 1e-12
    assert np.max(np.abs(x[3:] - ref.x[3:])) < 1e-5
    assert np.max(np.abs(x[:3] - ref.x[:3])) < 1e-7
    if outlier:
        assert abs(r[2 * len(q["L"])]) > F_SCALE          # the long range stays an outlier


@pytest.mark.parametrize("value", [1e9, 1e300, float("inf")])
def test_pose_kernel_absurd_ranges_give_no_fix_or_a_finite_one(value):
    """Absurd emitter ranges (overflowing whitened residuals) through the locator's solve: no
    fix, or a finite one."""
    from tests.vehicle.test_vehicle import camera_pose, make_map, sl_pairs
    lmap = make_map()
    R, C, psi = camera_pose(3.0)
    pairs = sl_pairs(lmap, R, C)
    loc = V.VehicleLocator(CAM, lmap, SETTINGS)
    aligned, res = loc._range_pairs(pairs, None, False)
    res["d_a"][0] = value
    sl_k = [j for j, role in enumerate(res["roles"]) if role == "SL"]
    out = loc._solve_pose(pairs, res, sl_k, R, C)
    assert out is None or (np.all(np.isfinite(out[1])) and np.all(np.isfinite(out[2])))


def test_covariance_kernel_equals_pinv():
    """s^2 (J' J)^-1 by Cholesky equals lsq.covariance_at's pinv on determined problems (within
    the conditioning's rounding), and declines rank-deficient ones (the pinv path decides)."""
    from receiver.locate.lsq import covariance_at

    rng = np.random.default_rng(2)
    for n in (8, 12, 30):
        J = rng.normal(size=(n, 6)) * np.array([5e3, 5e3, 5e3, 30.0, 30.0, 3.0])
        r = rng.normal(size=n) * 2.0
        out = np.empty((6, 6))
        assert k.covariance(r, J, out) == 0
        ref = covariance_at(r, J, 6)[0]
        assert np.allclose(out, ref, rtol=1e-9, atol=0.0)
        assert np.array_equal(out, out.T)
    J[:, 5] = 0.0
    assert k.covariance(r, J, np.empty((6, 6))) == 1
    J[0, 0] = np.nan
    assert k.covariance(r, J, np.empty((6, 6))) == 1


def test_pose_kernel_refuses_an_empty_problem():
    """With bounds checks off, an empty emitter list would be read out of bounds: it must raise."""
    import numpy as np
    import pytest
    from receiver.locate import _vehicle_pose as k
    z = lambda *s: np.zeros(s)  # noqa: E731
    with pytest.raises(ValueError):
        k.solve(z(0, 3), z(0, 2), 1.0, z(0), z(0), z(3), 1.0, z(6), z(6, 6), 0, 1.0, z(0, 8), 1.0, z(6), 5,
                1e-6, 1e-4, 1e-9, 1e-3, 1e6, z(0), z(0, 6))


def _pose_problem(M: int = 3, n_pairs: int = 1, n_att: int = 1):
    """A well-sized host-pose problem for the kernel (M points 10 m ahead, one range, n_att rows)."""
    import numpy as np
    L = np.column_stack([np.arange(M, dtype=float), np.full(M, 10.0), np.full(M, 6.0)])
    d = np.full(M, np.nan)
    d[0] = 11.0
    att = np.zeros((n_att, 8))
    att[:, 2] = 1.0
    n = 2 * M + 1 + 6 + n_att
    return dict(L=L, uv=np.zeros((M, 2)), d=d, sd=np.ones(M), up=np.array([0.0, 0.0, 1.0]), C=np.zeros(3),
                W=np.eye(3), n_pairs=n_pairs, att=att, p=np.array([0.1, 0.0, 0.0, 0.0, 0.0, 1.0]),
                r=np.empty(n), J=np.empty((n, 6)))


def _solve(k, q):
    return k.solve(q["L"], q["uv"], 1.0, q["d"], q["sd"], q["up"], 1.0, q["C"], q["W"], q["n_pairs"], 1.0,
                   q["att"], 1.0, q["p"], 3, 1e-6, 1e-4, 1e-9, 1e-3, 1e6, q["r"], q["J"])


def test_pose_kernel_checks_every_size():
    """The kernel reads its arrays unchecked: each mis-sized one raises, the well-sized problem solves."""
    import numpy as np
    import pytest
    from receiver.locate import _vehicle_pose as k
    assert _solve(k, _pose_problem()) >= 1
    bad = {"uv": np.zeros((2, 2)), "d": np.full(2, np.nan), "sd": np.ones(4), "up": np.zeros(2),
           "C": np.zeros(2), "W": np.eye(2), "n_pairs": 2, "att": np.zeros((1, 7)), "p": np.zeros(5),
           "r": np.empty(9), "J": np.empty((14, 5))}
    for key, value in bad.items():
        q = _pose_problem()
        q[key] = value
        with pytest.raises(ValueError):
            _solve(k, q)
    q = _pose_problem()
    q["d"][1] = 12.0                        # one more range row: r and J are now one row short
    with pytest.raises(ValueError):
        _solve(k, q)


def test_keep_separations_ages_out_like_a_filter_even_when_time_goes_back():
    """`_keep_separations` trims the aged-out prefix while the step times never went back, and
    filters every entry after they did: the kept histories are the former filter's either way."""
    from types import SimpleNamespace

    from tests.vehicle.test_vehicle import make_map

    loc = V.VehicleLocator(CAM, make_map(), SETTINGS)
    rng = np.random.default_rng(1)
    ref: dict = {}
    times = [i / 30.0 for i in range(90)] + [1.0 + i / 30.0 for i in range(80)]   # back by 2 s once
    for t in times:
        pairs = [SimpleNamespace(key=(k, k + 1), both_visible=rng.random() < 0.8,
                                 separation_px=float(rng.uniform(-1, 40))) for k in range(int(rng.integers(1, 5)))]
        loc._keep_separations(t, pairs)
        keep = t - V.SPEED_HIST_S
        new = {}
        for p in pairs:
            h = ref.get(p.key, ())          # the former code: a filter when the first entry aged out
            h = [e for e in h if e[0] >= keep] if h and h[0][0] < keep else list(h)
            if p.both_visible and p.separation_px > 0:
                h.append((t, p.separation_px))
            if h:
                new[p.key] = h
        ref = new
        assert loc._sep_hist == ref
    assert not loc._sep_sorted
