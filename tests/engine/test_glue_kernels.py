"""The per-frame glue around the kernels: `records.led_observation` against the record's own
constructor, and the positioner's compiled glue (receiver/locate/_ranging.pyx) against numpy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from receiver.core.records import LedObservation, led_observation


def test_led_observation_is_the_record():
    names = [f.name for f in dataclasses.fields(LedObservation)]
    args = dict(track=3, cx=1.5, cy=2.5, area_px=10.0, contour=np.zeros((3, 2)), border=True, id=7, mode="ook",
                peak=200.0, distance_m=2.5, distance_estimator="outline", freq_hz=1000.0, kind="SL",
                edge_px=(np.zeros((0, 2)), np.zeros(0)))
    assert list(args) == names
    fast, slow = led_observation(**args), LedObservation(**args)
    assert type(fast) is LedObservation and fast.__dict__.keys() == slow.__dict__.keys()
    assert all(getattr(fast, n) is getattr(slow, n) for n in names)
    assert led_observation(1, 2.0, 3.0, 4.0, None) == LedObservation(1, 2.0, 3.0, 4.0, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.cx = 0.0


# -- the positioner's per-frame glue (receiver/locate/_ranging.pyx) ---------------------------

from receiver.locate import indoor, ranging  # noqa: E402

ranging_native = pytest.mark.skipif(ranging._kr is None, reason="compiled glue not built (or OCCLOC_PURE=1)")


class _Cam:
    width, height = 640, 480


def _contours(rng, n):
    out = []
    for _ in range(n):
        r = rng.random()
        if r < 0.1:
            out.append(None)
        elif r < 0.15:
            out.append(np.zeros((0, 2)))
        else:
            c = rng.uniform(-5, 650, size=(int(rng.integers(1, 12)), 2))
            if rng.random() < 0.3:
                c = np.round(c)  # on the margin exactly
            if rng.random() < 0.05:
                c[int(rng.integers(len(c))), int(rng.integers(2))] = np.nan
            out.append(c)
    return out


@ranging_native
def test_edge_touch_kernel_equals_numpy(monkeypatch):
    rng = np.random.default_rng(2)
    for k in range(400):
        margin = float(rng.choice([0.0, 1.0, 2.5, 3.0]))
        ranger = ranging.Ranger.__new__(ranging.Ranger)
        ranger.camera, ranger.border_margin_px = _Cam(), margin
        obs = [LedObservation(i, 0.0, 0.0, 1.0, c) for i, c in enumerate(_contours(rng, int(rng.integers(0, 8))))]
        native = ranger._touching_edge(obs)
        with monkeypatch.context() as m:
            m.setattr(ranging, "_kr", None)
            pure = ranger._touching_edge(obs)
        assert native == pure and all(type(v) is bool for v in native)
    # contours the kernel does not read (float32, (K, 1, 2), lists) take the numpy path
    odd = [LedObservation(0, 0.0, 0.0, 1.0, np.zeros((3, 1, 2), np.float32)),
           LedObservation(1, 0.0, 0.0, 1.0, [[5.0, 5.0], [700.0, 5.0]])]
    ranger = ranging.Ranger.__new__(ranging.Ranger)
    ranger.camera, ranger.border_margin_px = _Cam(), 2.0
    assert ranger._touching_edge(odd) == [True, True]


@ranging_native
def test_outline_packing_kernel_equals_numpy(monkeypatch):
    rng = np.random.default_rng(4)
    # a frame's sigmas repeat (the kernel keeps the last 8 distinct ones and their hypot): pools of
    # 2 to 12 values, -0.0 and 0.0 among them, as well as all-different ones
    pool = np.concatenate([rng.uniform(0, 2, 10), [0.0, -0.0]])
    for k in range(200):
        chosen = []
        for i in range(int(rng.integers(1, 6))):
            n = int(rng.integers(0, 30))
            sig = (rng.uniform(0, 2, size=n) if k % 2 else
                   rng.choice(pool[:int(rng.integers(2, len(pool) + 1))], size=n))
            edges = (rng.uniform(0, 1000, size=(n, 2)), sig)
            obs = LedObservation(i, float(rng.uniform(0, 1000)), np.float64(rng.uniform(0, 1000)), 1.0, None)
            fx = (None, (float(rng.uniform(0.01, 1)), float(rng.uniform(0.01, 1))), tuple(rng.normal(size=3).tolist()))
            chosen.append((obs, edges, fx))
        native = indoor._pack_outline(chosen, 0.3, 1234.5)
        with monkeypatch.context() as m:
            m.setattr(indoor, "_kr", None)
            pure = indoor._pack_outline(chosen, 0.3, 1234.5)
        for a, b in zip(native, pure):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    # edge arrays the kernel does not read take the numpy path, with the same arrays
    chosen = [(LedObservation(0, 1.0, 2.0, 1.0, None), (np.ones((3, 2), np.float32), np.ones((3, 1))),
               (None, (0.5, 0.5), (1.0, 2.0, 3.0)))]
    got = indoor._pack_outline(chosen, 0.3, 10.0)
    assert got[0].shape == (4, 2) and got[1].shape == (3,) and got[2].tolist() == [0, 3]


@ranging_native
def test_polygon_sums_kernel_equals_numpy(monkeypatch):
    """Area, perimeter, centroid and a contour's whole geometry: the same numbers bit for bit
    (the kernel sums in np.sum's pairwise order), for polygons of 3 to 400 points (numpy's
    sequential, 8-accumulator and halving branches)."""
    from receiver.io.camera import CameraModel

    cam = CameraModel(K=np.array([[900.0, 0, 640], [0, 905.0, 360], [0, 0, 1]]),
                      dist=np.array([-0.2, 0.05, 0.001, -0.001, 0.0]), width=1280, height=720)
    rng = np.random.default_rng(9)
    for k in range(1500):
        n = int(rng.integers(3, 400))
        a = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = rng.uniform(1, 200) * (1 + 0.1 * rng.random(n))
        poly = np.column_stack([640 + r * np.cos(a), 360 + r * np.sin(a)]) * 10.0 ** rng.integers(-2, 2)
        if k % 50 == 0:
            poly[:, 1] = poly[0, 1]  # degenerate: no area, no centroid
        native = (ranging.polygon_area_perimeter(poly), ranging.polygon_centroid(poly),
                  ranging.contour_geometry(poly, cam, 0.5))
        with monkeypatch.context() as m:
            m.setattr(ranging, "_kr", None)
            pure = (ranging.polygon_area_perimeter(poly), ranging.polygon_centroid(poly),
                    ranging.contour_geometry(poly, cam, 0.5))
        assert native[0] == pure[0]
        assert (native[1] is None) == (pure[1] is None) and (pure[1] is None or np.array_equal(native[1], pure[1]))
        assert (native[2] is None) == (pure[2] is None)
        if pure[2] is not None:
            assert native[2].keys() == pure[2].keys()
            assert all(np.array_equal(native[2][key], pure[2][key]) for key in pure[2])
    # what the kernel does not read (float32, strided) is summed by numpy
    tri = np.array([[0, 0], [4, 0], [0, 3]], np.float32)
    assert ranging.polygon_area_perimeter(tri) == (6.0, 12.0)
    assert ranging.polygon_area_perimeter(np.array([[0, 0, 4, 0, 0, 3.0]]).reshape(3, 2)[::-1]) == (6.0, 12.0)


@ranging_native
def test_annotate_kernel_equals_python(monkeypatch):
    """`Ranger.annotate`: the same records (fields, untouched ones the same objects) with the
    compiled copies; another record type goes through `_with_range`."""
    @dataclasses.dataclass(frozen=True)
    class Other:
        track: int
        distance_m: float | None = None
        distance_estimator: str | None = None

    rng = np.random.default_rng(1)
    for k in range(200):
        leds = [LedObservation(i, float(i), 2.0, 3.0, None, id=i) if rng.random() < 0.9 else Other(i)
                for i in range(int(rng.integers(0, 8)))]
        items = [(o, None, None) for o in leds if rng.random() < 0.7]
        hard = [1.000005, np.nextafter(1.000005, 2), np.nextafter(1.000005, 0), 12.34565, 2.675, 1e12, 0.0, -0.0,
                -3.0000049, 1e-320]      # near round(v, 5)'s ties, huge, signed zeros, subnormal
        d = np.array([rng.choice([np.nan, np.inf, float(rng.uniform(0, 9)), float(rng.choice(hard))]) for _ in items])
        names = [str(rng.choice(["outline", "eq18"])) for _ in items]
        native = ranging.Ranger.annotate(leds, items, d, names)
        with monkeypatch.context() as m:
            m.setattr(ranging, "_kr", None)
            pure = ranging.Ranger.annotate(leds, items, d, names)
        assert len(native) == len(pure) == len(leds)
        for a, b, o in zip(native, pure, leds):
            assert type(a) is type(b) and a == b and a.__dict__ == b.__dict__
            assert repr(a.distance_m) == repr(b.distance_m)      # the same rounding, to the sign of a zero
            assert (a is o) == (b is o)
        for a in native:
            with pytest.raises(dataclasses.FrozenInstanceError):
                a.distance_m = 1.0


def test_led_records_follow_the_report_rules():
    """The report's LED records (receiver/vision/_track.pyx `led_records`) on a hand-made frame:
    paired and unstriped tracks give nothing, a covered one only its `want` entry (no record),
    a decoded OOK / tone light its record and its outline request, an S2-PSK one no request;
    tone frequencies rounded to 0.1 Hz (None without tone lights or a finite frequency); any
    envelope with a Blob's attributes is read; the decoded IDs are added to `decoded`."""
    from types import SimpleNamespace

    from receiver import pipeline
    from receiver.core.records import Blob
    from receiver.decode.policy import LightDecoder

    def light(striped, led_id, mode=None, freq=None):
        out = LightDecoder({})
        out.striped, out.led_id, out.mode = striped, led_id, mode
        if freq is not None:
            out.states = {("tone", 0.0): SimpleNamespace(freq_hz=freq)}
        return out

    ids = [1, 2, 3, 4, 5, 6, 7, 8]
    lights = [light(True, 10, "ook"), light(True, 11, "ook"), light(False, 12, "ook"), light(True, 13, "ook"),
              light(True, None), light(True, 14, "tone", 433.26), light(True, 15, "s2psk"),
              light(True, 16, "tone", float("nan"))]
    env = {i: Blob(float(i), 2.0 * i, 3.0, np.zeros((3, 2)), 0, 0, 1, 1, i == 5, 200.0 + i, 50.0, 3.0) for i in ids}
    env[8] = SimpleNamespace(**env[8].__dict__)
    seen = [SimpleNamespace(track_id=i) for i in ids]
    for locate, tones in ((True, True), (False, False)):
        decoded = {99}
        leds, want, fields = pipeline._kt.led_records(seen, lights, env, {2: None}, {4}, decoded, locate, tones,
                                                       LedObservation)
        assert [o.track for o in leds] == [1, 5, 6, 7, 8] and all(type(o) is LedObservation for o in leds)
        assert [o.id for o in leds] == [10, None, 14, 15, 16] and decoded == {99, 10, 14, 15, 16}
        assert [(o.cx, o.cy, o.area_px, o.border, o.peak, o.mode) for o in leds] == [
            (1.0, 2.0, 3.0, False, 201.0, "ook"), (5.0, 10.0, 3.0, True, 205.0, None),
            (6.0, 12.0, 3.0, False, 206.0, "tone"), (7.0, 14.0, 3.0, False, 207.0, "s2psk"),
            (8.0, 16.0, 3.0, False, 208.0, "tone")]
        assert all(o.contour is env[o.track].hull for o in leds)
        assert all(o.distance_m is None and o.distance_estimator is None and o.kind is None and o.edge_px is None
                   for o in leds)
        assert [o.freq_hz for o in leds] == ([None, None, 433.3, None, None] if tones else [None] * 5)
        by_track = {o.track: o for o in leds}
        assert want == ([1, 4, 6, 8] if locate else [])
        assert fields == ([by_track[1].__dict__, None, by_track[6].__dict__, by_track[8].__dict__] if locate else [])
        assert all(f is None or any(f is o.__dict__ for o in leds) for f in fields)
    with pytest.raises(ValueError):
        pipeline._kt.led_records(seen, lights[:-1], env, {}, (), set(), True, True, LedObservation)
