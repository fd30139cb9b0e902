"""The track stage's compiled kernels (receiver/vision/_envelope.pyx) against OpenCV: the convex
hull against cv2.convexHull (the same polygon, on random, repeated, collinear and nearly
collinear points: `same_hull`), the whole envelope history against OpenCV's hull of each light's
moved points (`_merge_reference`, `_same`); the compiled tracker step (receiver/vision/_track.pyx)
against the known lights of a stream."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from receiver.cli.benchscene import bench_scene, render_bench_frame
from receiver.core.native import require
from receiver.core.records import Blob
from receiver.vision.detect import _hull_geometry, detect
from receiver.vision.envelope import EnvelopeHistory
from receiver.vision.track import Track

_env = require("receiver.vision._envelope")


def _point_sets(rng, n_cases):
    """Random point sets of the kinds that steer the hull's corner cases."""
    for t in range(n_cases):
        kind = t % 6
        n = int(rng.integers(1, 150))
        if kind == 0:
            p = rng.normal(size=(n, 2)) * 50 + 300
        elif kind == 1:  # a small grid: many repeated and collinear points
            p = rng.integers(0, 6, size=(n, 2)).astype(float)
        elif kind == 2:  # nearly on one line: the turn test's rounding decides
            s = rng.normal(size=n)
            p = np.column_stack([s * 10 + 5, s * 3 + 1e-4 * rng.normal(size=n)])
        elif kind == 3:  # one convex polygon three times, moved a little and not at all (envelopes)
            ang = np.sort(rng.uniform(0, 2 * np.pi, size=max(n // 3, 1)))
            h = np.column_stack([np.cos(ang), np.sin(ang)]) * rng.uniform(2, 40) + rng.uniform(0, 1000, 2)
            p = np.concatenate([h, h + rng.normal(size=2) * 0.01, h + [0.0, 0.0]])
        elif kind == 4:  # all on one line
            s = rng.integers(0, 10, size=n).astype(float)
            p = np.column_stack([s, 2 * s + 1])
        else:
            p = np.round(rng.normal(size=(n, 2)) * 20, 1) + 100
        yield kind, np.ascontiguousarray(p, np.float32)


def same_hull(got: np.ndarray, want: np.ndarray) -> bool:
    """The same convex polygon as cv2.convexHull's, up to nearly collinear vertices (which
    OpenCV's normalised float test and the kernel's exact one may decide apart): areas within
    1e-6 of the squared extent, the same box, and, where the vertex counts agree, the same
    vertices in the same orientation (any start vertex)."""
    got, want = np.asarray(got, np.float64).reshape(-1, 2), np.asarray(want, np.float64).reshape(-1, 2)
    if len(want) == 0 or len(got) == 0:
        return len(got) == len(want)
    ext = float(np.ptp(want, axis=0).max()) ** 2 + 1.0
    area = lambda p: 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    if abs(area(got) - area(want)) > 1e-6 * ext:
        return False
    if not (np.array_equal(got.min(axis=0), want.min(axis=0)) and np.array_equal(got.max(axis=0), want.max(axis=0))):
        return False
    if len(got) != len(want):
        return True
    k = int(np.flatnonzero((want == got[0]).all(axis=1))[0]) if (want == got[0]).all(axis=1).any() else -1
    return k >= 0 and np.array_equal(np.roll(want, -k, axis=0), got)


def test_convex_hull_equals_opencv():
    rng = np.random.default_rng(7)
    kinds, exact = set(), 0
    for kind, p in _point_sets(rng, 6000):
        want = cv2.convexHull(p.reshape(-1, 1, 2)).reshape(-1, 2)
        got = np.array(_env.convex_hull_f32(p), np.float32).reshape(-1, 2)
        assert same_hull(got, want), (kind, p.tolist())
        exact += got.shape == want.shape and np.array_equal(got, want)
        kinds.add(kind)
    assert kinds == set(range(6))
    assert exact > 5000  # most hulls: cv2.convexHull's vertices, order and start
    assert _env.convex_hull_f32(np.zeros((0, 2), np.float32)) == []


def _same(a, b) -> bool:
    """The same envelope as the OpenCV merge's: the same box and decisions, the same hull up to
    nearly collinear vertices (`same_hull`), centroid within 1e-6 px, area within 1e-7 of itself."""
    assert type(a) is type(b)
    return ((a.x0, a.y0, a.x1, a.y1, a.border, a.peak, a.level, a.background)
            == (b.x0, b.y0, b.x1, b.y1, b.border, b.peak, b.level, b.background)
            and a.hull.dtype == b.hull.dtype and same_hull(a.hull, b.hull)
            and abs(a.cx - b.cx) <= 1e-6 and abs(a.cy - b.cy) <= 1e-6
            and abs(a.area_px - b.area_px) <= 1e-7 * abs(b.area_px))


def _merge_reference(blob, others, shape):
    """One light's merged envelope by OpenCV: cv2.convexHull of its own and its moved earlier
    hulls' points (float32), its centroid and area (`_hull_geometry`), the box floored and
    clipped to the frame, `border` when the box reaches the edge."""
    if not others:
        return blob
    pts = np.concatenate([blob.hull] + list(others)).astype(np.float32).reshape(-1, 1, 2)
    cx, cy, area, poly = _hull_geometry(pts)
    h, w = shape[:2]
    x0, y0 = np.floor(poly.min(axis=0)).astype(int)
    x1, y1 = np.floor(poly.max(axis=0)).astype(int) + 1
    border = blob.border or x0 <= 0 or y0 <= 0 or x1 >= w or y1 >= h
    return Blob(cx, cy, area, poly, max(int(x0), 0), max(int(y0), 0), min(int(x1), w), min(int(y1), h),
                bool(border), blob.peak, blob.level, blob.background)


@pytest.mark.parametrize("n_leds,static", [(5, False), (12, True), (12, False)])
def test_envelope_history_is_opencvs_hull_of_the_moved_hulls(n_leds, static):
    """Each track's envelope is OpenCV's merge of its own hull with its hulls of the last two
    frames, each moved by its velocity times the frames since: static tracks (velocity 0: the
    earlier hulls repeat the own one point for point) and moving ones, a track missing a frame,
    a dropped frame (index gap), a light past the edge."""
    leds = bench_scene(n_leds=n_leds, radius_px=30.0, seed=6)
    frames = [render_bench_frame(leds, k, rng=np.random.default_rng(k)) for k in range(6)]
    per_frame = [detect(g, stripe_gap_px=12) for g in frames]
    vel = [(0.0, 0.0)] if static else [(0.0, 0.0), (-1000.0, -800.0), (1.25, -0.5), (-2.0, 0.75), (0.3, 0.1), (0.0, 3.5)]
    skip = {(2, 1), (3, 1), (4, 0)}
    index = [0, 1, 2, 3, 5, 6]
    shape = frames[0].shape
    hist, seen, merged, border = EnvelopeHistory(3), {}, 0, False
    for j, blobs in enumerate(per_frame):
        k = index[j]
        tracks = [Track(i, b, 0, k, vx=vel[i % len(vel)][0], vy=vel[i % len(vel)][1])
                  for i, b in enumerate(blobs) if (j, i) not in skip]
        got = hist.step(tracks, k, shape)
        assert sorted(got) == [t.track_id for t in tracks]
        for t in tracks:
            others = [h + (t.vx * (k - kh), t.vy * (k - kh)) for kh, h in seen.get(t.track_id, []) if 0 < k - kh < 3]
            assert _same(got[t.track_id], _merge_reference(t.blob, others, shape)), (k, t.track_id)
            merged += bool(others)
            border |= got[t.track_id].border
            seen.setdefault(t.track_id, []).append((k, t.blob.hull))
    assert merged > n_leds  # most lights were merged with earlier hulls
    assert border or static


def test_envelope_history_restarts_on_an_older_frame_index():
    """A frame index at or below an earlier one starts the history afresh (no merge)."""
    leds = bench_scene(n_leds=3, radius_px=30.0, seed=6)
    g = render_bench_frame(leds, 0, rng=np.random.default_rng(0))
    blobs = detect(g, stripe_gap_px=12)
    hist = EnvelopeHistory(3)
    tracks = [Track(i, b, 0, 0) for i, b in enumerate(blobs)]
    hist.step(tracks, 10, g.shape)
    assert all(e is t.blob for t, e in zip(tracks, hist.step(tracks, 4, g.shape).values()))
    merged = hist.step(tracks, 5, g.shape)
    assert all(e is not t.blob for t, e in zip(tracks, merged.values()))


def test_kernel_blobs_are_plain_frozen_blobs():
    """The kernel builds merged Blobs from the blob's attribute dict: they must be equal to,
    compare like and stay as frozen as Blobs made by the constructor."""
    import dataclasses
    leds = bench_scene(n_leds=4, radius_px=30.0, seed=6)
    frames = [render_bench_frame(leds, k, rng=np.random.default_rng(k)) for k in range(2)]
    hist = EnvelopeHistory(3)
    for k, g in enumerate(frames):
        tracks = [Track(i, b, 0, k, vx=0.5) for i, b in enumerate(detect(g, stripe_gap_px=12))]
        env = hist.step(tracks, k, g.shape)
    for t in tracks:
        e = env[t.track_id]
        assert e is not t.blob
        rebuilt = dataclasses.replace(t.blob, **{f: getattr(e, f) for f in ("cx", "cy", "area_px", "hull", "x0", "y0", "x1", "y1", "border")})
        assert _same(e, rebuilt) and repr(e) == repr(rebuilt)
        with pytest.raises(dataclasses.FrozenInstanceError):
            e.cx = 0.0


def _blob(cx, cy, r):
    from receiver.core.records import Blob
    a = np.pi * r * r
    hull = np.array([[cx - r, cy - r], [cx + r, cy - r], [cx + r, cy + r], [cx - r, cy + r]])
    return Blob(cx, cy, a, hull, int(cx - r), int(cy - r), int(cx + r) + 1, int(cy + r) + 1, False, 200.0, 50.0, 10.0)


def _tracker_stream(seed):
    """Frames of blobs: lights on a grid 150 px apart (and one close pair: two blobs in one gate,
    the solver decides) moving together and blinking out, area jumps past the ratio gate, stray
    blobs in an empty band; a camera shake per frame (None on some), frame index gaps. Returns
    the frames and {id(blob): its light} (-1 for a stray)."""
    rng = np.random.default_rng(seed)
    n = 14
    pos = np.array([(60.0 + 150 * (i % 5), 60.0 + 150 * (i // 5)) for i in range(n)])
    pos[13] = pos[0] + (9.0, 2.0)  # a close pair
    vel = np.array([2.0, -0.5]) + rng.normal(size=(n, 2)) * 0.2
    vel[13] = vel[0]
    frames, k, light, sxy = [], 0, {}, np.zeros(2)
    for step in range(40):
        k += 1 + int(rng.random() < 0.15)
        shift = None if rng.random() < 0.3 else tuple(rng.normal(size=2) * 2)
        if shift is not None:
            sxy = sxy + shift
        blobs = []
        for i in range(n):
            if rng.random() < 0.12:
                continue  # dark or missed this frame
            r = 6.0 * (3.0 if rng.random() < 0.05 else 1.0)
            x, y = pos[i] + vel[i] * k + sxy + rng.normal(size=2) * 0.4
            blobs.append(_blob(float(x), float(y), r))
            light[id(blobs[-1])] = i
        if step % 9 == 5:
            blobs.append(_blob(float(rng.uniform(0, 800)), 520.0 + float(rng.uniform(0, 40)), 4.0))
            light[id(blobs[-1])] = -1
        order = rng.permutation(len(blobs))
        frames.append((k, [blobs[j] for j in order], shift))
    return frames, light


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_tracker_follows_each_light(seed, monkeypatch):
    """The compiled tracker step on a stream whose lights are known: every track holds the blobs
    of one light (the close pair included, where the solver decides), lights that vanish past
    max_missed end, new tracks start for lights seen again and for strays."""
    from receiver.vision import track
    from receiver.vision.track import Tracker
    stream, light = _tracker_stream(seed)
    calls = []
    real = track._solver_assignment
    monkeypatch.setattr(track, "_solver_assignment", lambda d, ok: calls.append(1) or real(d, ok))
    tracker = Tracker(max_missed=2)
    held: dict[int, set] = {}
    n_ended = 0
    for k, blobs, shift in stream:
        alive = tracker.step(k, blobs, shift)
        n_ended += len(tracker.ended)
        for t in alive:
            if t.seen:
                assert t.last_frame == k and t.misses == 0
                held.setdefault(t.track_id, set()).add(light[id(t.blob)])
            else:
                assert 1 <= t.misses <= 2
    assert all(len(lights) == 1 for lights in held.values()), {t: v for t, v in held.items() if len(v) > 1}
    assert {i for v in held.values() for i in v} >= set(range(14))  # every light followed
    assert calls and n_ended > 0 and tracker._next_id > 14


def test_edge_points_of_blobs_in_one_call_equal_the_box_path():
    """The Blobs' edge points in one compiled call (`_pixels.edge_points_blobs`: the boxes of
    merged envelopes, some past the image edge, one too narrow for a run, and their points)
    equal those of the boxes `outline._boxes` gives (floor / ceil of the hulls' extremes) read by
    the box kernel; hulls the call does not take (int32) go that way."""
    import dataclasses
    from receiver.vision import outline
    leds = bench_scene(n_leds=8, radius_px=30.0, seed=3)
    frames = [render_bench_frame(leds, k, rng=np.random.default_rng(k)) for k in range(3)]
    hist = EnvelopeHistory(3)
    for k, g in enumerate(frames):
        tracks = [Track(i, b, 0, k, vx=(-700.0 if i == 2 else 0.4), vy=-0.2) for i, b in enumerate(detect(g, stripe_gap_px=12))]
        env = list(hist.step(tracks, k, g.shape).values())
    narrow = dataclasses.replace(env[0], hull=env[0].hull[:1])
    items = env + [narrow]
    gray = frames[-1]
    for kw in ({}, {"bin_rows": 1}, {"pad": 1, "border_px": 0}):
        full = dict(dict(pad=4, border_px=2, min_contrast=outline.MIN_CONTRAST, bin_rows=outline.DEFAULT_BIN_ROWS), **kw)
        a = outline.stripe_edge_points_batch(gray, items, **kw)
        b = outline._edge_points_native(gray, outline._boxes(gray, items, full["pad"]),
                                        [(np.zeros((0, 2)), np.zeros(0))] * len(items),
                                        full["border_px"], full["min_contrast"], full["bin_rows"])
        ints = [dataclasses.replace(e, hull=np.round(e.hull).astype(np.int32)) for e in items]
        assert outline._k.edge_points_blobs(gray, ints, 4, 2, 20.0, 4, 0.05, 2.0, 11) is None
        assert sum(len(p) for p, _ in outline.stripe_edge_points_batch(gray, ints, **kw)) > 50
        assert len(a) == len(b) == len(items)
        for (pa, sa), (pb, sb) in zip(a, b):
            assert np.array_equal(pa, pb) and np.array_equal(sa, sb)
        assert sum(len(p) for p, _ in a) > 50 and len(a[-1][0]) == 0
