"""Scenes of the experiments that the synthetic camera's own scenes (`tools.synth.scenes`) do not
cover: a single LED on the optical axis (the thesis's lab set-up, Figure 40), a ceiling grid of
small panels at any height (Figure 32) and a straight night road with street lights and one
forward vehicle at a chosen speed (Figures 37-39). Geometry conventions: `tools.synth.camera`.

`build_scene(builder, seed, n_frames, kwargs)` splits `kwargs` like `tools.synth.make_scene`:
camera keywords (`make_camera`), sensor keywords (`RenderParams`) and the builder's own.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from receiver.io.ledmap import LedMap
from tools.synth.camera import Pose, make_camera
from tools.synth.model import Body, RenderParams, Scene
from tools.synth.scenes import (CAMERA_DEFAULTS, OOK_RATE_HZ, S2PSK_CLOCK_HZ, S2PSK_SYMCLK, _shake, ceiling_light,
                                make_scene, map_entry, s2psk_pair)

PHONE = CAMERA_DEFAULTS["indoor-static"]  # the synthetic smartphone: 1280x720, 1000 px focal
DASHCAM = CAMERA_DEFAULTS["vehicle-road"]  # the synthetic dash camera: 1280x720, 1200 px focal


def lab_led(rng, cam, distance_m=1.0, diameter_m=0.15, length_m=None, offset_m=(0.05, 0.0), seconds=0.4):
    """One OOK LED facing down at `distance_m` above a still camera that looks straight up: a
    circle of `diameter_m`, or with `length_m` a rectangle `diameter_m` wide (image columns) and
    `length_m` long (image rows). It sits `offset_m` (x, y) off the camera's axis so that its
    image is not centred on a pixel corner by construction. The thesis's lab set-up (Figure 40)."""
    led_id = int(rng.integers(1, 1 << 16))
    shape, size = ("circle", (diameter_m,)) if length_m is None else ("rect", (diameter_m, length_m))
    light = ceiling_light(rng, led_id, (1.0 + offset_m[0], 1.0 + offset_m[1], distance_m), shape, size)
    pose = Pose(1.0, 1.0, 0.0, yaw=0.0, pitch=90.0, roll=0.0)
    return dict(lights=[light], led_map=LedMap(addressing="map", leds={led_id: map_entry(light, rate_hz=OOK_RATE_HZ)}),
                trajectory=lambda t: pose, n_frames=int(round(seconds * cam.fps)),
                description="one circular LED above a camera looking up")


def pair_lab(rng, cam, distance_m=60.0, head_half_m=(0.4, 0.3), head_gap_m=0.5, clk_hz=S2PSK_CLOCK_HZ,
             symbol_clocks=S2PSK_SYMCLK, seconds=4.0):
    """One S2-PSK street-light head (two halves of `head_half_m`, centres `head_gap_m` apart,
    PROTOCOL.md section 3) facing a still camera `distance_m` away on its axis: at 60 m with the
    1200 px dash camera each half is 8 x 6 px and the halves 2 px apart, so a channel blur of
    about a pixel mixes them (Figure 34's Gaussian channel filter)."""
    led_id = int(rng.integers(0, 0x80))
    light = s2psk_pair(rng, led_id, (distance_m, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), head_half_m,
                       head_gap_m, clk_hz, symbol_clocks)
    pose = Pose(0.0, 0.0, 0.0, yaw=0.0, pitch=0.0, roll=0.0)
    led_map = LedMap(addressing="map", leds={led_id: map_entry(light, rate_hz=clk_hz, symbol_clocks=symbol_clocks)})
    return dict(lights=[light], led_map=led_map, trajectory=lambda t: pose, n_frames=int(round(seconds * cam.fps)),
                description="one S2-PSK head facing the camera")


def ceiling_grid(rng, cam, ceiling_m=3.0, panel_m=0.10, pitch_per_m=0.3, camera_height_m=1.0, tilt_deg=2.0,
                 seconds=1.0):
    """A still camera `camera_height_m` above the floor, looking up (tilted `tilt_deg`), under a
    ceiling at `ceiling_m` with `panel_m` square OOK panels (Table 2: 10 x 10 cm, 20 kHz) every
    `pitch_per_m` times the camera-ceiling distance, so that about the same number of panels
    (~8 with the phone camera) is in view at any height and only their image size changes; the
    panels cover the camera's whole view (and a margin)."""
    fx = float(cam.K[0, 0])
    h = max(ceiling_m - camera_height_m, 0.1)
    pitch_m = pitch_per_m * h
    half = 0.5 * max(cam.width, cam.height) / fx * h * 1.3 + pitch_m
    n = int(math.ceil(half / pitch_m))
    offs = (np.arange(-n, n + 1) + 0.37) * pitch_m  # the camera is not under a panel's centre
    ids = iter(rng.choice(1 << 16, size=len(offs) ** 2, replace=False))
    lights = [ceiling_light(rng, int(next(ids)), (x, y, ceiling_m), "square", (panel_m, panel_m))
              for x in offs for y in offs]
    led_map = LedMap(addressing="map", leds={lt.id: map_entry(lt, rate_hz=OOK_RATE_HZ) for lt in lights})
    pose = Pose(0.0, 0.0, camera_height_m, yaw=10.0, pitch=90.0 - tilt_deg, roll=0.0)
    return dict(lights=lights, led_map=led_map, trajectory=lambda t: pose, n_frames=int(round(seconds * cam.fps)),
                description="still camera under a grid of small panels")


def night_road(rng, cam, hv_kmh=50.0, fv_kmh=None, fv_gap_m=30.0, light_spacing_m=25.0, light_height_m=7.0,
               light_offset_y_m=6.0, head_half_m=(0.4, 0.3), head_gap_m=0.5, cam_height_m=1.2, cam_pitch_deg=8.0,
               shake_deg=0.3, taillight_size_m=(0.15, 0.10), taillight_baseline_m=1.4, taillight_height_m=1.0,
               start_x_m=-30.0, seconds=4.0):
    """A straight night road (Table 2): down-facing S2-PSK street-light heads `light_height_m`
    high every `light_spacing_m`, alternating sides at +-`light_offset_y_m` (as in
    `tools.synth.scenes.vehicle_road`), the host vehicle (HV) in the lane y = 0 at a constant
    `hv_kmh` from x = `start_x_m`, its camera shaken by road vibration (`shake_deg`, per axis
    at most), and, unless `fv_kmh` is None, one forward vehicle (FV) in the same lane starting
    `fv_gap_m` ahead at a constant `fv_kmh`, with an opaque body. Truth adds "vehicle":
    {"hv": {x, y, speed_mps}, "fv": [{id, distance_m, angle_deg, visible, ...}]} like the synth's
    vehicle scenes."""
    positions = []
    span = start_x_m + hv_kmh / 3.6 * seconds + 400.0
    for x in np.arange(0.0, span, light_spacing_m):
        positions.append((float(x), light_offset_y_m))
        positions.append((float(x) + light_spacing_m / 2, -light_offset_y_m))
    sl_ids = rng.choice(0x80, size=min(len(positions), 0x80), replace=False)
    lights, entries = [], {}
    for (x, y), sid in zip(positions, sl_ids):
        lt = s2psk_pair(rng, int(sid), (x, y, light_height_m), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), head_half_m,
                        head_gap_m, S2PSK_CLOCK_HZ, S2PSK_SYMCLK)
        lights.append(lt)
        entries[lt.id] = map_entry(lt, rate_hz=S2PSK_CLOCK_HZ, symbol_clocks=S2PSK_SYMCLK)
    v_hv = hv_kmh / 3.6
    carriers, bodies, fv_id = {}, [], None
    if fv_kmh is not None:
        fv_id = int(rng.choice(np.arange(0x80, 0x100)))
        v_fv = fv_kmh / 3.6

        def fv(t):
            return np.array([start_x_m + fv_gap_m + v_fv * t, 0.0, 0.0]), 0.0

        carriers["fv"] = fv
        bodies.append(Body("fv"))
        lights.append(s2psk_pair(rng, fv_id, (0.0, 0.0, taillight_height_m), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                 taillight_size_m, taillight_baseline_m, S2PSK_CLOCK_HZ, S2PSK_SYMCLK, carrier="fv"))
    taillight = {"shape": "rect", "size": list(taillight_size_m), "baseline_m": taillight_baseline_m}
    led_map = LedMap(addressing="map", leds=entries, taillight=taillight)
    shake_pitch, shake_yaw = _shake(rng, shake_deg), _shake(rng, shake_deg)

    def trajectory(t):
        return Pose(start_x_m + v_hv * t, 0.0, cam_height_m, yaw=shake_yaw(t), pitch=cam_pitch_deg + shake_pitch(t),
                    roll=0.0)

    def extra_truth(t, leds=()):
        pose = trajectory(t)
        fvs = []
        if fv_id is not None:
            vis = {d["id"]: d["visible"] for d in leds}
            pos, _ = carriers["fv"](t)
            rel = pos + np.array([0.0, 0.0, taillight_height_m]) - pose.position
            fvs.append({"id": fv_id, "x": float(rel[0]), "y": float(rel[1]),
                        "distance_m": float(np.linalg.norm(rel)),
                        "angle_deg": math.degrees(math.atan2(rel[1], rel[0])) - pose.yaw,
                        "visible": bool(vis.get(fv_id, False)), "speed_mps": v_fv})
        return {"vehicle": {"hv": {"x": pose.x, "y": pose.y, "speed_mps": v_hv}, "fv": fvs}}

    return dict(lights=lights, led_map=led_map, trajectory=trajectory, carriers=carriers, bodies=bodies,
                extra_truth=extra_truth, n_frames=int(round(seconds * cam.fps)),
                description="straight night road, street lights, one forward vehicle")


BUILDERS = {"lab-led": (lab_led, PHONE, {}), "ceiling-grid": (ceiling_grid, PHONE, {}),
            "pair-lab": (pair_lab, DASHCAM, dict(psf_sigma_px=0.7)),
            "night-road": (night_road, DASHCAM, dict(psf_sigma_px=0.7))}
CAMERA_KEYS = tuple(inspect.signature(make_camera).parameters)
PARAM_KEYS = tuple(RenderParams.__dataclass_fields__)


def builder_source(builder: str) -> str:
    """The source of an experiments' builder and of `build_scene` ('' for a tools.synth scene, whose
    source the cache hashes with the rest of tools/synth)."""
    if builder not in BUILDERS:
        return ""
    return inspect.getsource(BUILDERS[builder][0]) + repr(BUILDERS[builder][1:]) + inspect.getsource(build_scene)


def build_scene(builder: str, seed: int, n_frames: int | None, kwargs: dict) -> Scene:
    """The Scene of `builder` (a tools.synth scene name or a key of BUILDERS) with `kwargs`."""
    if builder not in BUILDERS:
        return make_scene(builder, seed=seed, n_frames=n_frames, **kwargs)
    fn, cam_defaults, par_defaults = BUILDERS[builder]
    cam_kw, par_kw, own = dict(cam_defaults), dict(par_defaults), {}
    for k, v in kwargs.items():
        (cam_kw if k in CAMERA_KEYS else par_kw if k in PARAM_KEYS else own)[k] = v
    cam = make_camera(**cam_kw)
    built = fn(np.random.default_rng(seed), cam, **own)
    if n_frames is not None:
        built["n_frames"] = int(n_frames)
    return Scene(name=builder, camera=cam, params=RenderParams(**par_kw), **built)
