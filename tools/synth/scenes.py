"""Scenes of the synthetic camera (thesis Table 2 values as defaults, all overridable).

`make_scene(name, seed=0, **overrides)` builds a `Scene`. Overrides are split three ways:
camera keywords (`width, height, focal_px, dist, pixel_size_um, row_readout_us, exposure_us,
fps`; see `tools.synth.camera.make_camera`), sensor keywords (the fields of
`tools.synth.model.RenderParams`) and the scene builder's own keywords (documented on each
builder below). `seed` fixes the scene's random choices (IDs, LED phases, clock errors);
the noise of each frame is seeded separately by `render_frames(..., seed=...)`.

Camera pose convention: `tools.synth.camera` (yaw about world z, pitch raises the optical
axis, pitch = +90 looks straight up; at yaw = 0, pitch = 90 the image's down direction is
world +x and its right is world -y).
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from receiver.io.ledmap import Led, LedMap
from tools.synth.camera import Pose, make_camera
from tools.synth.model import Body, Emitter, Light, RenderParams, Scene
from tools.synth.phone import draw_phone
from tools.synth.waveform import led_drive

SCENES = ("indoor-walk", "indoor-static", "indoor-sparse", "indoor-phone", "vehicle", "vehicle-road",
          "vehicle-random")
CAMERA_KEYS = tuple(inspect.signature(make_camera).parameters)
PARAM_KEYS = tuple(RenderParams.__dataclass_fields__)
DOWN = np.array([0.0, 0.0, -1.0])
OOK_RATE_HZ = 20000  # PROTOCOL.md section 2 default chip rate (Table 2: 20 kbps)
S2PSK_CLOCK_HZ = 200  # PROTOCOL.md section 3 default
S2PSK_SYMCLK = 16
CLOCK_PPM_SPREAD = 50.0  # crystal oscillators: tens of ppm


def _require_positive(**values) -> None:
    """InputError unless every value is a positive number (lengths a road is built from)."""
    from receiver.core.errors import InputError

    for key, value in values.items():
        if not value > 0:
            raise InputError(f"bad --set value: {key} must be positive, not {value!r}")


def _require_non_negative(**values) -> None:
    """InputError unless every value is a number >= 0 (a brightness, a rate, a start time)."""
    from receiver.core.errors import InputError

    for key, value in values.items():
        if not value >= 0:
            raise InputError(f"bad --set value: {key} must not be negative, not {value!r}")


def _drive(rng, mode, led_id, rate_hz, symclk=S2PSK_SYMCLK, pin=0, phase_s=None, ppm=None):
    d = led_drive(mode, led_id, rate_hz, symclk, pin=0)
    phase = float(rng.uniform(0.0, d.period_s)) if phase_s is None else phase_s
    ppm = float(rng.uniform(-CLOCK_PPM_SPREAD, CLOCK_PPM_SPREAD)) if ppm is None else ppm
    return led_drive(mode, led_id, rate_hz, symclk, pin=pin, phase_s=phase, clock_ppm=ppm)


def ceiling_light(rng, led_id, xyz, shape, size, mode="ook", rate_hz=OOK_RATE_HZ, u_axis=(0.0, 1.0, 0.0),
                  **light_kw) -> Light:
    """A downward-facing luminaire at `xyz`; for rect, width along `u_axis`, length across it."""
    e = Emitter(np.asarray(xyz, float), DOWN.copy(), np.asarray(u_axis, float), shape, tuple(size),
                _drive(rng, mode, led_id, rate_hz))
    return Light(led_id, mode, [e], **light_kw)


def map_entry(light: Light, rate_hz=None, freq_hz=None, symbol_clocks=None) -> Led:
    c = light.offset
    e = light.emitters[0]
    emitters = None
    if len(light.emitters) == 2:
        emitters = tuple(tuple(float(v) for v in em.offset) for em in light.emitters)
    # INTERFACES.md: a mapped LED faces down unless the map says otherwise (tilted heads do).
    n = np.asarray(e.normal, float) / np.linalg.norm(e.normal)
    normal = None if np.allclose(n, (0.0, 0.0, -1.0)) else tuple(round(float(v), 9) for v in n)
    return Led(id=light.id, mode=light.mode, x=float(c[0]), y=float(c[1]), z=float(c[2]), shape=e.shape,
               size=tuple(float(s) for s in e.size), rate_hz=rate_hz, freq_hz=freq_hz,
               symbol_clocks=symbol_clocks, emitters=emitters, normal=normal)


def panel_grid(rng, room_m, pitch_m, ceiling_m, shape, size, rate_hz):
    """OOK panels on a regular ceiling grid of a square room: (lights, map). `pitch_m` (along x,
    along y); panels at half a pitch from the walls; IDs distinct random 16-bit, drawn before
    the panels' drives (the order the bundled recordings were rendered with)."""
    xs = np.arange(pitch_m[0] / 2, room_m, pitch_m[0])
    ys = np.arange(pitch_m[1] / 2, room_m, pitch_m[1])
    ids = iter(rng.choice(1 << 16, size=len(xs) * len(ys), replace=False))
    lights = [ceiling_light(rng, int(next(ids)), (x, y, ceiling_m), shape, tuple(size), rate_hz=rate_hz)
              for x in xs for y in ys]
    return lights, LedMap(addressing="map", leds={lt.id: map_entry(lt, rate_hz=rate_hz) for lt in lights})


def indoor_walk(rng, cam, room_m=12.0, ceiling_m=3.0, panel_size_m=(0.3, 0.6), pitch_x_m=0.8, pitch_y_m=0.5,
                rate_hz=OOK_RATE_HZ, height_m=1.0, speed_mps=1.0, tilt_deg=3.0, start_xy=(3.0, 4.0),
                heading_deg=20.0, seconds=4.0):
    """Smartphone walking under a ceiling of OOK panels, camera looking up (map addressing).

    Why these panels: the receiver must read a 54-chip OOK packet within ~3 frames of an LED
    entering view. One LED image of height h rows shows ``h * rate_hz * row_readout_us * 1e-6``
    chips per frame, i.e. h / (rows per chip). With 1000 px focal length, a 2 m camera-ceiling
    distance, 15 us rows and 20 kHz chips (3.33 rows per chip, exposure 20 us < one 50 us
    chip), a thesis 10x10 cm panel is only ~50 rows = 15 chips. So the walk uses 0.3 x 0.6 m
    panels (a common ceiling size) with the 0.6 m length along the image's vertical (world x
    at yaw 0): ~300 rows = 90 chips per frame, more than a whole packet in every frame.
    Field of view at 2 m: 2.56 m (image x, world y) by 1.44 m (image y, world x). With panel
    pitch 0.8 m along x and 0.5 m along y, at least floor((1.44-0.6)/0.8) = 1 panel row and
    floor((2.56-0.3)/0.5) = 4 panel columns are always fully inside the view, so >= 4 LEDs
    are fully in view (typically 5-8), with ~3 deg of tilt. IDs: distinct random 16-bit.
    """
    lights, led_map = panel_grid(rng, room_m, (pitch_x_m, pitch_y_m), ceiling_m, "rect", panel_size_m, rate_hz)
    h = math.radians(heading_deg)
    x0, y0 = start_xy
    tilt = tilt_deg

    def trajectory(t):
        # A smooth walk: constant speed along a gently curving path, 1.8 Hz step bob, and the
        # hand's slow pitch/roll wobble of a few degrees.
        a = h + 0.15 * math.sin(0.6 * t)
        return Pose(x0 + speed_mps * (t * math.cos(h) + 0.4 * math.sin(0.6 * t) * -math.sin(h)),
                    y0 + speed_mps * (t * math.sin(h) + 0.4 * math.sin(0.6 * t) * math.cos(h)),
                    height_m + 0.02 * math.sin(2 * math.pi * 1.8 * t),
                    yaw=math.degrees(a - h) * 0.3 + 0.0 * a,
                    pitch=90.0 - tilt * math.sin(2 * math.pi * 0.35 * t + 0.5),
                    roll=tilt * 0.8 * math.sin(2 * math.pi * 0.45 * t + 1.3))

    return dict(lights=lights, led_map=led_map, trajectory=trajectory, n_frames=int(round(seconds * cam.fps)),
                description="indoor walk under 0.3x0.6 m OOK panels")


def indoor_static(rng, cam, ceiling_m=3.0, camera_xyz=(2.0, 2.0, 1.0), rate_hz=OOK_RATE_HZ, tone_hz=2000,
                  seconds=2.0):
    """Still camera looking straight up under LEDs of several sizes and shapes.

    Image areas span ~150 px (3 cm circle) to ~10000 px (0.15 x 0.3 m rect, 0.2 m square),
    for distance-from-area accuracy and BER sweeps. One tone-mode LED (2 kHz). The camera is
    at `camera_xyz` with yaw 0, pitch 90, roll 0: world +x is image down, world +y image left.
    """
    cx, cy, _ = camera_xyz
    # (dx, dy, shape, size, mode): offsets from the point above the camera, metres.
    layout = [(-0.45, 0.90, "circle", (0.03,), "ook"), (0.45, 0.90, "square", (0.05, 0.05), "ook"),
              (0.0, 0.45, "square", (0.10, 0.10), "ook"), (-0.35, -0.30, "circle", (0.15,), "ook"),
              (0.30, -0.80, "square", (0.20, 0.20), "ook"), (0.0, 0.0, "rect", (0.15, 0.30), "ook"),
              (-0.45, -0.95, "square", (0.10, 0.10), "tone"), (0.45, 0.30, "square", (0.10, 0.10), "ook")]
    ids = rng.choice(1 << 16, size=len(layout), replace=False)
    lights, entries = [], {}
    for (dx, dy, shape, size, mode), led_id in zip(layout, ids):
        rate = tone_hz if mode == "tone" else rate_hz
        lt = ceiling_light(rng, int(led_id), (cx + dx, cy + dy, ceiling_m), shape, size, mode=mode, rate_hz=rate)
        lights.append(lt)
        entries[lt.id] = map_entry(lt, rate_hz=None if mode == "tone" else rate,
                                   freq_hz=rate if mode == "tone" else None)
    pose = Pose(*camera_xyz, yaw=0.0, pitch=90.0, roll=0.0)
    return dict(lights=lights, led_map=LedMap(addressing="map", leds=entries), trajectory=lambda t: pose,
                n_frames=int(round(seconds * cam.fps)), description="still camera under LEDs of several sizes")


def indoor_sparse(rng, cam, room_m=9.0, ceiling_m=2.8, panel_m=0.25, pitch_m=1.1, rate_hz=OOK_RATE_HZ,
                  height_m=1.15, speed_mps=0.8, tilt_deg=(15.0, 30.0), start_xy=(2.2, 3.1), heading_deg=10.0,
                  seconds=2.0, turn_rad=0.1, turn_rate_rad_s=0.8, tilt_hz=0.3):
    """Walking with a phone held as people hold it, under a sparse ceiling: 0.25 m square OOK
    panels on a 1.1 m grid, ceiling 2.8 m, camera 1.1-1.2 m above the floor and tilted 15-30
    degrees from vertical towards the walking direction (the tilt swings between the two limits
    at 0.3 Hz, with a few degrees of roll wobble and the step bob). At ~1.7 m from the
    ceiling the 40 x 65 degree view covers ~1.2 x 2.1 m of it, so one or two whole panels are in
    view at a time; each is ~140 rows tall (~42 chips per frame, less than a 54-chip packet, so
    a new panel needs two or three frames to be decoded). IDs: distinct random 16-bit.
    `turn_rad` / `turn_rate_rad_s`: the heading swings by this amplitude at this angular
    frequency (a phone turning at up to their product, rad/s); `tilt_hz`: the rate of the tilt's
    swing.
    """
    lights, led_map = panel_grid(rng, room_m, (pitch_m, pitch_m), ceiling_m, "square", (panel_m, panel_m), rate_hz)
    h = math.radians(heading_deg)
    x0, y0 = start_xy
    t_lo, t_hi = tilt_deg

    def trajectory(t):
        a = h + turn_rad * math.sin(turn_rate_rad_s * t)
        tilt = 0.5 * (t_lo + t_hi) + 0.5 * (t_hi - t_lo) * math.sin(2 * math.pi * tilt_hz * t)
        return Pose(x0 + speed_mps * t * math.cos(h) - 0.1 * math.sin(0.8 * t) * math.sin(h),
                    y0 + speed_mps * t * math.sin(h) + 0.1 * math.sin(0.8 * t) * math.cos(h),
                    height_m + 0.02 * math.sin(2 * math.pi * 1.8 * t),
                    yaw=math.degrees(a), pitch=90.0 - tilt, roll=3.0 * math.sin(2 * math.pi * 0.45 * t + 1.3))

    return dict(lights=lights, led_map=led_map, trajectory=trajectory, n_frames=int(round(seconds * cam.fps)),
                description="walk under sparse 0.25 m square panels, phone tilted 15-30 deg")


def s2psk_pair(rng, led_id, centre, normal, across, half_size, gap_m, clk_hz, symclk, carrier=None,
               brightness=1.0) -> Light:
    """An S2-PSK pair: emitters A (pin A) at centre + across*gap/2 and B at centre - across*gap/2,
    sharing one schedule and one clock (so B = A XOR symbol at every instant)."""
    d = _drive(rng, "s2psk", led_id, clk_hz, symclk)
    ems = []
    for pin, sgn in ((0, 1.0), (1, -1.0)):
        drive = led_drive("s2psk", led_id, clk_hz, symclk, pin=pin, phase_s=d.phase_s,
                          clock_ppm=(d.clock_scale - 1.0) * 1e6)
        ems.append(Emitter(np.asarray(centre, float) + sgn * np.asarray(across, float) * gap_m / 2,
                           np.asarray(normal, float), np.asarray(across, float), "rect", tuple(half_size), drive))
    return Light(led_id, "s2psk", ems, brightness=brightness, carrier=carrier)


def road_point(s_m: float, lateral_m: float, curve_radius_m: float | None = None):
    """Road frame -> world: (x, y, heading_rad) of the point `lateral_m` left of the centre line
    (the host lane's centre) at arc length `s_m` along it. Straight road (None): x = s, y =
    lateral, heading 0. Curve of radius R (> 0 bends left, < 0 right) starting at the origin
    heading +x: centre of curvature at (0, R), heading s / R."""
    if curve_radius_m is None:
        return float(s_m), float(lateral_m), 0.0
    R = float(curve_radius_m)
    a = s_m / R
    return (R - lateral_m) * math.sin(a), R - (R - lateral_m) * math.cos(a), a


def smoothstep5(u: float) -> float:
    """Quintic 0 -> 1 ramp on u in [0, 1] with zero slope and curvature at both ends (a lane
    change without a jerk in lateral acceleration at its start and end)."""
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


def _shake(rng, amplitude_deg: float, n: int = 3, f_lo_hz: float = 2.0, f_hi_hz: float = 17.0):
    """Road vibration of one camera axis: a sum of `n` sinusoids of random frequency and phase
    whose amplitudes add up to `amplitude_deg`, so ``|shake(t)| <= amplitude_deg`` always."""
    freqs = rng.uniform(f_lo_hz, f_hi_hz, n)
    phases = rng.uniform(0.0, 2 * math.pi, n)
    w = rng.uniform(0.5, 1.0, n)
    amps = amplitude_deg * w / w.sum()
    comps = [(float(a), 2 * math.pi * float(f), float(p)) for a, f, p in zip(amps, freqs, phases)]

    def shake(t):
        return sum(a * math.sin(om * t + p) for a, om, p in comps)

    return shake


def _sway(rng, rms_deg: float, n: int = 3, f_lo_hz: float = 0.5, f_hi_hz: float = 2.5):
    """A dash camera's slow sway about one axis: `n` sinusoids of random frequency (0.5-2.5 Hz),
    phase and weight, scaled so that their sum's rms is `rms_deg`. The shake is correlated from
    frame to frame: over three frames a light may move several px, as on real roads."""
    freqs = rng.uniform(f_lo_hz, f_hi_hz, n)
    phases = rng.uniform(0.0, 2 * math.pi, n)
    w = rng.uniform(0.5, 1.0, n)
    amps = rms_deg * w / math.sqrt(float(np.sum(w * w)) / 2.0)
    comps = [(float(a), 2 * math.pi * float(f), float(p)) for a, f, p in zip(amps, freqs, phases)]

    def sway(t):
        return sum(a * math.sin(om * t + p) for a, om, p in comps)

    return sway


# Forward vehicles, in road coordinates relative to the HV (gap = FV's s minus the HV's s):
# (name, gap at t=0 m, gap rate m/s, lateral at t=0 m, lateral after the change m,
#  lane change start s, lane change duration s). Why this script: FV2's cut-in puts its body
# between the HV and FV1 (FV1's taillights are hidden first partly, then fully, while the HV
# is in the host lane); the HV's own lane change to the left then uncovers FV1, and FV3
# pulling into the host lane between FV2 and FV1 covers one of FV1's taillights from the
# left lane (and the side of FV2's body grazes FV3's right taillight).
FV_SCRIPT = (("fv1", 46.0, 0.45, 0.0, 0.0, 0.0, 0.0),
             ("fv2", 24.0, -0.65, 3.5, 0.0, 2.0, 2.5),
             ("fv3", 34.0, -0.25, -3.5, 0.0, 5.0, 2.5))


def vehicle(rng, cam, road_m=400.0, light_height_m=7.0, light_spacing_m=25.0, light_offset_y_m=6.0,
            head_tilt_deg=45.0, head_half_m=(0.4, 0.3), head_gap_m=0.5, clk_hz=S2PSK_CLOCK_HZ,
            symclk=S2PSK_SYMCLK, speed0_kmh=40.0, accel_mps2=1.0, cam_height_m=1.2, cam_pitch_deg=8.0,
            taillight_size_m=(0.15, 0.10), taillight_baseline_m=1.4, taillight_height_m=1.0, seconds=6.7,
            fv1_gap_m=22.0, fv1_closing_m=10.0, fv2_gap_m=38.0, fv2_gain_mps=0.8):
    """Night road: host vehicle (HV) with a forward camera, street lights, two forward vehicles.

    Road along world +x, host lane centred on y = 0 (y to the left), lane width 3.5 m (the
    thesis' 10 m "lane width" is taken as the road width between the light rows' kerbs).
    Street lights 7 m high every 25 m, alternating sides at y = +-6 m (left row at x = 0, 25,
    ..., right row offset by 12.5 m); each head is an S2-PSK pair of two 0.4 x 0.3 m halves
    0.5 m apart across the road, facing down but tilted `head_tilt_deg` towards approaching
    traffic (-x) so that a forward camera sees the face, not its edge. SL-IDs: distinct random
    in 0x00-0x7F. The HV starts at x = 0 at 40 km/h and accelerates at 1 m/s^2 (~64 km/h at
    6.7 s, within Table 2's 0-80 km/h). Camera: 1.2 m high, pitched up 8 deg (plus a little
    road vibration). Forward vehicles (FV, IDs in 0x80-0xFF, not in the map; the map's
    `taillight` block describes them): FV1 in the host lane closing from 22 m to ~12 m
    (`fv1_gap_m`, less `fv1_closing_m` over the 6.7 s); FV2 starts in the right lane 38 m ahead
    (`fv2_gap_m`), gains `fv2_gain_mps` on the HV and changes to the left lane. Far forward
    vehicles (thesis 50-100 m band): e.g. ``--set fv1_gap_m=95 --set fv1_closing_m=40 --set
    fv2_gap_m=70``. Taillights: 0.15 x 0.10 m
    rects, 1.4 m apart, 1 m high, facing backwards; emitter A is the left one. With the
    default 200 Hz clock and 16 clocks/symbol a 30-symbol packet lasts 2.4 s, so 6.7 s holds
    two full packets of every forward vehicle.
    """
    _require_positive(road_m=road_m, light_spacing_m=light_spacing_m)
    tilt = math.radians(head_tilt_deg)
    normal = np.array([-math.sin(tilt), 0.0, -math.cos(tilt)])
    across = np.array([0.0, 1.0, 0.0])
    positions = []
    for x in np.arange(0.0, road_m, light_spacing_m):
        positions.append((x, light_offset_y_m))
        positions.append((x + light_spacing_m / 2, -light_offset_y_m))
    sl_ids = rng.choice(0x80, size=len(positions), replace=False)
    lights, entries = [], {}
    for (x, y), sid in zip(positions, sl_ids):
        lt = s2psk_pair(rng, int(sid), (x, y, light_height_m), normal, across, head_half_m, head_gap_m,
                        clk_hz, symclk)
        lights.append(lt)
        e = map_entry(lt, rate_hz=clk_hz, symbol_clocks=symclk)
        entries[lt.id] = e
    fv_ids = rng.choice(np.arange(0x80, 0x100), size=2, replace=False)
    v0 = speed0_kmh / 3.6

    def hv_x(t):
        return v0 * t + 0.5 * accel_mps2 * t * t

    def hv_speed(t):
        return v0 + accel_mps2 * t

    def fv1(t):  # same lane, slower: gap 22 m -> ~12 m (defaults)
        return np.array([hv_x(t) + fv1_gap_m - fv1_closing_m * (1 - math.cos(math.pi * min(t / 6.7, 1.0))) / 2,
                         0.0, 0.0]), 0.0

    def fv2(t):  # right lane -> left lane between 2 s and 5 s, a little faster than the HV
        s = min(max((t - 2.0) / 3.0, 0.0), 1.0)
        y = -3.5 + 7.0 * (3 * s * s - 2 * s * s * s)
        dydt = 7.0 * (6 * s - 6 * s * s) / 3.0 if 0 < s < 1 else 0.0
        vx = hv_speed(t) + fv2_gain_mps
        return np.array([hv_x(t) + fv2_gap_m + fv2_gain_mps * t, y, 0.0]), math.degrees(math.atan2(dydt, vx))

    carriers = {"fv1": fv1, "fv2": fv2}
    for name, fid in zip(("fv1", "fv2"), fv_ids):
        lights.append(s2psk_pair(rng, int(fid), (0.0, 0.0, taillight_height_m), (-1.0, 0.0, 0.0),
                                 np.array([0.0, 1.0, 0.0]), taillight_size_m, taillight_baseline_m, clk_hz, symclk,
                                 carrier=name))
    taillight = {"shape": "rect", "size": list(taillight_size_m), "baseline_m": taillight_baseline_m}
    led_map = LedMap(addressing="map", leds=entries, taillight=taillight)

    def trajectory(t):
        return Pose(hv_x(t), 0.0, cam_height_m + 0.005 * math.sin(2 * math.pi * 3.1 * t), yaw=0.0,
                    pitch=cam_pitch_deg + 0.2 * math.sin(2 * math.pi * 1.3 * t), roll=0.0)

    def extra_truth(t):
        cam_pos = trajectory(t).position
        fvs = []
        for name, fid in zip(("fv1", "fv2"), fv_ids):
            pos, yaw = carriers[name](t)
            c = pos + np.array([0.0, 0.0, taillight_height_m])
            rel = c - cam_pos
            fvs.append({"id": int(fid), "x": round(float(rel[0]), 5), "y": round(float(rel[1]), 5),
                        "distance_m": round(float(np.linalg.norm(rel)), 5),
                        "angle_deg": round(math.degrees(math.atan2(rel[1], rel[0])), 5),
                        "world_x": round(float(pos[0]), 5), "world_y": round(float(pos[1]), 5),
                        "yaw_deg": round(float(yaw), 5)})
        return {"vehicle": {"hv": {"x": round(hv_x(t), 5), "y": 0.0, "speed_mps": round(hv_speed(t), 5)},
                            "fv": fvs}}

    return dict(lights=lights, led_map=led_map, trajectory=trajectory, carriers=carriers,
                extra_truth=extra_truth, n_frames=int(round(seconds * cam.fps)),
                description="night road with S2-PSK street lights and forward vehicles")


def vehicle_road(rng, cam, road_m=400.0, light_height_m=7.0, light_spacing_m=25.0, light_offset_y_m=6.0,
            head_tilt_deg=0.0, head_half_m=(0.4, 0.3), head_gap_m=0.5, clk_hz=S2PSK_CLOCK_HZ,
            symclk=S2PSK_SYMCLK, speed0_kmh=50.0, accel_mps2=0.5, cam_height_m=1.2, cam_pitch_deg=8.0,
            shake_deg=0.3, lane_change_start_s=4.0, lane_change_s=3.5, lane_change_m=3.5,
            taillight_size_m=(0.15, 0.10), taillight_baseline_m=1.4, taillight_height_m=1.0,
            body_size_m=(4.5, 1.8, 1.4), body_z0_m=0.15, curve_radius_m=None, seconds=8.0,
            light_layout="staggered", light_brightness=1.0, slow_shake_rms_deg=0.0, roll_rms_deg=0.0,
            jitter_deg=0.0, fv_gap_scale=1.0, wander_m=0.0, wander_hz=0.1, taillight_brightness=1.0):
    """Night road: host vehicle (HV) with a forward camera, S2-PSK street lights (SL), three
    forward vehicles (FV) with opaque bodies that hide each other's taillights.

    Road frame: arc length s along the host lane's centre line, lateral offset l to the left
    (metres); `road_point` maps it to the world frame (x, y floor, z up). Straight by default
    (world x = s, y = l); `curve_radius_m` bends it (> 0 left, < 0 right) with the lights,
    the HV and the FVs following the curve. Lane width 3.5 m (the thesis' 10 m "lane width",
    Table 2, is taken as the road width between the light rows' kerbs).

    Street lights (Table 2: 7 m high, 25 m apart): alternating sides at l = +-6 m (left row at
    s = 0, 25, ..., right row offset by 12.5 m). Each head is an S2-PSK pair (PROTOCOL.md
    section 3; thesis eqs. 40-42) of two horizontal 0.4 x 0.3 m panels facing straight down
    (normal [0, 0, -1], as ceiling LEDs are; `head_tilt_deg` > 0 tilts them towards approaching
    traffic), 0.5 m apart across the road. Seen from the 1.2 m camera a head 100 m ahead is
    ~5 px wide and ~0.2 px tall (foreshortening by sin(elevation)): the renderer's exact
    coverage keeps its flux. The HV's position follows from the SLs' ranges by thesis eqs.
    44-47. SL-IDs: distinct random in 0x00-0x7F.

    HV: starts at s = 0, l = 0 at `speed0_kmh` (50) accelerating at `accel_mps2` (0.5): 64 km/h
    at 8 s, inside Table 2's 0-80 km/h. From `lane_change_start_s` (4 s) over
    `lane_change_s` (3.5 s) it moves `lane_change_m` (3.5 m) left on a quintic ramp
    (`smoothstep5`); its heading is the direction of its velocity, and the camera's yaw
    follows it. `wander_m` > 0 adds a wander within the lane (a sinusoid of that amplitude at
    `wander_hz`, phase seeded). Camera: `cam_height_m` high at the HV's reference point, pitched up
    `cam_pitch_deg`; on top, a 3.1 Hz 5 mm bounce with a 1.3 Hz 0.2 deg pitch nod, and road
    vibration in pitch and yaw: per axis three sinusoids (2-17 Hz, seeded) summing to at most
    `shake_deg`; a dash camera's slow sway (`slow_shake_rms_deg` in yaw and pitch,
    `roll_rms_deg` in roll: per axis three sinusoids of 0.5-2.5 Hz, seeded, scaled to that rms)
    and a frame-to-frame jitter (`jitter_deg` rms per axis, held over each frame period).
    `light_layout`: "staggered" (the default above), "one-side" (the left row only) or
    "opposite" (both rows at the same s); `light_brightness`: the heads' radiance relative to
    `led_peak_dn` (above ~1.5 they saturate; with `halo_frac` their blobs then bloom);
    `taillight_brightness` the same for the taillights.

    FVs (IDs in 0x80-0xFF, not in the map; the map's `taillight` block describes them): see
    `FV_SCRIPT` (gaps 46, 24, 34 m, and their rates, times `fv_gap_scale`; FV2 cuts in from
    the left lane at 2-4.5 s, FV3 from the right lane at 5-7.5 s). Taillights: 0.15 x 0.10 m
    rects, 1.4 m apart, 1 m high on the body's rear face, facing backwards; emitter A is the
    left one. Bodies (`model.Body`): `body_size_m` = (length, width, height) = 4.5 x 1.8 x 1.4 m
    boxes from `body_z0_m` up.

    Length: `seconds` = 8 s = 240 frames at 30 fps; a 30-symbol packet at 200 Hz / 16 clocks
    lasts 2.4 s, so the SLs in view early are seen for several packets before they pass
    overhead, and FV1 for more than one packet before FV2 hides it. (8 s, not more: the
    FFV1 video of this scene is ~90 kB a frame, dominated by the sensor's read noise in the
    dark background, and all bundled recordings must stay under 40 MB.)

    Truth ("vehicle", at each frame's start time): ``hv`` {x, y (world), s_m, lateral_m
    (road frame), heading_deg, speed_mps}; ``fv`` entries {id, x (ahead), y (left) relative to
    the camera in its horizontal frame (rotated by the camera's yaw, not pitch or roll),
    distance_m (camera to the taillight pair's midpoint), angle_deg (bearing of that midpoint
    from the optical axis, positive left: thesis eq. 52's theta_FV), world_x, world_y, yaw_deg,
    s_m, lateral_m, speed_mps, rel_speed_mps (FV ground speed minus HV ground speed, thesis
    eq. 53's Delta V_FV), range_rate_mps (d distance_m / dt), visible (both emitters in the
    image, facing the camera and not occluded; false when the FV is out of view),
    occluded_frac (mean hidden fraction of the two taillights)}.
    """
    _require_positive(road_m=road_m, light_spacing_m=light_spacing_m)
    _require_non_negative(taillight_brightness=taillight_brightness, wander_hz=wander_hz,
                          lane_change_start_s=lane_change_start_s)
    R_curve = None if curve_radius_m is None else float(curve_radius_m)
    tilt = math.radians(head_tilt_deg)
    if light_layout not in ("staggered", "one-side", "opposite"):
        from receiver.core.errors import InputError
        raise InputError(f"light_layout must be staggered, one-side or opposite, not {light_layout!r}")
    positions = []
    for s in np.arange(0.0, road_m, light_spacing_m):
        positions.append((float(s), light_offset_y_m))
        if light_layout != "one-side":
            positions.append((float(s) + (light_spacing_m / 2 if light_layout == "staggered" else 0.0),
                              -light_offset_y_m))
    sl_ids = rng.choice(0x80, size=len(positions), replace=False)
    lights, entries = [], {}
    for (s, lat), sid in zip(positions, sl_ids):
        x, y, a = road_point(s, lat, R_curve)
        fwd = np.array([math.cos(a), math.sin(a), 0.0])
        across = np.array([-math.sin(a), math.cos(a), 0.0])  # the pair's halves straddle the road's width
        normal = DOWN if tilt == 0.0 else -math.sin(tilt) * fwd - math.cos(tilt) * np.array([0.0, 0.0, 1.0])
        lt = s2psk_pair(rng, int(sid), (x, y, light_height_m), normal, across, head_half_m, head_gap_m,
                        clk_hz, symclk, brightness=light_brightness)
        lights.append(lt)
        entries[lt.id] = map_entry(lt, rate_hz=clk_hz, symbol_clocks=symclk)
    fv_ids = rng.choice(np.arange(0x80, 0x100), size=len(FV_SCRIPT), replace=False)
    v0 = speed0_kmh / 3.6
    dt = 1e-3  # central differences for headings and speeds (paths are smooth at this scale)

    def hv_road(t):
        lat = lane_change_m * smoothstep5((t - lane_change_start_s) / lane_change_s)
        if wander_m > 0:
            lat += wander_m * math.sin(2 * math.pi * wander_hz * t + wander_phase)
        return v0 * t + 0.5 * accel_mps2 * t * t, lat

    def hv_xy(t):
        x, y, _ = road_point(*hv_road(t), R_curve)
        return np.array([x, y])

    def velocity(path, t):
        return (path(t + dt) - path(t - dt)) / (2 * dt)

    def heading_deg(path, t):
        vel = velocity(path, t)
        return math.degrees(math.atan2(vel[1], vel[0]))

    def fv_road(spec, t):
        _, gap0, rate, l0, l1, t0, dur = spec
        s_hv, _ = hv_road(t)
        lat = l0 if dur <= 0 else l0 + (l1 - l0) * smoothstep5((t - t0) / dur)
        return s_hv + gap0 * fv_gap_scale + rate * fv_gap_scale * t, lat

    def fv_xy_fn(spec):
        def xy(t):
            x, y, _ = road_point(*fv_road(spec, t), R_curve)
            return np.array([x, y])
        return xy

    fv_xy = {spec[0]: fv_xy_fn(spec) for spec in FV_SCRIPT}

    def carrier_fn(name):
        path = fv_xy[name]

        def carrier(t):
            p = path(t)
            return np.array([p[0], p[1], 0.0]), heading_deg(path, t)
        return carrier

    carriers = {spec[0]: carrier_fn(spec[0]) for spec in FV_SCRIPT}
    for spec, fid in zip(FV_SCRIPT, fv_ids):
        lights.append(s2psk_pair(rng, int(fid), (0.0, 0.0, taillight_height_m), (-1.0, 0.0, 0.0),
                                 np.array([0.0, 1.0, 0.0]), taillight_size_m, taillight_baseline_m, clk_hz, symclk,
                                 carrier=spec[0], brightness=taillight_brightness))
    length, width, height = body_size_m
    bodies = [Body(spec[0], length=length, width=width, height=height, z0=body_z0_m) for spec in FV_SCRIPT]
    taillight = {"shape": "rect", "size": list(taillight_size_m), "baseline_m": taillight_baseline_m}
    led_map = LedMap(addressing="map", leds=entries, taillight=taillight)
    shake_pitch = _shake(rng, shake_deg)
    shake_yaw = _shake(rng, shake_deg)
    sway = None
    if slow_shake_rms_deg > 0 or roll_rms_deg > 0 or jitter_deg > 0:
        # Drawn only when asked, so the default scene's random stream (IDs, phases) is unchanged.
        sway = [_sway(rng, rms) for rms in (slow_shake_rms_deg, slow_shake_rms_deg, roll_rms_deg)]
        n_jit = int(round(seconds * cam.fps)) + 2
        jit = rng.normal(0.0, jitter_deg, (3, n_jit)) if jitter_deg > 0 else np.zeros((3, n_jit))
        fps = cam.fps or 30.0
    # Drawn last and only when asked, for the same reason.
    wander_phase = float(rng.uniform(0.0, 2 * math.pi)) if wander_m > 0 else 0.0

    def camera_sway(t):
        """(yaw, pitch, roll) deg of the slow sway plus the jitter held over the frame period."""
        if sway is None:
            return 0.0, 0.0, 0.0
        k = min(max(int(math.floor(t * fps)), 0), jit.shape[1] - 1)
        return tuple(f(t) + float(jit[i, k]) for i, f in enumerate(sway))

    def trajectory(t):
        x, y = hv_xy(t)
        dyaw, dpitch, droll = camera_sway(t)
        return Pose(float(x), float(y), cam_height_m + 0.005 * math.sin(2 * math.pi * 3.1 * t),
                    yaw=heading_deg(hv_xy, t) + shake_yaw(t) + dyaw,
                    pitch=cam_pitch_deg + 0.2 * math.sin(2 * math.pi * 1.3 * t) + shake_pitch(t) + dpitch,
                    roll=droll)

    def fv_rel(name, t):
        """Taillight-pair midpoint relative to the camera at t: (x ahead, y left) in the camera's
        horizontal frame and the 3-D distance."""
        pose = trajectory(t)
        pos, yaw = carriers[name](t)
        rel = pos + np.array([0.0, 0.0, taillight_height_m]) - pose.position
        c, s = math.cos(math.radians(pose.yaw)), math.sin(math.radians(pose.yaw))
        return c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], float(np.linalg.norm(rel))

    def r5(v):
        return round(float(v), 5)

    def extra_truth(t, leds=()):
        by_id = {d["id"]: d for d in leds}
        hv_s, hv_l = hv_road(t)
        hv_p = hv_xy(t)
        hv_v = float(np.linalg.norm(velocity(hv_xy, t)))
        fvs = []
        for spec, fid in zip(FV_SCRIPT, fv_ids):
            name = spec[0]
            x, y, d = fv_rel(name, t)
            pos, yaw = carriers[name](t)
            s_fv, l_fv = fv_road(spec, t)
            v = float(np.linalg.norm(velocity(fv_xy[name], t)))
            rate = (fv_rel(name, t + dt)[2] - fv_rel(name, t - dt)[2]) / (2 * dt)
            rec = by_id.get(int(fid))
            fvs.append({"id": int(fid), "x": r5(x), "y": r5(y), "distance_m": r5(d),
                        "angle_deg": r5(math.degrees(math.atan2(y, x))), "world_x": r5(pos[0]),
                        "world_y": r5(pos[1]), "yaw_deg": r5(yaw), "s_m": r5(s_fv), "lateral_m": r5(l_fv),
                        "speed_mps": r5(v), "rel_speed_mps": r5(v - hv_v), "range_rate_mps": r5(rate),
                        "visible": bool(rec is not None and rec["visible"]),
                        "occluded_frac": None if rec is None else rec.get("occluded_frac")})
        return {"vehicle": {"hv": {"x": r5(hv_p[0]), "y": r5(hv_p[1]), "s_m": r5(hv_s), "lateral_m": r5(hv_l),
                                   "heading_deg": r5(heading_deg(hv_xy, t)), "speed_mps": r5(hv_v)},
                            "fv": fvs}}

    return dict(lights=lights, led_map=led_map, trajectory=trajectory, carriers=carriers, bodies=bodies,
                extra_truth=extra_truth, n_frames=int(round(seconds * cam.fps)),
                description="night road: down-facing S2-PSK street lights, HV lane change, three FVs "
                            "that occlude each other")


# What `vehicle-random` draws per seed, each uniform within its range (module constants so a
# test can check them): the roads the independent recordings showed our own scenes lacked.
RANDOM_ROAD = dict(head_spacing_m=(12.5, 40.0), light_height_m=(6.0, 10.0), light_offset_y_m=(5.0, 8.0),
                   light_brightness=(1.5, 3.0), slow_shake_rms_deg=(0.2, 0.35), cam_pitch_deg=(2.0, 4.0),
                   speed0_kmh=(40.0, 70.0), halo_frac=(0.05, 0.15), halo_sigma_px=(2.0, 4.0),
                   accel_mps2=(-0.5, 0.8), bloom_frac=(0.02, 0.1), bloom_len_px=(1.0, 4.0),
                   head_half_width_m=(0.2, 0.3), head_sep_m=(0.5, 0.8), taillight_baseline_m=(1.2, 1.7),
                   fv_gap_scale=(0.5, 1.3), wander_m=(0.0, 0.3), wander_hz=(0.05, 0.2),
                   lane_change_start_s=(1.0, 4.0), taillight_brightness=(1.5, 3.0))
# The host's lane change per seed: left, none or right (m to the left).
RANDOM_LANE_CHANGES_M = (3.5, 0.0, -3.5)
RANDOM_LAYOUTS = ("staggered", "one-side", "opposite")
# "split": a head's two halves `head_sep_m` apart with a gap between them (two blobs at every
# range); "merged": the halves touch (one blob, the separation below the blur).
RANDOM_HEAD_STYLES = ("split", "merged")
HEAD_LENGTH_M = 0.5  # a head's halves along the road
# A dash camera per seed (its own stream, as `draw_phone`): focal length and radial distortion.
DASH_CAMERA_RANGES = dict(focal_px=(1300.0, 1500.0), k1=(-0.05, 0.05))
ROAD_SENSOR_KEYS = ("halo_frac", "halo_sigma_px", "bloom_frac", "bloom_len_px")


def draw_dash_camera(rng: np.random.Generator) -> dict:
    """Camera keywords of one dash camera drawn from `DASH_CAMERA_RANGES` (k2..k3 zero)."""
    v = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in DASH_CAMERA_RANGES.items()}
    return dict(focal_px=v["focal_px"], dist=(v["k1"], 0.0, 0.0, 0.0, 0.0))


def vehicle_random(rng, cam, head_spacing_m=None, light_layout=None, light_height_m=None, light_offset_y_m=None,
                   light_brightness=None, slow_shake_rms_deg=None, cam_pitch_deg=None, speed0_kmh=None,
                   halo_frac=None, halo_sigma_px=None, accel_mps2=None, bloom_frac=None, bloom_len_px=None,
                   head_style=None, head_half_width_m=None, head_sep_m=None, taillight_baseline_m=None,
                   fv_gap_scale=None, wander_m=None, wander_hz=None, lane_change_m=None, lane_change_start_s=None,
                   taillight_brightness=None, jitter_deg=0.05, cam_height_m=1.3, seconds=8.0):
    """`vehicle_road` on a road drawn per seed (`RANDOM_ROAD`, `RANDOM_LAYOUTS`,
    `RANDOM_HEAD_STYLES`; a keyword given is taken instead of drawn, so each effect can be
    switched off or fixed): heads `head_spacing_m` apart along the road (12.5-40 m) in a
    staggered, one-side or opposite layout, 6-10 m high, 5-8 m off the host lane. Each head is
    two face-down halves `head_half_width_m` (0.2-0.3 m) across by 0.5 m along the road: "split"
    heads have their centres `head_sep_m` (0.5-0.8 m) apart, a gap between them (two blobs at
    every range); "merged" heads have the halves touching (one blob). The heads are bright
    enough to saturate (`light_brightness` 1.5-3x `led_peak_dn`) and bloom: `halo_frac`
    0.05-0.15 of the flux through a 2-4 px Gaussian (saturated blobs 2-3x their image area) and
    `bloom_frac` 0.02-0.1 of the charge above the white level spilt along the columns (1/e
    length `bloom_len_px` 1-4 px). The camera is 1.3 m high, pitched up 2-4 deg, swaying slowly
    (0.5-2.5 Hz sinusoids, yaw and pitch `slow_shake_rms_deg` 0.2-0.35 deg rms, roll half
    that) with `jitter_deg` (0.05 deg) of frame-to-frame jitter and no fast road vibration;
    the host starts at 40-70 km/h and accelerates or brakes (`accel_mps2` -0.5..0.8), wanders
    within its lane (`wander_m` 0-0.3 m at `wander_hz` 0.05-0.2 Hz) and changes lane to the
    left, not at all or to the right (`lane_change_m` from `RANDOM_LANE_CHANGES_M`) from
    `lane_change_start_s` (1-4 s). The forward vehicles are `vehicle_road`'s with their gaps
    scaled by `fv_gap_scale` (0.5-1.3: the nearest 9-31 m ahead, the farthest 23-65 m), their
    taillights `taillight_baseline_m` (1.2-1.7 m) apart (the map's `taillight` block) and, as
    the heads, bright enough to saturate (`taillight_brightness` 1.5-3x `led_peak_dn`). Returns
    `vehicle_road`'s dict plus `render` (the drawn sensor values, for `make_scene`) and `road`
    (every drawn value)."""
    # Every value is drawn, given or not, so that fixing one leaves the seed's other values as
    # they were (an effect can be switched off on the same road).
    def draw(name, given):
        lo, hi = RANDOM_ROAD[name]
        drawn = float(rng.uniform(lo, hi))
        return drawn if given is None else float(given)

    def pick(choices, given, what, any_value=False):
        drawn = choices[int(rng.integers(len(choices)))]
        if given is None:
            return drawn
        if not any_value and given not in choices:
            from receiver.core.errors import InputError
            raise InputError(f"bad --set value: {what} must be {' or '.join(choices)}, not {given!r}")
        return given

    road = dict(head_spacing_m=draw("head_spacing_m", head_spacing_m),
                light_layout=pick(RANDOM_LAYOUTS, light_layout, "light_layout"),
                light_height_m=draw("light_height_m", light_height_m),
                light_offset_y_m=draw("light_offset_y_m", light_offset_y_m),
                light_brightness=draw("light_brightness", light_brightness),
                slow_shake_rms_deg=draw("slow_shake_rms_deg", slow_shake_rms_deg),
                cam_pitch_deg=draw("cam_pitch_deg", cam_pitch_deg), speed0_kmh=draw("speed0_kmh", speed0_kmh),
                halo_frac=draw("halo_frac", halo_frac), halo_sigma_px=draw("halo_sigma_px", halo_sigma_px))
    # Drawn after the values above, so those stay what each seed drew before these existed.
    road.update(accel_mps2=draw("accel_mps2", accel_mps2), bloom_frac=draw("bloom_frac", bloom_frac),
                bloom_len_px=draw("bloom_len_px", bloom_len_px),
                head_style=pick(RANDOM_HEAD_STYLES, head_style, "head_style"),
                head_half_width_m=draw("head_half_width_m", head_half_width_m),
                head_sep_m=draw("head_sep_m", head_sep_m),
                taillight_baseline_m=draw("taillight_baseline_m", taillight_baseline_m),
                fv_gap_scale=draw("fv_gap_scale", fv_gap_scale), wander_m=draw("wander_m", wander_m),
                wander_hz=draw("wander_hz", wander_hz),
                lane_change_m=float(pick(RANDOM_LANE_CHANGES_M, lane_change_m, "lane_change_m", any_value=True)),
                lane_change_start_s=draw("lane_change_start_s", lane_change_start_s),
                taillight_brightness=draw("taillight_brightness", taillight_brightness))
    _require_positive(**{k: road[k] for k in ("head_spacing_m", "light_height_m", "head_half_width_m",
                                              "taillight_baseline_m", "fv_gap_scale")})
    if road["head_style"] == "merged" and head_sep_m is None:
        road["head_sep_m"] = road["head_half_width_m"]      # the halves touch
    if road["head_sep_m"] < road["head_half_width_m"]:
        from receiver.core.errors import InputError
        raise InputError(f"bad --set value: head_sep_m ({road['head_sep_m']:g}) must be at least head_half_width_m "
                         f"({road['head_half_width_m']:g}): the halves would overlap")
    # vehicle_road's light_spacing_m is a row's spacing; a staggered layout puts the other row
    # half-way, so its heads follow each other at half of it.
    row = road["head_spacing_m"] * (2.0 if road["light_layout"] == "staggered" else 1.0)
    built = vehicle_road(rng, cam, light_spacing_m=row, light_layout=road["light_layout"],
                         light_height_m=road["light_height_m"], light_offset_y_m=road["light_offset_y_m"],
                         light_brightness=road["light_brightness"],
                         head_half_m=(road["head_half_width_m"], HEAD_LENGTH_M), head_gap_m=road["head_sep_m"],
                         shake_deg=0.0, slow_shake_rms_deg=road["slow_shake_rms_deg"],
                         roll_rms_deg=road["slow_shake_rms_deg"] / 2.0, jitter_deg=jitter_deg,
                         cam_height_m=cam_height_m, cam_pitch_deg=road["cam_pitch_deg"],
                         speed0_kmh=road["speed0_kmh"], accel_mps2=road["accel_mps2"],
                         taillight_baseline_m=road["taillight_baseline_m"], fv_gap_scale=road["fv_gap_scale"],
                         wander_m=road["wander_m"], wander_hz=road["wander_hz"], lane_change_m=road["lane_change_m"],
                         lane_change_start_s=road["lane_change_start_s"],
                         taillight_brightness=road["taillight_brightness"], seconds=seconds)
    built["render"] = {k: road[k] for k in ROAD_SENSOR_KEYS}
    built["road"] = road
    built["description"] = "night road drawn per seed: " + ", ".join(
        f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in road.items())
    return built


def indoor_phone(rng, cam, room_m=9.0, seconds=3.0, **kw):
    """`indoor_sparse` as a phone films it (`make_scene` draws the phone: `tools.synth.phone`):
    0.25 m panels on a 1.1 m grid, one or two in view, the walk drawn per seed: start and
    heading anywhere in the room's middle, 0.8-1.2 m/s, tilt swinging between 15-20 and 30-35
    degrees, heading swinging by 10-25 degrees (the phone turning at up to 10-30 deg/s).
    Keywords of `indoor_sparse` override the drawn values."""
    r = np.random.default_rng(int(rng.integers(2 ** 32)))
    turn = math.radians(r.uniform(10.0, 25.0))
    drawn = dict(start_xy=(float(r.uniform(2.5, room_m - 2.5)), float(r.uniform(2.5, room_m - 2.5))),
                 heading_deg=float(r.uniform(0.0, 360.0)), speed_mps=float(r.uniform(0.8, 1.2)),
                 tilt_deg=(float(r.uniform(15.0, 20.0)), float(r.uniform(30.0, 35.0))), turn_rad=turn,
                 turn_rate_rad_s=math.radians(r.uniform(10.0, 30.0)) / turn, tilt_hz=float(r.uniform(0.2, 0.4)))
    x, y = drawn["start_xy"]
    h = math.radians(drawn["heading_deg"])
    # Walk towards the room's middle, so that the whole walk stays under the ceiling's grid.
    if not (1.0 < x + 4 * math.cos(h) < room_m - 1.0 and 1.0 < y + 4 * math.sin(h) < room_m - 1.0):
        drawn["heading_deg"] = math.degrees(math.atan2(room_m / 2 - y, room_m / 2 - x))
    drawn.update(kw)
    out = indoor_sparse(rng, cam, room_m=room_m, seconds=seconds, **drawn)
    out["description"] = "phone walk under sparse 0.25 m panels, tilt 15-35 deg, turning, every phone effect"
    return out


BUILDERS = {"indoor-walk": indoor_walk, "indoor-static": indoor_static, "indoor-sparse": indoor_sparse,
            "indoor-phone": indoor_phone,
            "vehicle": vehicle,
            "vehicle-road": vehicle_road,
            "vehicle-random": vehicle_random}

CAMERA_DEFAULTS = {
    # Smartphone main camera at 1280x720: 1000 px focal (65 x 40 deg field of view), mild barrel
    # distortion, 15 us rows (3.33 rows per 20 kHz chip), 20 us exposure (< one chip).
    "indoor-walk": dict(focal_px=1000.0, dist=(-0.04, 0.01, 0.0, 0.0, 0.0), pixel_size_um=3.0,
                        row_readout_us=15.0, exposure_us=20.0, fps=30.0),
    "indoor-static": dict(focal_px=1000.0, dist=(-0.04, 0.01, 0.0, 0.0, 0.0), pixel_size_um=3.0,
                          row_readout_us=15.0, exposure_us=20.0, fps=30.0),
    "indoor-sparse": dict(focal_px=1000.0, dist=(-0.04, 0.01, 0.0, 0.0, 0.0), pixel_size_um=3.0,
                          row_readout_us=15.0, exposure_us=20.0, fps=30.0),
    # Phone main camera at 1280x720 (1.4 um pixels, 1100 px focal), 10 us rows, 20 us exposure;
    # its lens distortion is drawn with the phone (tools.synth.phone.PHONE_RANGES).
    "indoor-phone": dict(focal_px=1100.0, pixel_size_um=1.4, row_readout_us=10.0, exposure_us=20.0, fps=30.0),
    # Dash camera: 1200 px focal (56 x 33 deg), 100 us exposure << the 2.5 ms S2-PSK half clock.
    "vehicle": dict(focal_px=1200.0, dist=(-0.03, 0.0, 0.0, 0.0, 0.0), pixel_size_um=3.75,
                    row_readout_us=15.0, exposure_us=100.0, fps=30.0),
}
CAMERA_DEFAULTS["vehicle-road"] = CAMERA_DEFAULTS["vehicle"]
# A dash camera as the independent recordings' (15 us rows, 100 us exposure); its focal length
# (1300-1500 px) and k1 (-0.05..0.05) are drawn per seed (`draw_dash_camera`).
CAMERA_DEFAULTS["vehicle-random"] = dict(CAMERA_DEFAULTS["vehicle"], focal_px=1400.0, dist=(-0.03, 0.0, 0.0, 0.0, 0.0))
# The bundled `vehicle` recording was rendered with the sampled coverage throughout
# (exact_coverage_rows 0 keeps it bit-exact); `vehicle-road` has sub-pixel-tall far heads,
# which only the exact coverage renders with their true flux.
PARAM_DEFAULTS = {"indoor-walk": {}, "indoor-static": {}, "indoor-sparse": {}, "indoor-phone": {},
                  "vehicle": dict(psf_sigma_px=0.7, exact_coverage_rows=0.0),
                  "vehicle-road": dict(psf_sigma_px=0.7),
                  # Lens blur 0.5 px, read noise 1.5 DN over an 8 DN black level (halo and bloom: drawn).
                  "vehicle-random": dict(psf_sigma_px=0.5, read_noise_dn=1.5, black_level_dn=8.0)}


def make_scene(name: str, seed: int = 0, n_frames: int | None = None, **overrides) -> Scene:
    """Build scene `name` (one of SCENES) with keyword overrides (see the module docstring)."""
    from receiver.core.errors import InputError

    if name not in BUILDERS:
        raise InputError(f"unknown scene '{name}' (choose from {', '.join(SCENES)})")
    cam_kw = dict(CAMERA_DEFAULTS[name])
    par_kw = dict(PARAM_DEFAULTS[name])
    overrides = dict(overrides)
    if overrides.pop("phone", name == "indoor-phone"):
        # One phone per seed (its own stream: the scene's draws stay those of the seed).
        cam_phone, par_phone = draw_phone(np.random.default_rng([seed, 0x9407E]))
        cam_kw.update(cam_phone)
        par_kw.update(par_phone)
    if name == "vehicle-random":
        # One dash camera per seed (its own stream); an explicit --set still wins.
        cam_kw.update(draw_dash_camera(np.random.default_rng([seed, 0xDA5C])))
    builder = BUILDERS[name]
    scene_keys = set(inspect.signature(builder).parameters) - {"rng", "cam", "kw"}
    if builder is indoor_phone:
        scene_keys |= set(inspect.signature(indoor_sparse).parameters) - {"rng", "cam"}
    scene_kw = {}
    for key, value in overrides.items():
        if key in CAMERA_KEYS:
            cam_kw[key] = value
        elif key in PARAM_KEYS:
            par_kw[key] = value
        elif key in scene_keys:
            scene_kw[key] = value
        else:
            raise InputError(f"scene '{name}' has no parameter '{key}'")
    cam = _checked_camera(cam_kw)
    params = _checked_params(par_kw)
    for key, value in scene_kw.items():
        _check_override_value(key, value)
    rng = np.random.default_rng(seed)
    built = builder(rng, cam, **scene_kw)
    # A builder may draw sensor values (`render`); an explicit override still wins.
    drawn = {k: v for k, v in built.pop("render", {}).items() if k not in overrides}
    built.pop("road", None)
    if drawn:
        params = _checked_params({**par_kw, **drawn})
    if n_frames is not None:
        built["n_frames"] = int(n_frames)
    return Scene(name=name, camera=cam, params=params, **built)


# Bounds of the sensor parameters (RenderParams): all finite and non-negative; at most these.
PARAM_MAX = {"led_peak_dn": 1e4, "ambient_dn": 1e4, "black_level_dn": 255.0, "shot_noise_alpha": 100.0,
             "read_noise_dn": 1e3, "psf_sigma_px": 100.0, "subrows": 64, "motion_blur_samples": 64,
             "frame_jitter_us": 1e6, "exact_coverage_rows": 1e4, "halo_frac": 1.0, "halo_sigma_px": 100.0,
             "glare_frac": 1.0, "glare_sigma_px": 500.0,
             "vignetting": 0.95, "row_noise_dn": 100.0, "bloom_frac": 1.0, "bloom_len_px": 100.0,
             "centre_gain": 10.0, "bezel_frac": 1.0, "tone_gamma": 5.0, "sharpen": 5.0, "rs_band_rows": 720}
INT_PARAMS = ("subrows", "motion_blur_samples")


def _finite_numbers(value) -> bool:
    vals = value if isinstance(value, (tuple, list)) else (value,)
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in vals)


def _check_override_value(key: str, value) -> None:
    """Scene keywords: numbers (or tuples of numbers) must be finite; strings reach the builder."""
    from receiver.core.errors import InputError

    if isinstance(value, (int, float, tuple, list)) and not isinstance(value, bool) and not _finite_numbers(value):
        raise InputError(f"bad --set value: {key}={value!r}: numbers must be finite")


def _checked_camera(cam_kw: dict):
    """make_camera(**cam_kw) with every value checked: the physical ranges of a camera file
    (receiver.io.camera.check_camera), 5 distortion coefficients, integer sizes."""
    from receiver.core.errors import InputError
    from receiver.io.camera import check_camera

    for key, value in cam_kw.items():
        if key == "dist":
            if not isinstance(value, (tuple, list)) or len(value) != 5 or not _finite_numbers(value):
                raise InputError(f"bad --set value: dist must be 5 finite numbers (k1,k2,p1,p2,k3), not {value!r}")
        elif not _finite_numbers(value) or isinstance(value, (tuple, list)):
            raise InputError(f"bad --set value: {key} must be a finite number, not {value!r}")
        elif key in ("width", "height") and value != int(value):
            raise InputError(f"bad --set value: {key} must be a whole number of pixels, not {value!r}")
    try:
        cam = make_camera(**cam_kw)
    except (TypeError, ValueError, OverflowError) as e:
        raise InputError(f"bad --set value: {e}") from None
    check_camera(cam, "bad --set value")
    if not cam.fps > 0:
        raise InputError("bad --set value: fps must be positive (the synthetic camera needs a frame rate)")
    return cam


def _checked_params(par_kw: dict) -> RenderParams:
    from receiver.core.errors import InputError

    for key, value in par_kw.items():
        if not _finite_numbers(value) or isinstance(value, (tuple, list)) or not 0 <= value <= PARAM_MAX[key]:
            raise InputError(f"bad --set value: {key} must be a number within 0..{PARAM_MAX[key]:g}, not {value!r}")
        if key in INT_PARAMS and (value != int(value) or value < 1):
            raise InputError(f"bad --set value: {key} must be a positive whole number, not {value!r}")
        if key == "rs_band_rows" and value != int(value):
            raise InputError(f"bad --set value: {key} must be a whole number, not {value!r}")
        if key == "tone_gamma" and value < 0.2:
            raise InputError(f"bad --set value: {key} must be at least 0.2, not {value!r}")
    if par_kw.get("bloom_frac", 0) > 0 and not par_kw.get("bloom_len_px", RenderParams.bloom_len_px) > 0:
        raise InputError("bad --set value: bloom_len_px must be positive when bloom_frac is above 0")
    if "rs_band_rows" in par_kw:
        par_kw["rs_band_rows"] = int(par_kw["rs_band_rows"])
    return RenderParams(**par_kw)
