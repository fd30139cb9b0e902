"""The vehicle stage's compiled kernels against their numpy references (receiver.core.native):
every call the locator makes on the synthetic scenes of test_vehicle / test_vehicle_single is
run both ways on the same inputs and compared."""

from __future__ import annotations

import math

import numpy as np
import pytest

import receiver.locate.vehicle as V
from receiver.locate import vehicle_cars as VC, vehicle_host as VH, vehicle_ranging as VR


def set_kr(monkeypatch, kernel):
    """The per-pair kernel (receiver.locate._vehicle_range) in every module that calls it."""
    for m in (VR, VH, VC):
        monkeypatch.setattr(m, "_kr", kernel)
from tests.vehicle.test_vehicle import CAM, SETTINGS, camera_pose, fv_pair, make_map, sl_pairs
from tests.vehicle.test_vehicle_single import _drive

needs_kernel = pytest.mark.skipif(VH._k is None, reason="compiled kernel not built (tests/engine/test_native.py fails then)")


class _Both:
    """Wraps VehicleLocator._solve_pose: each call runs the kernel and the numpy path and records
    the largest differences; the kernel's result goes on."""

    def __init__(self, monkeypatch):
        self.orig = V.VehicleLocator._solve_pose
        self.calls = []
        this = self

        def wrapped(loc, *a, **k):
            out = this.orig(loc, *a, **k)
            monkeypatch.setattr(VH, "_k", None)
            try:
                ref = this.orig(loc, *a, **k)
            finally:
                monkeypatch.setattr(VH, "_k", kernel)
            this.calls.append((k, out, ref))
            return out

        kernel = VH._k
        monkeypatch.setattr(V.VehicleLocator, "_solve_pose", wrapped)

    def check(self, tol_C=1e-9, tol_R=1e-11, tol_cov=1e-9):
        assert self.calls
        for kw, out, ref in self.calls:
            assert (out is None) == (ref is None), kw
            if out is None:
                continue
            (R, C, cov), (R0, C0, cov0) = out, ref
            assert np.max(np.abs(R - R0)) <= tol_R
            assert np.max(np.abs(C - C0)) <= tol_C
            assert np.max(np.abs(cov - cov0)) <= tol_cov * max(1.0, float(np.max(np.abs(cov0))))


@needs_kernel
@pytest.mark.parametrize("radius", [None, 150.0])
def test_pose_kernel_equals_numpy_cold_and_warm(monkeypatch, radius):
    """Cold solves (2-D registration start, up to pose_max_iter steps) and warm ones (tracking,
    pose_track_iter steps) with pixel noise, both emitter orders, forward vehicles in view."""
    both = _Both(monkeypatch)
    rng = np.random.default_rng(5)
    lmap = make_map(radius)
    loc = V.VehicleLocator(CAM, lmap, SETTINGS)
    for i in range(25):
        R, C, psi = camera_pose(2.0 + 0.5 * i, radius, lateral=-1.0, yaw_off=rng.normal(0, 0.3))
        pairs = sl_pairs(lmap, R, C, rng=rng, px_sigma=0.3, area_rel=0.03, swap=True)
        pairs.append(fv_pair((20.0, 0.5), R, C, psi, rng=rng, px_sigma=0.3)[0])
        hv = loc.step(i / 30.0, pairs).vehicle["hv"]
        assert hv is not None
    assert any(kw.get("max_iter") == V.POSE_TRACK_ITER for kw, _, _ in both.calls)
    assert any(kw.get("max_iter") is None for kw, _, _ in both.calls)
    both.check()


@needs_kernel
def test_pose_kernel_equals_numpy_single_light_attitude_rows(monkeypatch):
    """The single-light solve (`_single_fix`: yaw, roll and pitch priors, the midpoint range,
    no emitter ranges) both ways."""
    both = _Both(monkeypatch)
    _drive(make_map(), 12)
    att = [kw["attitude"] for kw, _, _ in both.calls if kw.get("attitude")]
    assert att and {"yaw", "roll", "mid_range"} <= set(att[0])
    both.check()


@needs_kernel
@pytest.mark.parametrize("value", [1e9, 1e300, float("inf"), float("nan")])
def test_pose_kernel_absurd_ranges_agree(monkeypatch, value):
    """Absurd emitter ranges (overflowing whitened residuals) give no fix, or the same fix, both
    ways."""
    both = _Both(monkeypatch)
    lmap = make_map()
    R, C, psi = camera_pose(3.0)
    pairs = sl_pairs(lmap, R, C)
    loc = V.VehicleLocator(CAM, lmap, SETTINGS)
    out = loc._range_pairs(pairs, None, False)
    aligned, res = out
    res["d_a"][0] = value
    sl_k = [k for k, r in enumerate(res["roles"]) if r == "SL"]
    init = loc._init_pose(np.array([[0.0, -5.0, 20.0], [0.0, -5.0, 30.0]]),
                          np.array([lmap.leds[0].xyz, lmap.leds[1].xyz]))
    R0, C0 = init if init is not None else (R, C)
    loc._solve_pose(pairs, res, sl_k, R0, C0)
    assert len(both.calls) == 1
    both.check(tol_C=1e-6, tol_R=1e-8)
    assert all(o is None or np.all(np.isfinite(o[1])) for _, o, _ in both.calls)


def test_pure_path_without_kernel(monkeypatch):
    """With the kernel unavailable (OCCLOC_PURE=1 or not built) the numpy path places the host."""
    monkeypatch.setattr(VH, "_k", None)
    lmap = make_map()
    R, C, psi = camera_pose(41.0)
    hv = V.VehicleLocator(CAM, lmap, SETTINGS).step(0.0, sl_pairs(lmap, R, C)).vehicle["hv"]
    assert math.hypot(hv["raw"]["x"] - C[0], hv["raw"]["y"] - C[1]) < 0.03


@needs_kernel
def test_covariance_kernel_equals_pinv():
    """s^2 (J' J)^-1 by Cholesky equals lsq.covariance_at's pinv on determined problems (within
    the conditioning's rounding), and declines rank-deficient ones (the pinv path decides)."""
    from receiver.locate.lsq import covariance_at

    rng = np.random.default_rng(2)
    for n in (8, 12, 30):
        J = rng.normal(size=(n, 6)) * np.array([5e3, 5e3, 5e3, 30.0, 30.0, 3.0])
        r = rng.normal(size=n) * 2.0
        out = np.empty((6, 6))
        assert VH._k.covariance(r, J, out) == 0
        ref = covariance_at(r, J, 6)[0]
        assert np.allclose(out, ref, rtol=1e-9, atol=0.0)
        assert np.array_equal(out, out.T)
    J[:, 5] = 0.0
    assert VH._k.covariance(r, J, np.empty((6, 6))) == 1
    J[0, 0] = np.nan
    assert VH._k.covariance(r, J, np.empty((6, 6))) == 1


def _same(a, b) -> bool:
    """Equal to the last bit, NaN equal to NaN, bools as bools."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if isinstance(x, bool) or isinstance(y, bool):
            if type(x) is not type(y) or x != y:
                return False
        elif x != x or y != y:
            if not (x != x and y != y):
                return False
        elif x != y or math.copysign(1.0, x) != math.copysign(1.0, y):
            return False
    return True


@pytest.mark.skipif(VR._kr is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")
def test_range_kernel_equals_python_loop_bit_for_bit(monkeypatch):
    """range_core's compiled loop gives the Python loop's numbers exactly, on SL heads (with and
    without a known pose), taillight pairs, half-seen pairs and absurd areas / centroids."""
    orig = VR.range_core
    kernel = VR._kr
    n_pairs = [0]

    def both(*a, **k):
        out = orig(*a, **k)
        set_kr(monkeypatch, None)
        try:
            ref = orig(*a, **k)
        finally:
            set_kr(monkeypatch, kernel)
        assert set(out) == set(ref)
        for key in ref:
            if key in ("ra", "rb"):
                assert np.array_equal(out[key], ref[key], equal_nan=True)
            else:
                assert _same(out[key], ref[key]), key
        n_pairs[0] += len(ref["fused"])
        return out

    monkeypatch.setattr(VR, "range_core", both)
    rng = np.random.default_rng(9)
    lmap = make_map(150.0)
    loc = V.VehicleLocator(CAM, lmap, SETTINGS)
    for i in range(8):
        R, C, psi = camera_pose(3.0 + i, 150.0, yaw_off=rng.normal(0, 0.3))
        pairs = sl_pairs(lmap, R, C, rng=rng, px_sigma=0.3, area_rel=0.03, swap=True)
        pairs.append(fv_pair((18.0, 0.5), R, C, psi, rng=rng, px_sigma=0.3)[0])
        pairs.append(fv_pair((35.0, -3.0), R, C, psi, key=(902, 903), led_id=None)[0])
        if i >= 5:       # absurd values in one pair
            q = pairs[0]
            value = (0.0, -1.0, 1e300)[i - 5]
            pairs[0] = V.PairObservation(**{**q.__dict__, "area_a_px": value,
                                            "a_seen": ((value, q.a_px[1]), value, 0)})
        loc.step(i / 30.0, pairs)
    assert n_pairs[0] >= 40


@pytest.mark.skipif(VR._kr is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")
def test_rays_kernel_equals_numpy_bit_for_bit(monkeypatch):
    rng = np.random.default_rng(3)
    u = np.concatenate([rng.normal(size=(500, 2)) * 0.4, [[1e200, 0.0], [np.nan, 0.1], [np.inf, 0.0], [0.0, 0.0]]])
    got = VR._rays(u)
    set_kr(monkeypatch, None)
    with np.errstate(over="ignore", invalid="ignore"):
        ref = VR._rays(u)
    assert np.array_equal(got, ref, equal_nan=True)


@pytest.mark.skipif(VR._kr is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")
def test_record_rounding_kernel_equals_python_round():
    """The records' rounding (`_r`) compiled gives round(v, nd) exactly: ties, signed zeros,
    huge values, None / NaN / inf, numpy floats and ints."""
    rng = np.random.default_rng(8)
    vals = list(rng.normal(size=4000) * 10.0 ** rng.integers(-6, 9, 4000))
    vals += [0.5e-4, 1.5e-4, 2.5e-4, -0.5e-4, 0.00015, 1.00005, 2.675, -2.675, 0.0, -0.0, -1e-7, 1e-7, 5e-5, -5e-5,
             123456789.12345, 1e15 + 0.3, 4.9999999999e-5, np.float64(3.14159265), 7, -3]
    for v in vals:
        for nd in (3, 4):
            a, b = VR._kr.rnd(v, nd), VR._r_py(v, nd)
            assert a == b and math.copysign(1.0, a) == math.copysign(1.0, b) and type(a) is float, (v, nd, a, b)
    for v in (None, float("nan"), float("inf"), -float("inf")):
        assert VR._kr.rnd(v) is None and VR._r_py(v) is None


@pytest.mark.skipif(VR._kr is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")
def test_pose_ranges_kernel_equals_python_loop(monkeypatch):
    """The "pose" ranges of the street-light pairs, compiled and in Python, bit for bit."""
    lmap = make_map()
    R, C, psi = camera_pose(20.0)
    pairs = sl_pairs(lmap, R, C) + [fv_pair((20.0, 0.0), R, C, psi)[0]]
    pairs.append(V.PairObservation(**{**pairs[0].__dict__, "led_id": 99, "kind": "SL"}))    # unmapped
    loc = V.VehicleLocator(CAM, lmap, SETTINGS)
    fix = {"pose": (C + np.array([0.3, -0.2, 0.05]), np.array([[0.04, 0.01], [0.01, 0.09]]))}
    got, ref = [None] * len(pairs), [None] * len(pairs)
    loc._pose_ranges(pairs, got, fix)
    set_kr(monkeypatch, None)
    loc._pose_ranges(pairs, ref, fix)
    assert got == ref and sum(r is not None for r in ref) == len(pairs) - 2


@pytest.mark.skipif(VR._kr is None, reason="compiled kernel not built (or OCCLOC_PURE=1)")
def test_on_mapped_sl_kernel_equals_numpy(monkeypatch):
    """Whether an emitter lies on a projected mapped head: compiled and numpy decide alike, also
    at the gate's edge and with NaN points."""
    lmap = make_map()
    R, C, psi = camera_pose(20.0)
    loc = V.VehicleLocator(CAM, lmap, SETTINGS)
    hv = {"x": float(C[0]), "y": float(C[1])}
    loc.z_last = float(C[2])
    loc._on_mapped_sl(0.0, np.zeros(2), np.zeros(2), hv, R)
    P = loc._sl_seen_at[2]
    g = math.tan(math.radians(V.FV_SL_GATE_DEG))
    rng = np.random.default_rng(1)
    cases = [(P[0] + [g * 0.999, 0.0], P[1] + [5.0, 5.0]), (P[0] + [g * 1.001, 0.0], P[1] + [0.0, g * 1.001]),
             (np.array([np.nan, 0.0]), P[2]), (P[3], np.array([np.nan, np.nan]))]
    cases += [(rng.normal(size=2) * 0.3, rng.normal(size=2) * 0.3) for _ in range(200)]
    got = [loc._on_mapped_sl(0.0, a, b, hv, R) for a, b in cases]
    set_kr(monkeypatch, None)
    ref = [loc._on_mapped_sl(0.0, a, b, hv, R) for a, b in cases]
    assert got == ref and any(ref) and not all(ref)


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


def test_range_kernels_check_their_lengths():
    """range_rows' columns and pose_ranges' output list are indexed unchecked: short ones raise."""
    import numpy as np
    import pytest
    from receiver.locate import _vehicle_range as k
    with pytest.raises(ValueError):
        k.range_rows([1.0, 2.0], [1.0], *([[]] * 18), 1000.0, 0.0, 0.5, 1.0)
    with pytest.raises(ValueError):
        k.pose_ranges([object(), object()], {}, 0, 0, 0, 1, 0, 0, 1, 0.1, [None])
    with pytest.raises(ValueError):
        k.near_any(np.zeros((2, 3)), 0, 0, 1, 1, 0.1)
    assert k.near_any(np.zeros((1, 2)), 0.0, 0.0, 1.0, 1.0, 0.1)


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
