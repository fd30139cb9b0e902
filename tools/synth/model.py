"""Scene description: lights, their emitters, moving carriers and the camera trajectory.

All geometry in the world frame (x, y floor, z up, metres; see `tools.synth.camera`).
An emitter is a flat luminous surface: `shape` circle (size = [diameter]) or square/rect
(size = [width, length]), centred at `offset`, emitting around its unit `normal`; `u_axis`
is the direction of the width. A light (one map entry, one ID) has one emitter (OOK, tone)
or two (an S2-PSK pair: emitter A on pin A, emitter B on pin B of the same schedule).
Lights on a vehicle give `offset`, `normal`, `u_axis` in the vehicle's body frame
(x forward, y left, z up, origin on the road under the vehicle's rear centre) and name the
vehicle in `carrier`; `Scene.carriers[name](t_s)` returns that vehicle's (position, yaw_deg).
A vehicle may also have an opaque `Body` (a box in the same body frame) that hides the
lights behind it from the camera (per pixel, in `tools.synth.render`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap, shape_area_m2
from tools.synth.camera import Pose
from tools.synth.waveform import LedDrive

CIRCLE_SEGMENTS = 96  # outline vertices of a circle: area error < 0.1 %
EDGE_SEGMENTS = 8  # vertices per square edge, so lens distortion can bend the edges


@dataclass
class Emitter:
    offset: np.ndarray
    normal: np.ndarray
    u_axis: np.ndarray
    shape: str
    size: tuple
    drive: LedDrive

    def outline_local(self) -> np.ndarray:
        """(M, 3) outline points around `offset` (carrier or world frame), counter-clockwise seen
        from the front."""
        n = self.normal / np.linalg.norm(self.normal)
        u = self.u_axis - n * float(self.u_axis @ n)
        u = u / np.linalg.norm(u)
        v = np.cross(n, u)
        if self.shape == "circle":
            a = np.linspace(0.0, 2 * math.pi, CIRCLE_SEGMENTS, endpoint=False)
            r = self.size[0] / 2.0
            ab = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
        else:
            w = self.size[0]
            h = self.size[1] if len(self.size) > 1 else w
            s = np.linspace(0.0, 1.0, EDGE_SEGMENTS, endpoint=False)
            corners = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
            ab = np.concatenate([corners[i] + s[:, None] * (corners[(i + 1) % 4] - corners[i])
                                 for i in range(4)])
        return self.offset + ab[:, :1] * u + ab[:, 1:] * v

    @property
    def area_m2(self) -> float:
        return shape_area_m2(self.shape, self.size)


@dataclass
class Light:
    """One ID: `emitters` has 1 entry (OOK, tone, steady) or 2 (S2-PSK pair, A then B)."""

    id: int
    mode: str
    emitters: list
    brightness: float = 1.0  # radiance relative to RenderParams.led_peak_dn
    lambertian_m: float = 1.0  # Lambertian order m of thesis eq. 1 (1 = ideal diffuser)
    carrier: str | None = None

    @property
    def offset(self) -> np.ndarray:
        return np.mean([e.offset for e in self.emitters], axis=0)


@dataclass(frozen=True)
class Body:
    """Opaque box of the vehicle `carrier`, in its body frame (x forward, y left, z up, metres;
    origin on the road under the rear centre): x in [0, length], y in [-width/2, width/2],
    z in [z0, z0 + height]. Its rear face (width x height) is what a following camera sees.
    The body hides other lights behind it; it is not drawn itself (a dark car at night is
    as dark as the unlit background) and never hides its own carrier's lights."""

    carrier: str
    length: float = 4.5
    width: float = 1.8
    height: float = 1.4
    z0: float = 0.15

    def corners_local(self) -> np.ndarray:
        """(8, 3) box corners in the body frame."""
        xs, ys, zs = (0.0, self.length), (-self.width / 2, self.width / 2), (self.z0, self.z0 + self.height)
        return np.array([[x, y, z] for x in xs for y in ys for z in zs], dtype=np.float64)


@dataclass(frozen=True)
class RenderParams:
    """Sensor and optics of the synthetic camera (every value in DN = 8-bit digital numbers).

    led_peak_dn: pixel signal of a fully covered pixel of a fully-on LED seen head-on on the
      optical axis (brightness 1); off-axis and oblique views follow thesis eqs. 1/10.
    ambient_dn: uniform background signal (ambient light over the exposure).
    black_level_dn: sensor offset added before quantisation (0 = clamped black, as most
      webcams deliver).
    shot_noise_alpha / read_noise_dn: the pixel noise model of thesis eq. 4: noise variance
      ``alpha * S + beta`` with S the signal in DN and ``beta = read_noise_dn**2``.
    psf_sigma_px: Gaussian lens blur (0 = none).
    subrows: y supersampling of the coverage (x is exact).
    motion_blur_samples: poses averaged over the exposure window (1 = no motion blur).
    exact_coverage_rows: shapes whose projected outline spans fewer image rows than this get
      exact area coverage (`raster.coverage_exact`) instead of `subrows` sampling, which
      loses or doubles the flux of shapes about a pixel tall or less. Above it the sampled
      coverage is kept (bit-exact with the recordings made before the exact path existed).
    frame_jitter_us: standard deviation of each frame's start time around k / fps.
    halo_frac, halo_sigma_px: a halo: this fraction of every light's flux
      is spread by a wide Gaussian (sigma px) instead of the lens PSF, so a saturating light's
      blob grows well past its image (2-3x its area within saturation; 0 = none).

    Phone effects (`tools.synth.phone`; all 0 = off, and then the frame is drawn as above):
    glare_frac / glare_sigma_px: share of each light's signal spread as veiling glare by a
      Gaussian of that sigma.
    vignetting: relative loss of light at the image corners (quadratic in the radius).
    row_noise_dn: 1-sigma of a per-row offset (read-out noise common to a row).
    bloom_frac / bloom_len_px: share of a clipped pixel's excess charge (above the white level,
      255) that spills along its column, with an exponential tail of that 1/e length (also
      without the other phone effects: a saturated street light or taillight on a dash camera).
    centre_gain: a panel's centre this much brighter than its edges (diffuser fall-off,
      quadratic across the panel).
    bezel_frac: a dark frame around each panel, this fraction of its half size wide, that hides
      the lit ceiling behind it.
    tone_gamma: the phone's tone curve, out = 255 (in / 255)^(1 / gamma) (1 = linear).
    sharpen: unsharp-mask amount (sigma 1 px) after the tone curve.
    rs_band_rows: in-frame motion: each band of this many rows of a light is drawn with the
      camera pose of its own read time (0: one pose per light, at its centroid's row).
    """

    led_peak_dn: float = 180.0
    ambient_dn: float = 0.0
    black_level_dn: float = 0.0
    shot_noise_alpha: float = 0.02
    read_noise_dn: float = 0.35
    psf_sigma_px: float = 0.6
    subrows: int = 4
    motion_blur_samples: int = 1
    frame_jitter_us: float = 100.0
    exact_coverage_rows: float = 8.0
    halo_frac: float = 0.0
    halo_sigma_px: float = 3.0
    glare_frac: float = 0.0
    glare_sigma_px: float = 40.0
    vignetting: float = 0.0
    row_noise_dn: float = 0.0
    bloom_frac: float = 0.0
    bloom_len_px: float = 6.0
    centre_gain: float = 0.0
    bezel_frac: float = 0.0
    tone_gamma: float = 1.0
    sharpen: float = 0.0
    rs_band_rows: int = 0

    @property
    def phone(self) -> bool:
        """True when any effect needs the whole frame drawn (`tools.synth.phone.finish_frame`)."""
        return bool(self.glare_frac or self.vignetting or self.row_noise_dn
                    or self.bezel_frac or self.tone_gamma != 1.0 or self.sharpen)


@dataclass
class Scene:
    """Everything needed to render frames of one scene.

    trajectory(t_s) -> camera `Pose`; carriers[name](t_s) -> (position (3,), yaw_deg);
    extra_truth(t_s, leds) -> dict of scene-specific truth added to each truth line (or None);
    `leds` is the frame's list of per-light truth records (so visibility can be reported).
    bodies: opaque vehicle bodies (`Body`) that occlude lights behind them.
    """

    name: str
    camera: CameraModel
    lights: list
    trajectory: Callable
    led_map: LedMap
    params: RenderParams = RenderParams()
    n_frames: int = 90
    carriers: dict = field(default_factory=dict)
    extra_truth: Callable | None = None
    bodies: list = field(default_factory=list)
    description: str = ""
