"""Synthetic camera signal: rolling-shutter stripe period and S2-PSK pair XOR.

Hand-built scenes: a large LED seen head-on (stripes), and a close S2-PSK pair seen by a
global-shutter camera (XOR of the two emitters = the packet's symbol at that LED time).
Sensor noise stays at its defaults (thesis eq. 4), so the measurements are made on noisy frames.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_tx.framing import s2psk_packet
from receiver.io.ledmap import LedMap
from tools.synth.camera import Pose, make_camera
from tools.synth.model import Emitter, Light, RenderParams, Scene
from tools.synth.render import FrameRenderer
from tools.synth.scenes import make_scene
from tools.synth.waveform import led_drive

UP_POSE = Pose(0.0, 0.0, 1.0, yaw=0.0, pitch=90.0, roll=0.0)  # looking up: world +x = image down
DOWN = (0.0, 0.0, -1.0)
IMAGE_ACROSS = (0.0, 1.0, 0.0)  # world y = image horizontal at UP_POSE
PERIOD_RTOL = 0.01


def one_light_scene(light: Light, cam, pose=UP_POSE, n_frames=1, **params) -> Scene:
    return Scene(name="test", camera=cam, lights=[light], trajectory=lambda t: pose,
                 led_map=LedMap(addressing="map", leds={}), params=RenderParams(**params), n_frames=n_frames)


def stripe_profile(mode, rate_hz, row_readout_us, exposure_us, led_id=0x1234, seed=3):
    """Row profile (rows fully inside the LED) of a 0.3 x 0.8 m panel 2 m above the camera."""
    cam = make_camera(row_readout_us=row_readout_us, exposure_us=exposure_us)
    drive = led_drive(mode, led_id, rate_hz, phase_s=0.00123, clock_ppm=0.0)
    e = Emitter(np.array([0.0, 0.0, 3.0]), np.array(DOWN), np.array(IMAGE_ACROSS), "rect", (0.3, 0.8), drive)
    img, truth = FrameRenderer(one_light_scene(Light(led_id, mode, [e]), cam), seed=seed).render(0)
    (led,) = truth["leds"]
    r0, r1 = int(led["cy"]) - 180, int(led["cy"]) + 180  # the panel spans ~400 rows
    c0, c1 = int(led["cx"]) - 30, int(led["cx"]) + 30
    return img[r0:r1, c0:c1].astype(np.float64).mean(axis=1)


def spectral_period_rows(profile: np.ndarray, pad: int = 1 << 16) -> float:
    """Period (rows) of the strongest spectral line of a row profile (Hann window, zero padding,
    parabolic peak interpolation)."""
    x = (profile - profile.mean()) * np.hanning(len(profile))
    s = np.abs(np.fft.rfft(x, pad))
    k = int(np.argmax(s[1:])) + 1
    a, b, c = s[k - 1], s[k], s[k + 1]
    k_f = k + 0.5 * (a - c) / (a - 2 * b + c)
    return pad / k_f


@pytest.mark.parametrize("tone_hz,row_readout_us", [(2000, 15.0), (5000, 10.0), (1200, 25.0)])
def test_tone_stripe_period(tone_hz, row_readout_us):
    profile = stripe_profile("tone", tone_hz, row_readout_us, exposure_us=20.0)
    expected = 1.0 / (tone_hz * row_readout_us * 1e-6)
    assert profile.max() - profile.min() > 100  # real stripes, not a flat blob
    assert spectral_period_rows(profile) == pytest.approx(expected, rel=PERIOD_RTOL)


def edge_rows(profile: np.ndarray) -> np.ndarray:
    """Sub-row positions where the profile crosses half its range (linear interpolation)."""
    half = 0.5 * (profile.max() + profile.min())
    s = profile - half
    i = np.nonzero(np.sign(s[:-1]) != np.sign(s[1:]))[0]
    return i + s[i] / (s[i] - s[i + 1])


def test_ook_chip_period():
    """OOK chips (20 kHz, 15 us rows): every on/off edge sits on a grid of 1/(rate*t_row) = 3.33 rows.
    The grid's period is found as the period that best aligns all edges (phase coherence),
    searched over 0.6..1.6 x the expected value (excluding its sub-multiples)."""
    rate_hz, t_row_us = 20000, 15.0
    profile = stripe_profile("ook", rate_hz, t_row_us, exposure_us=20.0)
    edges = edge_rows(profile)
    assert len(edges) > 40
    expected = 1.0 / (rate_hz * t_row_us * 1e-6)
    periods = np.linspace(0.6 * expected, 1.6 * expected, 4001)
    coherence = np.abs(np.exp(2j * np.pi * edges[None, :] / periods[:, None]).mean(axis=1))
    best = periods[int(np.argmax(coherence))]
    assert best == pytest.approx(expected, rel=PERIOD_RTOL)
    assert coherence.max() > 0.9


# --- S2-PSK ------------------------------------------------------------------------------
S2_ID = 0x5A
S2_CLK_HZ = 200
S2_SYMCLK = 16
S2_FRAMES = 60
S2_EXPOSURE_US = 50.0


def s2psk_pair_scene(led_id=S2_ID, phase_s=0.3377, clock_ppm=37.0) -> Scene:
    """Emitters A and B (0.04 m squares, 0.1 m apart) 2 m above a global-shutter camera."""
    cam = make_camera(row_readout_us=0.0, exposure_us=S2_EXPOSURE_US)
    ems = []
    for pin, dy in ((0, 0.05), (1, -0.05)):
        drive = led_drive("s2psk", led_id, S2_CLK_HZ, S2_SYMCLK, pin=pin, phase_s=phase_s, clock_ppm=clock_ppm)
        ems.append(Emitter(np.array([0.0, dy, 3.0]), np.array(DOWN), np.array(IMAGE_ACROSS), "square",
                           (0.04, 0.04), drive))
    return one_light_scene(Light(led_id, "s2psk", ems), cam, n_frames=S2_FRAMES)


def patch_mean(img, cx, cy, half=3):
    u, v = int(round(cx)), int(round(cy))
    return float(img[v - half:v + half + 1, u - half:u + half + 1].mean())


def test_s2psk_xor_equals_symbol_stream():
    scene = s2psk_pair_scene()
    drive_a = scene.lights[0].emitters[0].drive
    tick_hz = 2 * S2_CLK_HZ
    symbols = s2psk_packet(S2_ID)
    on_threshold = 0.5 * scene.params.led_peak_dn
    renderer = FrameRenderer(scene, seed=11)
    t_exp = scene.camera.exposure_us * 1e-6
    used, seen_symbols, seen_a = 0, set(), set()
    for k in range(S2_FRAMES):
        img, truth = renderer.render(k)
        (led,) = truth["leds"]
        t0 = truth["t"]
        tick0 = math.floor(float(drive_a.led_time(t0)) * tick_hz)
        tick1 = math.floor(float(drive_a.led_time(t0 + t_exp)) * tick_hz)
        if tick0 != tick1:  # exposure straddles a level change: neither state is clean
            continue
        a_on = patch_mean(img, led["emitters"][0]["cx"], led["emitters"][0]["cy"]) > on_threshold
        b_on = patch_mean(img, led["emitters"][1]["cx"], led["emitters"][1]["cy"]) > on_threshold
        symbol = symbols[(tick0 // (2 * S2_SYMCLK)) % len(symbols)]
        assert a_on == (tick0 % 2 == 0), k  # PROTOCOL.md section 3: A high in each clock's first half
        assert (a_on ^ b_on) == bool(symbol), k
        used += 1
        seen_symbols.add(symbol)
        seen_a.add(a_on)
    assert used >= 0.85 * S2_FRAMES  # 50 us of 2500 us ticks straddle an edge ~2 % of the time
    assert seen_symbols == {0, 1} and seen_a == {False, True}


VEHICLE_FRAMES = range(0, 200, 17)  # spread over the 6.7 s drive: lane change and closing distance


def test_vehicle_taillight_xor_equals_symbol_stream():
    """In rendered vehicle-scene frames (rolling shutter, 15 us rows, 100 us exposure), each forward
    vehicle's taillight pair reads A XOR B = its packet's symbol at the LED time of the emitters'
    rows; A itself follows the clock (high in the first half)."""
    scene = make_scene("vehicle", seed=1)
    cam = scene.camera
    t_row, t_exp = cam.row_readout_us * 1e-6, cam.exposure_us * 1e-6
    fvs = [light for light in scene.lights if light.carrier is not None]
    renderer = FrameRenderer(scene, seed=1)
    used = 0
    for k in VEHICLE_FRAMES:
        img, truth = renderer.render(k)
        by_id = {d["id"]: d for d in truth["leds"]}
        for light in fvs:
            rec = by_id.get(light.id)
            if rec is None or not rec["visible"]:
                continue
            states, ticks = [], []
            for emitter, em in zip(light.emitters, rec["emitters"]):
                u, v = int(round(em["cx"])), int(round(em["cy"]))
                t_row_start = truth["t"] + v * t_row  # PROTOCOL.md section 2: row v's exposure start
                tick0 = math.floor(float(emitter.drive.led_time(t_row_start)) * 2 * S2_CLK_HZ)
                tick1 = math.floor(float(emitter.drive.led_time(t_row_start + t_exp)) * 2 * S2_CLK_HZ)
                if tick0 != tick1:
                    break
                level = img[v, u - 1:u + 2].astype(np.float64).mean()  # one row: one exposure time
                states.append(level > 0.5 * scene.params.led_peak_dn * light.brightness)
                ticks.append(tick0)
            if len(states) != 2 or ticks[0] // (2 * S2_SYMCLK) != ticks[1] // (2 * S2_SYMCLK):
                continue  # an edge inside an exposure, or A and B's rows straddle a symbol change
            symbol = s2psk_packet(light.id)[(ticks[0] // (2 * S2_SYMCLK)) % 30]
            assert states[0] == (ticks[0] % 2 == 0), (k, light.id)
            assert (states[0] ^ states[1]) == bool(symbol), (k, light.id)
            used += 1
    assert used >= len(VEHICLE_FRAMES)  # two vehicles per frame; most readings are clean
