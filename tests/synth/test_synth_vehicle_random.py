"""The `vehicle-random` scene (tools.synth.scenes.vehicle_random): a road drawn per seed within
the ranges the independent recordings span (head spacing, height, layout, split or merged
halves, saturation with bloom along the columns, a slow correlated camera sway with roll and
jitter, taillight baselines, a dash camera's focal length and distortion), each effect present
in the rendered frames, each switchable, every seed reproducible."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tools.synth.camera import make_camera
from tools.synth.recording import write_recording
from tools.synth.render import WHITE_DN, FrameRenderer
from tools.synth.scenes import (DASH_CAMERA_RANGES, RANDOM_HEAD_STYLES, RANDOM_LAYOUTS, RANDOM_ROAD, make_scene,
                                vehicle_random)

SEEDS = range(1, 9)
SL_MAX_ID = 0x7F  # street-light IDs; forward vehicles use 0x80-0xFF


def _road(seed, **kw):
    cam = make_camera(focal_px=1400.0)
    return vehicle_random(np.random.default_rng(seed), cam, **kw)["road"]


def test_every_drawn_value_is_within_its_range_and_seeds_differ():
    roads = [_road(s) for s in SEEDS]
    for road in roads:
        for key, (lo, hi) in RANDOM_ROAD.items():
            if key == "head_sep_m" and road["head_style"] == "merged":
                assert road[key] == road["head_half_width_m"]                # the halves touch
                continue
            assert lo <= road[key] <= hi, (key, road[key])
        assert road["light_layout"] in RANDOM_LAYOUTS
        assert road["head_style"] in RANDOM_HEAD_STYLES
    assert len({r["head_spacing_m"] for r in roads}) == len(roads)
    assert len({r["light_layout"] for r in roads}) >= 2
    assert {r["head_style"] for r in roads} == set(RANDOM_HEAD_STYLES)


def test_a_given_keyword_is_taken_instead_of_drawn_and_bad_choices_are_refused():
    from receiver.core.errors import InputError

    road = _road(3, head_style="split", head_sep_m=0.7, head_half_width_m=0.25, taillight_baseline_m=1.5,
                 bloom_frac=0.0)
    assert (road["head_style"], road["head_sep_m"], road["head_half_width_m"]) == ("split", 0.7, 0.25)
    assert road["taillight_baseline_m"] == 1.5 and road["bloom_frac"] == 0.0
    with pytest.raises(InputError, match="head_style"):
        _road(3, head_style="fused")
    with pytest.raises(InputError, match="overlap"):
        _road(3, head_sep_m=0.1, head_half_width_m=0.3)


def test_fixing_one_value_leaves_the_seeds_other_values_and_lights_as_drawn():
    """An effect switched off on the same road: every other drawn value, the IDs and the heads'
    positions stay the seed's."""
    base = make_scene("vehicle-random", seed=4, n_frames=1)
    road = _road(4)
    for key, value in (("head_style", "split" if road["head_style"] == "merged" else "merged"),
                       ("slow_shake_rms_deg", 0.0), ("light_layout", "one-side"), ("lane_change_m", -3.5)):
        other = _road(4, **{key: value})
        changed = {k for k in road if other[k] != road[k]}
        allowed = {key, "head_sep_m"} if key == "head_style" else {key}
        assert changed <= allowed and key in changed, (key, changed)
        if key != "light_layout":
            sc = make_scene("vehicle-random", seed=4, n_frames=1, **{key: value})
            assert sorted(sc.led_map.leds) == sorted(base.led_map.leds)
            assert [(led.x, led.y, led.z) for led in sc.led_map.leds.values()] == \
                [(led.x, led.y, led.z) for led in base.led_map.leds.values()]


@pytest.mark.parametrize("seed", [1, 2, 5])
def test_map_heads_follow_the_drawn_spacing_height_and_halves(seed):
    sc = make_scene("vehicle-random", seed=seed, n_frames=1)
    road = _road(seed)
    heads = sorted(sc.led_map.leds.values(), key=lambda led: (led.x, led.y))
    assert all(led.z == pytest.approx(road["light_height_m"]) for led in heads)
    xs = sorted({round(led.x, 6) for led in heads})
    assert np.median(np.diff(xs)) == pytest.approx(road["head_spacing_m"], rel=1e-6)
    for led in heads:
        a, b = np.asarray(led.emitters)
        assert led.size[0] == pytest.approx(road["head_half_width_m"])
        assert np.linalg.norm(a - b) == pytest.approx(road["head_sep_m"])
        gap = np.linalg.norm(a - b) - led.size[0]
        if road["head_style"] == "split":
            assert gap >= 0.2 - 1e-9                                          # a gap between the halves
        else:
            assert gap == pytest.approx(0.0, abs=1e-9)                        # the halves touch
    assert sc.led_map.taillight["baseline_m"] == pytest.approx(road["taillight_baseline_m"])
    tails = [lt for lt in sc.lights if lt.carrier is not None]
    assert tails and all(np.linalg.norm(lt.emitters[0].offset - lt.emitters[1].offset)
                         == pytest.approx(road["taillight_baseline_m"]) for lt in tails)
    assert sc.params.halo_frac == pytest.approx(road["halo_frac"])
    assert sc.params.bloom_frac == pytest.approx(road["bloom_frac"])


def test_each_seed_has_its_dash_camera_and_a_given_camera_value_wins():
    cams = [make_scene("vehicle-random", seed=s, n_frames=1).camera for s in SEEDS]
    for cam in cams:
        assert DASH_CAMERA_RANGES["focal_px"][0] <= cam.K[0, 0] <= DASH_CAMERA_RANGES["focal_px"][1]
        assert DASH_CAMERA_RANGES["k1"][0] <= cam.dist[0] <= DASH_CAMERA_RANGES["k1"][1]
        assert not cam.dist[1:].any()
    assert len({round(float(c.K[0, 0]), 6) for c in cams}) == len(cams)
    fixed = make_scene("vehicle-random", seed=1, n_frames=1, focal_px=1250.0, dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    assert fixed.camera.K[0, 0] == 1250.0 and not fixed.camera.dist.any()


def _series(sc, seconds=8.0, rate_hz=120.0):
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    poses = [sc.trajectory(float(x)) for x in t]
    return (t, np.array([p.yaw for p in poses]), np.array([p.pitch for p in poses]),
            np.array([p.roll for p in poses]))


def _band_power_fraction(x, rate_hz, lo_hz, hi_hz):
    """Share of the (Hann-windowed, mean-removed) power of `x` between lo_hz and hi_hz."""
    x = (x - x.mean()) * np.hanning(len(x))
    p = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / rate_hz)
    return float(p[(f >= lo_hz) & (f <= hi_hz)].sum() / p[1:].sum())


@pytest.mark.parametrize("seed", [3, 6])
def test_the_camera_sways_slowly_with_roll_and_jitter(seed):
    sc = make_scene("vehicle-random", seed=seed)
    road = _road(seed)
    fps = sc.camera.fps
    _, _, pitch, roll = _series(sc, rate_hz=fps)
    pitch = pitch - road["cam_pitch_deg"]
    # The 1.3 Hz 0.2 deg nod of vehicle_road stays on top of the drawn sway.
    assert 0.6 * road["slow_shake_rms_deg"] < np.std(pitch) < 1.6 * math.hypot(road["slow_shake_rms_deg"], 0.15)
    assert 0.5 * road["slow_shake_rms_deg"] / 2 < np.std(roll) < 1.6 * road["slow_shake_rms_deg"] / 2
    # Correlated: over three frames the sway moves a light by several px (the jitter alone ~1 px).
    step3 = np.abs(pitch[3:] - pitch[:-3])
    assert np.percentile(step3, 90) * math.radians(1.0) * sc.camera.K[0, 0] > 3.0
    # The jitter is held over a frame period: the same scene without it differs by one value
    # per frame (the sway is drawn before the jitter, so it is the same).
    still = make_scene("vehicle-random", seed=seed, jitter_deg=0.0)
    jit = [sc.trajectory(t).roll - still.trajectory(t).roll for t in (1.001, 1.02, 1.04)]
    assert jit[0] == pytest.approx(jit[1], abs=1e-12) and abs(jit[2] - jit[1]) > 1e-6


@pytest.mark.parametrize("seed", [3, 6])
def test_the_sway_spectrum_lies_in_the_slow_band(seed):
    """Without the frame jitter, the pitch and roll motion is 0.5-2.5 Hz: at least 90 % of its
    power there (the rest is the window's leakage), and almost none above 5 Hz."""
    sc = make_scene("vehicle-random", seed=seed, jitter_deg=0.0)
    rate = 120.0
    _, _, pitch, roll = _series(sc, rate_hz=rate)
    for x in (pitch, roll):
        assert _band_power_fraction(x, rate, 0.5, 2.5) > 0.9
        assert _band_power_fraction(x, rate, 5.0, rate / 2) < 1e-3


def test_the_sway_and_jitter_switch_off():
    sc = make_scene("vehicle-random", seed=3, slow_shake_rms_deg=0.0, jitter_deg=0.0, cam_pitch_deg=3.0)
    _, _, pitch, roll = _series(sc, rate_hz=30.0)
    assert np.all(roll == 0.0)
    assert np.max(np.abs(pitch - 3.0)) <= 0.2 + 1e-9                     # only the 0.2 deg nod is left


def _lit_heads(sc, seed, frames, max_m, want):
    """(img, truth led) of near street lights whose two halves are both lit (each peaks at the
    white level) in frames `frames`, until `want` are found."""
    fr = FrameRenderer(sc, seed=seed)
    found = []
    for k in frames:
        img, truth = fr.render(k)
        for led in truth["leds"]:
            if led["id"] > SL_MAX_ID or not led["visible"] or led["distance_m"] > max_m:
                continue
            peaks = []
            for e in led["emitters"]:
                x, y = int(round(e["cx"])), int(round(e["cy"]))
                peaks.append(img[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2].max())
            if min(peaks) == WHITE_DN:
                found.append((img, led))
        if len(found) >= want:
            break
    return found


def _blob_labels(img, black_dn):
    return cv2.connectedComponentsWithStats((img >= black_dn + 15).astype(np.uint8))


def test_split_halves_are_two_blobs_at_their_projected_separation():
    """Both halves lit: two blobs, each saturated and bloomed past its true image area, whose
    centroids are as far apart as the two emitters' projected centres."""
    sc = make_scene("vehicle-random", seed=2, head_style="split", head_sep_m=0.6, head_half_width_m=0.25)
    found = _lit_heads(sc, 2, range(0, 90, 3), 60.0, 3)
    assert len(found) >= 3
    for img, led in found:
        _, lab, stats, cents = _blob_labels(img, sc.params.black_level_dn)
        ea, eb = led["emitters"]
        la = lab[int(round(ea["cy"])), int(round(ea["cx"]))]
        lb = lab[int(round(eb["cy"])), int(round(eb["cx"]))]
        assert la and lb and la != lb, led["id"]
        for lbl, e in ((la, ea), (lb, eb)):
            assert stats[lbl, cv2.CC_STAT_AREA] >= 1.5 * e["area_px"], (led["id"], e)
        truth_sep = math.hypot(ea["cx"] - eb["cx"], ea["cy"] - eb["cy"])
        blob_sep = float(np.linalg.norm(cents[la] - cents[lb]))
        assert truth_sep > 4.0
        assert blob_sep == pytest.approx(truth_sep, abs=1.0), led["id"]


def test_merged_halves_are_one_blob():
    sc = make_scene("vehicle-random", seed=2, head_style="merged", head_half_width_m=0.25)
    found = _lit_heads(sc, 2, range(0, 90, 3), 60.0, 3)
    assert len(found) >= 3
    for img, led in found:
        _, lab, _, _ = _blob_labels(img, sc.params.black_level_dn)
        la, lb = (lab[int(round(e["cy"])), int(round(e["cx"]))] for e in led["emitters"])
        assert la and la == lb, led["id"]


def _quiet(seed, **kw):
    return make_scene("vehicle-random", seed=seed, n_frames=1, read_noise_dn=0.0, shot_noise_alpha=0.0,
                      frame_jitter_us=0.0, halo_frac=0.0, head_style="split", **kw)


def test_saturated_pixels_sit_at_the_white_level_and_bloom_spills_along_columns():
    """Noise-free renders of frames with and without column bloom: the saturated pixels are
    at the white level; bloom adds charge above and below a saturated blob in its columns and
    none beside it in its rows; the dimmed switch (heads and taillights at brightness 1, no bloom)
    saturates nothing."""
    on = _quiet(4, light_brightness=3.0, bloom_frac=0.1, bloom_len_px=3.0)
    off = _quiet(4, light_brightness=3.0, bloom_frac=0.0)
    checked = 0
    for k in range(0, 60, 6):
        checked += _check_column_bloom(on, off, k)
        if checked >= 2:
            break
    assert checked >= 2
    dim = _quiet(4, light_brightness=1.0, taillight_brightness=1.0, bloom_frac=0.0)
    img_dim, _ = FrameRenderer(dim, seed=4).render(0)
    assert img_dim.max() < WHITE_DN


def _check_column_bloom(on, off, k):
    """Frame k of `on` (bloom) against `off` (none) around each saturated half: the number checked."""
    img_on, truth = FrameRenderer(on, seed=4).render(k)
    img_off, _ = FrameRenderer(off, seed=4).render(k)
    assert img_on.max() <= WHITE_DN and img_off.max() <= WHITE_DN
    _, lab, stats, _ = _blob_labels(img_off, on.params.black_level_dn)
    checked = 0
    for led in truth["leds"]:
        for e in led.get("emitters", ()):
            x, y = int(round(e["cx"])), int(round(e["cy"]))
            lbl = lab[y, x]
            if not lbl or np.count_nonzero((lab == lbl) & (img_off == WHITE_DN)) < 10:
                continue            # not saturated, or too little excess charge to show
            x0, y0, w, h = (stats[lbl, i] for i in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH,
                                                     cv2.CC_STAT_HEIGHT))
            cols = slice(x0 + w // 4, x0 + w - w // 4)
            above = slice(max(y0 - 4, 0), y0)
            below = slice(y0 + h, min(y0 + h + 4, img_on.shape[0]))
            spill = (img_on[above, cols].astype(int) - img_off[above, cols]).sum() \
                + (img_on[below, cols].astype(int) - img_off[below, cols]).sum()
            assert spill > 0, (led["id"], e)
            rows = slice(y0 + h // 4, y0 + h - h // 4 + 1)
            beside = np.concatenate([img_on[rows, max(x0 - 4, 0):x0], img_on[rows, x0 + w:x0 + w + 4]], axis=1)
            beside_off = np.concatenate([img_off[rows, max(x0 - 4, 0):x0], img_off[rows, x0 + w:x0 + w + 4]], axis=1)
            assert np.array_equal(beside, beside_off), (led["id"], e)
            assert img_off[lab == lbl].max() == WHITE_DN
            checked += 1
    return checked


def test_a_seed_renders_the_same_recording_twice_and_another_seed_differs(tmp_path):
    paths = []
    for run, seed in (("a", 5), ("b", 5), ("c", 6)):
        out = tmp_path / run
        write_recording(make_scene("vehicle-random", seed=seed, n_frames=2), str(out), seed=seed, codec="mjpeg",
                        progress=False)
        paths.append(out)
    a, b, c = ({n: (p / n).read_bytes() for n in ("video.avi", "truth.jsonl", "map.json", "camera.yaml")}
               for p in paths)
    assert a == b
    assert a["truth.jsonl"] != c["truth.jsonl"] and a["map.json"] != c["map.json"]
    assert a["camera.yaml"] != c["camera.yaml"]


def test_the_host_wanders_and_changes_lane_as_drawn_and_the_cars_gaps_scale():
    """Truth of the host's lateral position: the drawn lane change plus a wander of at most
    `wander_m`; the cars' gaps at the start are `FV_SCRIPT`'s times `fv_gap_scale`."""
    from tools.synth.scenes import FV_SCRIPT, RANDOM_LANE_CHANGES_M, smoothstep5

    roads = [_road(s) for s in SEEDS]
    assert len({r["lane_change_m"] for r in roads}) >= 2
    assert all(r["lane_change_m"] in RANDOM_LANE_CHANGES_M for r in roads)
    for seed in (2, 7):
        road = _road(seed)
        sc = make_scene("vehicle-random", seed=seed)
        t = np.arange(0.0, 8.0, 0.1)
        lateral = np.array([sc.extra_truth(x)["vehicle"]["hv"]["lateral_m"] for x in t])
        change = np.array([road["lane_change_m"] * smoothstep5((x - road["lane_change_start_s"]) / 3.5) for x in t])
        wander = lateral - change
        assert np.max(np.abs(wander)) <= road["wander_m"] + 1e-4
        assert np.ptp(wander) > 0.5 * road["wander_m"] * min(1.0, 2 * math.pi * road["wander_hz"] * 8.0 / 2)
        fv = sc.extra_truth(0.0)["vehicle"]
        gaps = sorted(f["s_m"] - fv["hv"]["s_m"] for f in fv["fv"])
        assert gaps == pytest.approx(sorted(spec[1] * road["fv_gap_scale"] for spec in FV_SCRIPT), abs=1e-4)
    still = make_scene("vehicle-random", seed=2, wander_m=0.0, lane_change_m=0.0)
    assert all(still.extra_truth(x)["vehicle"]["hv"]["lateral_m"] == 0.0 for x in (0.0, 3.0, 6.0))


def _taillight_peaks(sc, frames):
    """Peak value around each visible taillight emitter's centre (in the image) over `frames`."""
    fr = FrameRenderer(sc, seed=1)
    peaks = []
    for k in frames:
        img, truth = fr.render(k)
        for led in truth["leds"]:
            if led["id"] <= SL_MAX_ID or not led["visible"]:
                continue
            for e in led["emitters"]:
                x, y = int(round(e["cx"])), int(round(e["cy"]))
                peaks.append(int(img[max(y - 2, 0):y + 3, max(x - 2, 0):x + 3].max()))
    return np.array(peaks)


def test_lit_taillights_saturate_unless_dimmed():
    """Every lit taillight (peak well above the background) is at the white level; at
    brightness 1 none is."""
    frames = range(0, 40, 4)
    bright = _taillight_peaks(make_scene("vehicle-random", seed=1, taillight_brightness=2.0), frames)
    lit = bright[bright > 60]
    assert len(lit) >= 10 and np.all(lit == WHITE_DN)
    dim = _taillight_peaks(make_scene("vehicle-random", seed=1, taillight_brightness=1.0), frames)
    assert np.count_nonzero(dim > 60) >= 10 and dim.max() < WHITE_DN
