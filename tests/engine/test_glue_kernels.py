"""The per-frame glue around the kernels: `records.led_observation` against the record's own
constructor, and the positioner's compiled glue (receiver/locate/_ranging.pyx) against its
definitions, known truth and OpenCV."""

from __future__ import annotations

import dataclasses

import cv2
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


class _Cam:
    width, height = 640, 480


def test_edge_touch_is_any_envelope_point_within_the_margin():
    """`Ranger._touching_edge` against its definition, point by point: an envelope touches the
    edge when one of its points lies within `border_margin_px` of it (no contour: False)."""
    rng = np.random.default_rng(2)
    ranger = ranging.Ranger.__new__(ranging.Ranger)
    ranger.camera = _Cam()
    for k in range(300):
        m = ranger.border_margin_px = float(rng.choice([0.0, 1.0, 2.5, 3.0]))
        contours = []
        for _ in range(int(rng.integers(0, 8))):
            r = rng.random()
            c = None if r < 0.1 else np.zeros((0, 2)) if r < 0.15 else rng.uniform(-5, 650, (int(rng.integers(1, 12)), 2))
            if c is not None and len(c) and rng.random() < 0.3:
                c = np.round(c)  # on the margin exactly
            contours.append(c)
        obs = [LedObservation(i, 0.0, 0.0, 1.0, c) for i, c in enumerate(contours)]
        want = [c is not None and any(x <= m or y <= m or x >= 639 - m or y >= 479 - m for x, y in c.tolist())
                for c in contours]
        assert ranger._touching_edge(obs) == want
    odd = [LedObservation(0, 0.0, 0.0, 1.0, np.zeros((3, 1, 2), np.float32)),
           LedObservation(1, 0.0, 0.0, 1.0, [[5.0, 5.0], [700.0, 5.0]]),
           LedObservation(2, 0.0, 0.0, 1.0, [[50.0, 50.0], [60.0, 70.0]])]
    ranger.border_margin_px = 2.0
    assert ranger._touching_edge(odd) == [True, True, False]


def test_outline_packing_of_two_targets():
    """`indoor._pack_outline` on a hand-made frame: the edge points in turn, then the centroids;
    sigma = hypot(point sigma, model sigma) / focal; the ends, map centres and half extents."""
    o1, o2 = LedObservation(0, 10.0, 20.0, 1.0, None), LedObservation(1, 30.0, 40.0, 1.0, None)
    e1 = (np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([0.4, 0.0]))
    e2 = (np.array([[5.0, 6.0]], np.float32), np.array([1.2]))
    chosen = [(o1, e1, (None, (0.5, 0.25), (1.0, 2.0, 3.0))), (o2, e2, (None, (0.1, 0.2), (4.0, 5.0, 6.0)))]
    pts, sig, ends, centres, half = indoor._pack_outline(chosen, 0.3, 10.0)
    assert pts.tolist() == [[1, 2], [3, 4], [5, 6], [10, 20], [30, 40]] and pts.dtype == np.float64
    np.testing.assert_allclose(sig, [0.05, 0.03, np.hypot(1.2, 0.3) / 10], rtol=1e-15)
    assert ends.tolist() == [0, 2, 3] and ends.dtype == np.int64
    assert centres.tolist() == [[1, 2, 3], [4, 5, 6]] and half.tolist() == [[0.5, 0.25], [0.1, 0.2]]


def test_polygon_area_perimeter_and_centroid_of_regular_polygons():
    """Known truth: a regular n-gon of circumradius r has area n r^2 sin(2 pi / n) / 2, perimeter
    2 n r sin(pi / n) and its centre as centroid, whatever its orientation and vertex order; a
    polygon of no area has no centroid. OpenCV's contourArea and arcLength agree (float32)."""
    rng = np.random.default_rng(9)
    for k in range(300):
        n = int(rng.integers(3, 400))
        r, c = float(rng.uniform(1, 200)), rng.uniform(-500, 1500, 2)
        a = np.arange(n) * 2 * np.pi / n + rng.uniform(0, 2 * np.pi)
        poly = c + r * np.column_stack([np.cos(a), np.sin(a)])
        if k % 2:
            poly = poly[::-1]
        area, perim = ranging.polygon_area_perimeter(poly)
        assert area == pytest.approx(0.5 * n * r * r * np.sin(2 * np.pi / n), rel=1e-9)
        assert perim == pytest.approx(2 * n * r * np.sin(np.pi / n), rel=1e-9)
        np.testing.assert_allclose(ranging.polygon_centroid(poly), c, rtol=0, atol=1e-9 * (r + np.abs(c).max()))
        p32 = poly.astype(np.float32)
        assert area == pytest.approx(cv2.contourArea(p32), rel=1e-4)
        assert perim == pytest.approx(cv2.arcLength(p32, True), rel=1e-4)
    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    assert ranging.polygon_centroid(line) is None and ranging.polygon_area_perimeter(line)[0] == 0.0
    tri = np.array([[0, 0], [4, 0], [0, 3]], np.float32)
    assert ranging.polygon_area_perimeter(tri) == (6.0, 12.0)
    assert ranging.polygon_area_perimeter(np.array([[0, 0, 4, 0, 0, 3.0]]).reshape(3, 2)[::-1]) == (6.0, 12.0)


def test_annotate_rounds_finite_ranges_to_10_um_and_leaves_the_rest():
    """`Ranger.annotate`: an item with a finite range gets it rounded to 10 um (Python's round)
    and its estimator; the others are the same objects; another record type is copied too."""
    @dataclasses.dataclass(frozen=True)
    class Other:
        track: int
        distance_m: float | None = None
        distance_estimator: str | None = None

    leds = [LedObservation(i, float(i), 2.0, 3.0, None, id=i) for i in range(5)] + [Other(5)]
    d = np.array([1.000005, np.nan, 2.675, np.inf, -0.0, 12.34565])
    names = ["outline", "eq18", "eq18", "eq18", "eq18", "oblique-up"]
    items = [(o, None, None) for o in leds]
    got = ranging.Ranger.annotate(leds, items, d, names)
    assert [type(o) for o in got] == [type(o) for o in leds]
    assert got[1] is leds[1] and got[3] is leds[3]
    for i in (0, 2, 4, 5):
        assert repr(got[i].distance_m) == repr(round(float(d[i]), 5)) and got[i].distance_estimator == names[i]
        assert got[i].track == leds[i].track
    with pytest.raises(dataclasses.FrozenInstanceError):
        got[0].distance_m = 1.0


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
