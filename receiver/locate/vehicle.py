"""Vehicle positioning from S2-PSK pairs (thesis chapter 5.3): the host vehicle (HV) placed from
street lights (SL), forward vehicles (FV) located from their taillights.

Frames and units
* Road / map frame: metres, x along the road, y to the left, z up (the map's frame; curved roads
  are fine, nothing assumes the lights lie on a line).
* Camera frame: OpenCV (x right, y down, z forward). ``R_cw`` is the world-to-camera rotation,
  ``X_cam = R_cw @ (X_world - C)``, C the camera centre (receiver.locate.pose conventions).
* Level frame of the camera: x = the optical axis projected on the horizontal plane (ahead),
  y to the left, z up, origin at the camera. FV ``x``, ``y`` and ``angle_deg`` are given in it.
* Image points: distorted pixels in, undistorted normalized coordinates (x/z, y/z) inside.
* Angles in the output: degrees; heading counter-clockwise from road +x.

Ranging of one pair (`range_pair`, `VehicleLocator`; distance from the camera to the pair's
midpoint, metres):
* ``"eq18"``: thesis eq. 18 per emitter, ``d = f/rho sqrt(A_LED / eta)`` with the emitter area
  (SL: the map entry's shape/size, FV: the map's `taillight` block), averaged over the two
  emitters. Kept as the thesis reference: it assumes the emitter faces the camera on the axis.
* ``"oblique"``: eq. 18 with what it leaves out corrected (as receiver.locate.ranging's
  ``distance_oblique``): the envelope's area grown by the half-pixel edge offset (Steiner,
  perimeter from the shape), mapped to normalized image area through the local Jacobian of the
  undistortion, and ``d = sqrt(A cos(theta) / (a cos(alpha)^3))`` with theta the angle between
  the emitter normal and the ray. Street-light panels face down (map `normal`, default
  [0, 0, -1]) and are seen at grazing angles (theta ~ 80 deg at 30 m): plain eq. 18 then reads
  ``1/sqrt(cos theta)`` (2x and more) too far; the correction needs the camera orientation, and
  its sigma grows as ``0.5 tan(theta) sigma_orientation``.
* ``"baseline"``: ``d = f B / separation_px`` generalised to any baseline orientation: with the
  two unit rays r_a, r_b and the baseline vector B_cam (camera frame), the emitters are at
  ``s_a r_a`` and ``s_b r_b`` with ``s_b r_b - s_a r_a = B_cam``, solved in least squares;
  d = |s_a r_a + s_b r_b| / 2 (= f B / sep for a baseline perpendicular to the axis). SL: B from
  the map's emitter positions, turned by the camera orientation; taillights: B horizontal and
  perpendicular to the FV heading, taken as the HV's (perpendicular to the camera axis in the
  level frame). sigma/d = sqrt(2) sigma_px / separation_px (+ a model term).
* ``"fused"``: inverse-variance mean of "oblique" and "baseline" (what is reported). When the
  two disagree beyond `CONSISTENCY_SIGMAS` only the area one is dropped: the baseline rests on
  geometry alone.
Saturation (`PairObservation.a_saturated`, `b_saturated`: the blob's peak at the sensor's white
level): a clipped blob is blur and bloom, 2-3x its emitter's true image area, so a saturated
emitter gives no area range (nor a size test, nor an emitter range to the host pose); its pair
is ranged by its baseline (`_drop_clipped_areas`). What its areas read only bounds the range
(`SATURATED_AREA_SPAN`), which tells an undecoded head's halves from taillights.
No range from half a pair: a street light needs `both_visible`; a taillight pair is ranged only
in frames where both emitters' own blobs are measured (`fv_measured`: `a_seen`, `b_seen` of age
0, the measured centroids, not the pairing's rigid-model positions `a_px`, `b_px`, whose
separation is the founding one scaled by the envelope areas: on the bundled recording 2.1 %
|median| off, the measured one 0.39 %). The pairing's founding frame is such a frame, so a pair
has a distance from the frame it is formed.

Host vehicle (`hv`):
* ``"eq44-47"`` (reported beside the fix as ``hv_eq44_47``, not fed to the filter): thesis eqs. 44-47. Flat distances a_j = sqrt(D_j^2 - (z_SL - h_cam)^2) to two
  street lights SL1 (nearer), SL2 at spacing d_SL-SL give c (eq. 46, along the SL1->SL2 line)
  and h (eq. 47, across it); the side of the line comes from the image (which light is further
  left). Works for any two mapped lights.
* ``"pose"``: the full camera pose (R_cw, C) from the angles of arrival of every decoded SL
  emitter centroid (undistorted) and their "oblique" ranges, one robust Levenberg-Marquardt
  solve (receiver.locate.pose's joint residuals, soft-L1) with the camera height
  (`camera_height_m`) and the nominal tilt as weak priors. Initialised from the previous pose,
  else by a 2-D registration of the lights' camera-frame positions (ranged, nominal tilt) onto
  the map (any road shape).
* then `RoadKalman` (receiver.locate.road_kalman; state x, y, heading, speed, turn rate) fed the
  fix (x, y, camera yaw) and the odometry speed V_HV of eq. 48; it coasts between fixes
  (method ``"kalman-coast"``). ``raw`` is the unfiltered fix. Without odometry the speed comes
  from the first two fixes `SPEED_INIT_MIN_DT_S` apart (`_speed_from_fixes`).
* One decoded light: while the filter runs and is sure (`SL1_MAX_STD_M`), the
  head's undistorted midpoint and its range update it directly (``"sl-1"``,
  `_single_observation`: an EKF measurement whose noise carries the camera's yaw shake, pitch,
  roll and height through its Jacobian; a pose solve would need the filter's own heading as
  prior). With no filter running, a pose solve of its two emitters with the map's road
  direction near the light as heading prior, roll 0 and the last full pose's pitch as priors,
  and the head's midpoint range (``"pose-1sl"``, `_single_fix`) starts it when its std is at
  most `SL1_START_MAX_STD_M`. `n_lights` 1.
* Map-aided association (`_associate`): while the filter is sure, undecoded pairs
  (both emitters' own blobs fresh) are matched to mapped heads projected from its prediction by
  a unique Mahalanobis gate and a separation check, and join the solve (method suffix
  ``"+map"``, `n_assoc`; `n_lights` counts them). They stay undecoded everywhere else: no ID,
  no range, no forward vehicle.
* The HV is reported only while the filter's 2D std is at most `hv_max_std_m`.

Forward vehicles (`fv`): bearing from the horizontal displacement of the pair midpoint
(thesis eq. 52), undistorted and turned into the level frame (pitch/roll from the HV pose when
known, else the nominal pitch), every frame: in frames without a range from the emitter measured
in the frame and the last measured separation (`_fv_directions`); distance "fused" (with the
taillight sigmas the area range weighs ~1/20 of the baseline one); between ranged frames the
filter predicts; a per-pair `RangeKalman` gives the range rate
(``rel_speed_mps``, negative = closing) and ``ttc_s = d / -rate`` when closing; ``zone`` as
thesis Figure 27 ("safe", "min", "critical") from the time headway d / V_HV (distance thresholds
when V_HV is unknown), tightened by ttc; ``road_x``, ``road_y`` = P_HV + rotation(heading) (x, y)
(eq. 53) when the HV is placed. A pair still undecoded (kind None) is taken as an FV when its
midpoint, ranged as a taillight pair, lies between `fv_min_height_m` and `fv_max_height_m`
above the road (once the camera's tilt is known) and its area and baseline ranges agree (a street
light's emitters are ~7x larger for their spacing than taillights; two far heads paired across
the road clash likewise: scale-free, so it holds before the tilt is known), its two emitters are
level (`FV_MAX_TILT_DEG`) and of like area (`FV_MAX_AREA_RATIO`), and, once the HV is placed,
neither emitter lies on a mapped street light projected from the HV pose (`FV_SL_GATE_DEG`):
two far heads 200 m away, one each side of the road, can pass the area/baseline test by chance
(read as a car at 30-40 m). A new undecoded pair that shares a lamp (founding track) with a live
pair already tracked as an FV is not one either: at 50+ m one taillight of each of two cars side
by side also passes the area test (tiny blobs read large, the cross baseline short).

Cost (`range_core`, `_pair_geometry`): a frame has 1-15 pairs, so the per-pair math is scalar
Python; only what numpy rounds differently from scalar math (matrix products, cos/sin/tan,
x**3) stays in numpy calls, so the numbers are the former vectorised form's to the last bit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from receiver.core.records import PairObservation
from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap, shape_area_m2
from receiver.core.native import load
from receiver.locate.lsq import LM_FTOL, LM_LAMBDA0, LM_LAMBDA_MAX, covariance_at, lm_iterate
from receiver.locate.pose import _joint_fun, rotation_to_ypr_deg, ypr_to_rotation
from receiver.locate.settings import VehicleSettings
from receiver.locate.road_kalman import RangeKalman, RoadKalman, wrap_pi

ESTIMATORS = ("eq18", "oblique", "baseline", "fused")
ZONES = ("safe", "min", "critical")
# Mapped heads that give the road direction near a light (`_road_heading`): two or three a side
# of the road, whatever their spacing (a staggered layout's 12.5 m, an alternating one's 30 m).
ROAD_HEADS = 6
# The range a saturated pair's bloomed areas may read, relative to its baseline range: bloom only
# grows a blob (at most the true range, 1.25: the envelope's edge noise) and by 2-3x, up to 4x
# on a small far one (at least half the true range). A street-light head's halves taken for
# taillights read 0.2-0.4 of their baseline range.
SATURATED_AREA_SPAN = (0.5, 1.25)
# An undecoded pair ranged as taillights beyond this (m) is taken for no car: thesis Table 2's
# detection range ends at 150 m, and a far street-light head's halves (0.6 m apart) taken for
# taillights (1.4 m) read 2.3x their range, 200-250 m, with areas too small to tell them apart.
UNDECODED_FV_MAX_RANGE_M = 150.0
# Why the host is unplaced, by what the frame holds (`VehicleLocator.hv_reason`).
NO_LIGHT = "no light in view"
NOT_DECODED = "lights in view, not decoded yet"
ONE_LIGHT = "one street light decoded, waiting for a second"
DOWN = np.array([0.0, 0.0, -1.0])
# Compiled host-pose solve (`_solve_native`); None: the numpy path (`_solve_pose`).
_k = load("receiver.locate._vehicle_pose")
# Compiled per-pair ranging loop (`range_core`); None: its Python loop.
_kr = load("receiver.locate._vehicle_range")
# Compiled map-aided association (`VehicleLocator._associate`); None: its numpy form.
_ka = load("receiver.locate._vehicle_step")

# ------------------------------------------------------------------------------ model constants
# What the locator's model assumes, not what a user sets (VehicleSettings holds those); each
# with its unit and why its value.
# Ranging.
SL_SEPARATION_SIGMA_PX = 0.3    # px, a head's centroid difference: one half lit at a time, the other's centroid a frame or more old
FV_CENTROID_SIGMA_PX = 0.2      # px, a taillight centroid measured this frame (`fv_measured`; separation error ~0.4 % of 44-125 px)
FV_AREA_MODEL_REL = 0.05        # eq. 18 model error of a taillight's striped 10-50 px envelope cut by clock edges, relative
EDGE_SIGMA_PX = 0.1             # px, an envelope edge's 1-sigma all around
AREA_MODEL_REL = 0.01           # eq. 18 model error of a street-light half (calibration, shape), relative
BASELINE_MODEL_REL = 0.002      # baseline-range model error with a mapped baseline, relative
TAILLIGHT_YAW_SIGMA_DEG = 5.0   # deg, a car's heading about the host's (its taillight baseline's direction)
CONSISTENCY_SIGMAS = 4.0        # area and baseline ranges further apart than this many sigmas: the area one is dropped
ORIENT_SIGMA_POSE_DEG = 0.3     # deg, camera orientation 1-sigma once a pose is solved
ORIENT_SIGMA_PRIOR_DEG = 5.0    # deg, ... with the nominal tilt only (a mount's pitch is known to a few degrees)
# Host pose.
CAMERA_HEIGHT_SIGMA_M = 0.3     # m, the camera height prior's 1-sigma (load, suspension, mount)
TILT_SIGMA_DEG = 10.0           # deg, weak tilt prior of the pose solve (matters with one light only)
MIN_LIGHTS = 2                  # decoded heads a full pose solve needs (one: `_single_fix`, `_single_observation`)
POSE_F_SCALE = 3.0              # sigmas, the soft-L1 loss's knee
POSE_MAX_ITER = 20              # Levenberg-Marquardt iterations of a cold pose solve
POSE_TRACK_ITER = 2             # ... warm-started from the road filter's prediction (more lean on that prediction twice)
POSE_ROT_TOL_RAD = 1e-5         # rad, the solve stops once a step turns the camera by less
POSE_POS_TOL_M = 1e-3           # m, ... and moves it by less (the output's resolution ~1e-4 m)
FIX_FLOOR_M = 0.15              # m, added in quadrature to a pose fix's x, y sigma: the heads' model errors the solve does not know
HEADING_SIGMA_DEG = 1.0         # deg, camera yaw as the host heading's measurement (mounting)
ACCEL_PSD = 2.0                 # m^2/s^3, a car's accelerations (~2 m/s^2 for ~1 s)
YAW_ACCEL_PSD = 0.05            # rad^2/s^3, its turn-rate changes
INIT_SPEED_SIGMA_MPS = 15.0     # m/s, speed 1-sigma of a filter started without odometry
INIT_OMEGA_SIGMA_RPS = 0.2      # rad/s, turn-rate 1-sigma at a start
GATE_CHI2 = 13.8                # a fix's innovation gate (chi-square 2 dof, 99.9 %)
MAX_REJECTS = 3                 # consecutive gated fixes that restart the filter
SL1_RANGE_FLOOR_REL = 0.05      # added in quadrature to a single light's range sigma: one head's range error persists over frames
SL1_MAX_STD_M = 1.5             # m, a single light updates the filter only while its predicted 2D std is at most this
SL1_START_MAX_STD_M = 0.7       # m, ... and starts it only from a single-light pose this sure
SPEED_INIT_MIN_DT_S = 0.12      # s, the first two fixes this far apart give the speed (one frame apart, fix noise dominates)
SPEED_HIST_S = 0.3              # s, the heads' image growth over this long gives the speed at a start without odometry
SPEED_HIST_MIN = 5              # ... from at least this many separations
SPEED_MOTION_FLOOR_MPS = 1.0    # m/s, ... its sigma at least this
ASSOC_MAX_STD_M = 1.0           # m, undecoded pairs are matched to mapped heads only while the filter's 2D std is at most this
ASSOC_GATE_CHI2 = 9.21          # ... Mahalanobis^2 gate of a pair's midpoint to a projected head (chi-square 2 dof, 99 %)
ASSOC_MAX_AGE = 1               # frames, ... both emitters' own blobs seen within this
ASSOC_SEP_TOL = 0.3             # ... and the separation within this fraction of the head's predicted one
OBS_GATE_CHI2 = 16.3            # one light's (u, v, range) into the filter: chi-square 3 dof, 99.9 %
# Cars ahead.
FV_ACCEL_PSD = 4.0              # m^2/s^3, relative acceleration of a car ahead
FV_RATE_SIGMA_MPS = 10.0        # m/s, initial range-rate 1-sigma
FV_CONFIRM_S = 0.6              # s, an undecoded pair ranged once and not again within this is forgotten (no car's taillights)
FV_GATE_CHI2 = 9.0              # range innovation gate of a car's track (3 sigma)
FV_MAX_REJECTS = 4              # consecutive gated ranges that restart the track
FV_DUP_DEG = 0.5                # deg, car entries closer in bearing are one car (one kept)
FV_COAST_MAX_REL = 0.05         # a coasting car entry is reported while its std is at most this x its distance
FV_LATERAL_SIGMA_M = 0.05       # m, a car's lateral position 1-sigma floor
FV_BEARING_SIGMA_DEG = 0.05     # deg, ... and its bearing's
FV_LATERAL_RATE_SIGMA_MPS = 2.0  # m/s, initial lateral-rate 1-sigma
FV_LATERAL_ACCEL_PSD = 0.5      # m^2/s^3, lateral relative acceleration (a lane change)
FV_YAW_MIN_FRAMES = 10          # lateral positions before a car's yaw is estimated
FV_YAW_MIN_SPEED_MPS = 3.0      # m/s, ... and the car's ground speed needed (yaw = atan2(vy, vx))
FV_YAW_MAX_RAD = 0.5            # rad, |yaw| clipped here (~29 deg)
FV_MAX_TILT_DEG = 3.0           # deg, an undecoded pair is taillights only if this level (road cross-slope, body roll)
FV_MAX_AREA_RATIO = 2.0         # ... and (unsaturated) its two areas within this ratio
FV_SL_GATE_DEG = 0.5            # deg, ... and no emitter this close to a mapped head projected from the placed host
FV_OCCLUSION_RATIO = 1.1        # ... and no farther lamp (separation this many times smaller) inside its body's image
CLOSING_MIN_MPS = 0.2           # m/s, ttc only when closing faster than this





@dataclass(frozen=True)
class VehicleResult:
    """`vehicle`: INTERFACES.md vehicle object {"hv": {...} | None, "fv": [...]}, or None when no
    pair is in view and no HV track is kept. `ranges`: aligned with the input pairs, each
    (distance_m, sigma_m, estimator) or None."""

    vehicle: dict | None
    ranges: tuple = field(default_factory=tuple)


# ------------------------------------------------------------------------------ helpers

def _sides(shape: str | None, size) -> tuple[float, float]:
    """Side lengths (m) of an emitter: [width, length] (width along the pair's baseline), a
    circle's diameter twice; NaN when unknown."""
    if not size:
        return math.nan, math.nan
    return float(size[0]), float(size[1] if len(size) > 1 and shape != "circle" else size[0])


def _finite(v) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _r(v, nd=4):
    """round(v, nd) of a finite number, else None (the records' numbers)."""
    v = _finite(v)
    return None if v is None else round(v, nd)


_r_py = _r
if _kr is not None:
    _r = _kr.rnd            # noqa: F811 -- the same numbers, compiled (tests/engine/test_vehicle_native.py)


def level_rotation(R_cw: np.ndarray) -> np.ndarray:
    """(3, 3) rotation turning camera-frame vectors into the camera's level frame (module doc):
    rows are the level axes (ahead, left, up) expressed in the camera frame."""
    ux, uy, uz = (float(v) for v in R_cw[:, 2])      # world up in the camera frame
    fx, fy, fz = -ux * uz, -uy * uz, 1.0 - uz * uz    # the optical axis minus its up component
    n = math.sqrt(fx * fx + fy * fy + fz * fz)
    fx, fy, fz = (fx / n, fy / n, fz / n) if n > 1e-9 else (0.0, -1.0, 0.0)
    return np.array([[fx, fy, fz], [uy * fz - uz * fy, uz * fx - ux * fz, ux * fy - uy * fx], [ux, uy, uz]])


def nominal_rotation(settings: VehicleSettings, yaw_deg: float = 0.0) -> np.ndarray:
    return ypr_to_rotation(yaw_deg, settings.camera_pitch_deg, 0.0)


def _undistort(camera: CameraModel, a_px: np.ndarray, b_px: np.ndarray):
    """Normalized points of a, b (N, 2) and the px^2 -> normalized area factor at each."""
    n = len(a_px)
    off = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    pts = np.concatenate([a_px[:, None, :] + off, b_px[:, None, :] + off], axis=1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, camera.K, camera.dist).reshape(n, 2, 3, 2)
    j1 = und[:, :, 1] - und[:, :, 0]
    j2 = und[:, :, 2] - und[:, :, 0]
    det = np.abs(j1[..., 0] * j2[..., 1] - j1[..., 1] * j2[..., 0])      # (N, 2)
    return und[:, 0, 0], und[:, 1, 0], det[:, 0], det[:, 1]


def _rays(u: np.ndarray) -> np.ndarray:
    if _kr is not None and u.ndim == 2 and u.shape[1] == 2:
        out = np.empty((len(u), 3))
        _kr.rays(np.ascontiguousarray(u, float), out)
        return out
    v = np.empty((len(u), 3))
    v[:, :2] = u
    v[:, 2] = 1.0
    return v / np.sqrt(np.add.reduce(v * v, 1))[:, None]


NAN = math.nan
SQRT2 = math.sqrt(2.0)


def _sqrt(x: float) -> float:
    """math.sqrt with numpy's IEEE results: NaN for a negative or NaN argument."""
    return math.sqrt(x) if x >= 0.0 else NAN


def _div(a: float, b: float) -> float:
    """a / b with numpy's IEEE results for b == 0 (+-inf, NaN for 0/0 or NaN)."""
    try:
        return a / b
    except ZeroDivisionError:
        return NAN if a != a or a == 0.0 else math.copysign(math.inf, a) * math.copysign(1.0, b)


def _area_range(rx, ry, rz, cos3, eta, j, A, S1, S2, circle, nx, ny, nz, osig, off, edge_sigma):
    """One emitter's area range (module doc, "oblique"): (d, ea, eb) with d the distance along
    the ray r (unit, camera frame), ea / eb its relative edge / foreshortening sigmas. S1, S2:
    the emitter's side (or diameter) vectors (camera frame, m); their components across the ray
    (a locally parallel projection; scale-free, so no distance is needed) give the seen
    outline's P / sqrt(area): foreshortened panels are long and thin, so their perimeter is far
    above the shape's own P / sqrt(A)."""
    s1x, s1y, s1z = S1
    s2x, s2y, s2z = S2
    k1 = s1x * rx + s1y * ry + s1z * rz
    k2 = s2x * rx + s2y * ry + s2z * rz
    p1x, p1y, p1z = s1x - k1 * rx, s1y - k1 * ry, s1z - k1 * rz
    p2x, p2y, p2z = s2x - k2 * rx, s2y - k2 * ry, s2z - k2 * rz
    l1 = math.sqrt(p1x * p1x + p1y * p1y + p1z * p1z)
    l2 = math.sqrt(p2x * p2x + p2y * p2y + p2z * p2z)
    cx, cy, cz = p1y * p2z - p1z * p2y, p1z * p2x - p1x * p2z, p1x * p2y - p1y * p2x
    ar = math.sqrt(cx * cx + cy * cy + cz * cz)
    if circle:
        kperim = _div((math.pi / 2) * (l1 + l2), math.sqrt(math.pi * ar / 4))
    else:
        kperim = _div(2.0 * (l1 + l2), math.sqrt(ar))
    sq_eta = _sqrt(max(eta, 0.0))
    eta_c = eta + kperim * sq_eta * off + math.pi * off * off if off else eta
    cos_th = abs(nx * rx + ny * ry + nz * rz)
    d = _sqrt(_div(A * cos_th, eta_c * j * cos3)) if eta > 0 and cos_th > 1e-3 else NAN
    tan_th = _div(_sqrt(max(1.0 - cos_th * cos_th, 0.0)), max(cos_th, 1e-3))
    return d, _div(edge_sigma * kperim, 2.0 * sq_eta), 0.5 * tan_th * osig


def _floats(v, n: int) -> list:
    """Rows of v as Python floats: an array's `tolist()`, a list as it is, a scalar n times."""
    if isinstance(v, np.ndarray):
        return [float(v)] * n if v.ndim == 0 else v.tolist()
    return v if isinstance(v, list) else [float(v)] * n


def range_core(ua, ub, ja, jb, eta_a, eta_b, area_m2, S1, S2, circle, B_cam, n_cam, orient_sigma_rad,
               base_model_rel, focal_px, settings: VehicleSettings, centroid_sigma_px=None, area_model_rel=None):
    """Ranging of N pairs (module doc). ua, ub (N, 2) normalized; ja, jb (N,) area factors;
    eta_a, eta_b (N,) px^2; area_m2 (N,); S1, S2 (N, 3) emitter side vectors and `circle` (N,)
    bool (`_area_range`); B_cam (N, 3) baseline a -> b (sign fixed here from the image);
    n_cam (N, 3) emitter normals; orient_sigma_rad, base_model_rel (N,); centroid_sigma_px,
    area_model_rel: scalars or (N,) (default: the settings'). Returns a dict of length-N lists
    of floats (NaN where unavailable; `flip`: B reversed) and the unit rays `ra`, `rb` (N, 3).
    Scalar math per pair (a frame has 1-15 pairs: numpy's per-call overhead dominated the
    vectorised form, ~220 calls); the rays and cos(alpha)^3 stay vectorised (numpy's own
    rounding of the power, so the numbers are the vectorised form's to the last bit)."""
    s = settings
    n = len(ua)
    r2 = _rays(np.concatenate([ua, ub]))          # (2N, 3): A's rays, then B's
    ra, rb = r2[:n], r2[n:]
    cos3 = (r2[:, 2] ** 3).tolist()
    R2 = r2.tolist()
    amr = AREA_MODEL_REL if area_model_rel is None else area_model_rel
    csig = s.centroid_sigma_px if centroid_sigma_px is None else centroid_sigma_px
    cols = [_floats(v, n) for v in (ja, jb, eta_a, eta_b, area_m2, orient_sigma_rad, base_model_rel, amr, csig,
                                    ua, ub, S1, S2, B_cam, n_cam)]
    cols += [circle.tolist() if isinstance(circle, np.ndarray) else list(circle), R2[:n], R2[n:], cos3[:n], cos3[n:]]
    off, esig, cons = s.edge_offset_px, EDGE_SIGMA_PX, CONSISTENCY_SIGMAS
    keys = ("eq18", "eq18_sigma", "oblique", "oblique_sigma", "baseline", "baseline_sigma", "fused", "fused_sigma",
            "d_a", "d_b", "s_a", "s_b", "flip", "base_fused_only", "area_clash")
    if _kr is not None:
        out = dict(zip(keys, _kr.range_rows(*cols, float(focal_px), float(off), float(esig), float(cons))))
        out.update(ra=ra, rb=rb)
        return out
    rows = []
    for (ja_i, jb_i, eta_a_i, eta_b_i, A, osig, bm, amr_i, csig_i, (uax, uay), (ubx, uby), S1i, S2i, (bx, by, bz),
         (nx, ny, nz), circ, (rax, ray, raz), (rbx, rby, rbz), cos3_a, cos3_b) in zip(*cols):
        # Image direction of the baseline at the midpoint: d(x/z) = (dX - u dZ) / Z.
        umx, umy = 0.5 * (uax + ubx), 0.5 * (uay + uby)
        dux, duy = ubx - uax, uby - uay
        flip = (bx - umx * bz) * dux + (by - umy * bz) * duy < 0
        if flip:
            bx, by, bz = -bx, -by, -bz
        # Baseline: [-ra, rb] [sa, sb]^T = B in least squares (normal matrix [[1, -rab], [-rab, 1]]).
        rab = rax * rbx + ray * rby + raz * rbz
        ba = -(rax * bx + ray * by + raz * bz)
        bb = rbx * bx + rby * by + rbz * bz
        det = 1.0 - rab * rab
        sa = _div(ba + rab * bb, det)
        sb = _div(bb + rab * ba, det)
        px, py, pz = sa * rax + sb * rbx, sa * ray + sb * rby, sa * raz + sb * rbz
        d_base = 0.5 * _sqrt(px * px + py * py + pz * pz)
        sep_px = math.sqrt(dux * dux + duy * duy) * focal_px
        s_base = d_base * (_div(SQRT2 * csig_i, sep_px) + bm)
        if not (det > 1e-14 and sa > 0 and sb > 0):
            d_base = NAN
        # Areas (eq. 18 and its corrected form), each emitter.
        da, ea_a, eb_a = _area_range(rax, ray, raz, cos3_a, eta_a_i, ja_i, A, S1i, S2i, circ, nx, ny, nz, osig,
                                     off, esig)
        db, ea_b, eb_b = _area_range(rbx, rby, rbz, cos3_b, eta_b_i, jb_i, A, S1i, S2i, circ, nx, ny, nz,
                                     osig, off, esig)
        if eta_a_i > 0 and eta_b_i > 0:
            d18 = 0.5 * focal_px * (_sqrt(_div(A, eta_a_i)) + _sqrt(_div(A, eta_b_i)))
        else:
            d18 = NAN
        s18 = d18 * (amr_i + 0.5 * (ea_a + ea_b))
        if not math.isfinite(s18):
            d18 = NAN
        pax, pay, paz = 0.5 * (da * rax + db * rbx), 0.5 * (da * ray + db * rby), 0.5 * (da * raz + db * rbz)
        d_ob = _sqrt(pax * pax + pay * pay + paz * paz)
        fore = 0.5 * (eb_a + eb_b)
        s_ob = d_ob * _sqrt((ea_a * ea_a + ea_b * ea_b) / 4 + fore * fore + amr_i * amr_i)
        wa = _div(1.0, s_ob * s_ob)
        wb = _div(1.0, s_base * s_base)
        fa = math.isfinite(d_ob) and math.isfinite(wa)
        fb = math.isfinite(d_base) and math.isfinite(wb)
        # The area range rests on the emitter's normal and size (a map entry without the normal
        # of a tilted head reads it several times too short); the baseline only on geometry.
        # When the two disagree beyond `CONSISTENCY_SIGMAS`, the area range is dropped.
        clash = fa and fb and abs(d_ob - d_base) > cons * _sqrt(s_ob * s_ob + s_base * s_base)
        fa = fa and not clash
        wa = wa if fa else 0.0
        wb = wb if fb else 0.0
        wsum = wa + wb
        if wsum > 0:
            d_f = (wa * (d_ob if fa else 0.0) + wb * (d_base if fb else 0.0)) / wsum
            s_f = 1.0 / math.sqrt(wsum)
        else:
            d_f = s_f = NAN
        amr2 = amr_i * amr_i
        rows.append((d18, s18, d_ob, s_ob, d_base, s_base, d_f, s_f, da, db,
                     da * _sqrt(ea_a * ea_a + eb_a * eb_a + amr2), db * _sqrt(ea_b * ea_b + eb_b * eb_b + amr2),
                     flip, fb and not fa, clash))
    out = dict(zip(keys, (list(c) for c in zip(*rows)))) if rows else {k: [] for k in keys}
    out.update(ra=ra, rb=rb)
    return out


def _split_pairs(fun, n_pairs: int, sep_gain: float):
    """The joint residuals `fun` (receiver.locate.pose._joint_fun, the angle rows first: per
    point x, y; points a, b of each pair in turn) with each pair's four angle rows turned into
    its midpoint (x, y; weight unchanged: an orthonormal turn) and its centroid difference
    (x, y) scaled by `sep_gain` (< 1: the separation of a head's centroids is far less sure
    than their midpoint, SL_SEPARATION_SIGMA_PX). Same interface: fun(p),
    fun.jac(p), fun.fun_jac(p)."""
    m = 4 * n_pairs
    h = 1.0 / SQRT2
    T = np.array([[h, 0, h, 0], [0, h, 0, h], [-h * sep_gain, 0, h * sep_gain, 0], [0, -h * sep_gain, 0, h * sep_gain]])

    def turn(a):
        head = a[:m].reshape(n_pairs, 4, -1)
        out = a.copy()
        out[:m] = np.einsum("ij,kj...->ki...", T, head).reshape(out[:m].shape)
        return out

    def f(p):
        return turn(fun(p))

    def jac(p):
        return turn(fun.jac(p))

    def fun_jac(p):
        r, J = fun.fun_jac(p)
        return turn(r), turn(J)

    f.jac, f.fun_jac = jac, fun_jac
    return f


def _fix_covariance(r: np.ndarray, J: np.ndarray) -> np.ndarray:
    """(6, 6) covariance of a pose solution from its whitened residuals and Jacobian
    (receiver.locate.lsq.covariance_at; compiled: by Cholesky when J' J is positive definite)."""
    if _k is not None:
        out = np.empty((6, 6))
        if _k.covariance(r, J, out) == 0:
            return out
    with np.errstate(over="ignore", invalid="ignore"):
        return covariance_at(r, J, J.shape[1])[0]


_W_CACHE: dict = {}


def _prior_whitening(cov: np.ndarray) -> np.ndarray:
    """W with W^T W = cov^-1 (receiver.locate.pose._joint_fun's), kept per covariance."""
    key = cov.tobytes()
    W = _W_CACHE.get(key)
    if W is None:
        W = _W_CACHE[key] = np.ascontiguousarray(np.linalg.cholesky(np.linalg.inv(cov)).T)
    return W


def _solve_native(L, uv, sigma_uv, d, sd, up, up_sigma, C_prior, W, n_pairs, sep_gain, attitude, p0,
                  max_iter, s: VehicleSettings):
    """The compiled form (receiver.locate._vehicle_pose) of `_solve_pose`'s soft-L1 solve:
    `_split_pairs(_joint_fun(...))` with `_with_attitude_prior`'s rows, iterated as
    `lm_iterate` with the solve's stopping rule (W: the position prior's whitening,
    `_prior_whitening`), and `_pose_result`'s checks. Returns (x, r, J, R, cov6, status) at the
    solution (status: `receiver.locate._vehicle_pose.solve_pose`'s, 0 = a fix)."""
    att = np.zeros((0, 8))
    if attitude:
        rows = []
        for kind, name in enumerate(("yaw", "pitch", "roll", "mid_range")):
            v = attitude.get(name)
            if v is None:
                continue
            if name == "mid_range":
                M, D, sig_d = v
                rows.append([3.0, 0.0, 1.0, *np.asarray(M, float), D, sig_d])
            else:
                rows.append([float(kind), v[0], v[1], 0.0, 0.0, 0.0, 0.0, 1.0])
        att = np.array(rows, float).reshape(-1, 8)
    n_d = sum(1 for v in d.tolist() if math.isfinite(v))
    r = np.empty(_k.rows(len(L), n_d, len(att)))
    J = np.empty((len(r), 6))
    x = np.array(p0, float)
    R, cov6 = np.empty((3, 3)), np.empty((6, 6))
    status = _k.solve_pose(L, uv, float(sigma_uv), d, sd, up, float(up_sigma), C_prior, W, int(n_pairs),
                           float(sep_gain), att, float(POSE_F_SCALE), x, int(max_iter), float(POSE_ROT_TOL_RAD),
                           float(POSE_POS_TOL_M), LM_FTOL, LM_LAMBDA0, LM_LAMBDA_MAX, r, J, R, cov6)
    return x, r, J, R, cov6, status


def camera_yaw(R_cw: np.ndarray) -> float:
    """Azimuth (rad, counter-clockwise from world +x) of the optical axis (R_cw's third row)."""
    return math.atan2(float(R_cw[2, 1]), float(R_cw[2, 0]))


def _with_attitude_prior(fun, yaw=None, pitch=None, roll=None, mid_range=None):
    """The residuals `fun` (pose p = Rodrigues vector, C) with a row per given prior, each
    (value rad, sigma rad): the optical axis's azimuth (`camera_yaw`; wrapped), its elevation
    asin(R[2, 2]) (pitch, up positive) and the roll atan2(-R[0, 2], -R[1, 2]) (the angles of
    receiver.locate.pose.ypr_to_rotation). With a single street light the image fixes the camera
    on a circle around the head: the heading prior picks the point (lateral sigma ~ range x
    sigma), the roll and pitch priors keep the two emitters' slant from turning the camera.
    Jacobians from cv2.Rodrigues' derivative of R (its 3x9, row-major elements of R).
    `mid_range`: (M (3,), D m, sigma m), one more row (|M - C| - D) / sigma: a single head's
    range to its midpoint, in place of its two emitters' own (noisy) area ranges, whose
    difference would turn the camera (the bundled recording: yaw 3-5 deg off)."""
    rows = [(k, v) for k, v in (("yaw", yaw), ("pitch", pitch), ("roll", roll), ("range", mid_range))
            if v is not None]

    def extra(p):
        R, dR = cv2.Rodrigues(np.asarray(p[:3], float).reshape(3, 1))
        r = np.empty(len(rows))
        J = np.zeros((len(rows), len(p)))
        for i, (kind, (v0, *sig)) in enumerate(rows):
            sig = sig[0] if len(sig) == 1 else sig
            if kind == "yaw":
                a, b = float(R[2, 0]), float(R[2, 1])
                n2 = max(a * a + b * b, 1e-12)
                r[i] = wrap_pi(math.atan2(b, a) - v0) / sig
                J[i, :3] = (a * dR[:, 7] - b * dR[:, 6]) / n2 / sig
            elif kind == "range":
                M, D, sig_d = v0, sig[0], sig[1]
                Vm = np.asarray(M, float) - p[3:]
                dm = math.sqrt(float(Vm @ Vm))
                r[i] = (dm - D) / sig_d
                J[i, 3:] = -Vm / max(dm, 1e-9) / sig_d
            elif kind == "pitch":
                z = min(max(float(R[2, 2]), -1.0 + 1e-12), 1.0 - 1e-12)
                r[i] = (math.asin(z) - v0) / sig
                J[i, :3] = dR[:, 8] / math.sqrt(1.0 - z * z) / sig
            else:
                a, b = -float(R[0, 2]), -float(R[1, 2])
                n2 = max(a * a + b * b, 1e-12)
                r[i] = wrap_pi(math.atan2(a, b) - v0) / sig
                J[i, :3] = (b * -dR[:, 2] - a * -dR[:, 5]) / n2 / sig
        return r, J

    def f(p):
        return np.append(fun(p), extra(p)[0])

    def jac(p):
        return np.vstack([fun.jac(p), extra(p)[1]])

    def fun_jac(p):
        r, J = fun.fun_jac(p)
        r1, j1 = extra(p)
        return np.append(r, r1), np.vstack([J, j1])

    f.jac, f.fun_jac = jac, fun_jac
    return f


def _pick(res: dict, i: int, estimator: str):
    """(distance, sigma, estimator) of pair i, falling back from "fused" to what exists."""
    order = [estimator] if estimator != "fused" else ["fused"]
    for name in order:
        d, s = res[name][i], res[name + "_sigma"][i]
        if math.isfinite(d) and math.isfinite(s) and d > 0:
            if name == "fused":
                fa = math.isfinite(res["oblique"][i]) and math.isfinite(res["oblique_sigma"][i]) \
                    and not res["area_clash"][i]
                fb = math.isfinite(res["baseline"][i]) and math.isfinite(res["baseline_sigma"][i])
                name = "fused" if fa and fb else ("baseline" if fb else "oblique")
            return float(d), float(s), name
    return None


def eq44_47(D1: float, D2: float, sl1: np.ndarray, sl2: np.ndarray, cam_height: float,
            sl2_left_of_sl1: bool) -> np.ndarray | None:
    """Thesis eqs. 44-47: HV (camera) road position (x, y) from the direct distances D1 (nearer)
    and D2 to street lights at sl1, sl2 (3,) and the camera height. `sl2_left_of_sl1`: SL2 is
    seen further left in the image than SL1 (tells the side of the SL1-SL2 line)."""
    (x1, y1, z1), (x2, y2, z2) = (float(v) for v in sl1[:3]), (float(v) for v in sl2[:3])
    dz1, dz2 = z1 - cam_height, z2 - cam_height
    a1s, a2s = D1 * D1 - dz1 * dz1, D2 * D2 - dz2 * dz2          # flat distances squared
    if a1s <= 0 or a2s <= 0:
        return None
    vx, vy = x2 - x1, y2 - y1
    dsl = math.sqrt(vx * vx + vy * vy)
    if dsl < 1e-6:
        return None
    ux, uy = vx / dsl, vy / dsl
    c = ((a2s - a1s) - dsl * dsl) / (2.0 * dsl)                  # eq. 46
    h = math.sqrt(max(a1s - c * c, 0.0))                          # eq. 47
    nx, ny = -uy, ux                                             # left normal of SL1 -> SL2
    # cross_z(SL1 - P, SL2 - P) = -s h dsl; seen counter-clockwise (SL2 left of SL1) -> > 0.
    s = -1.0 if sl2_left_of_sl1 else 1.0
    # a1^2 = c^2 + h^2 (eq. 44): the foot point F of the camera on the line lies c before SL1
    # (SL1 = F + c u, SL2 = F + (c + d) u, eq. 45) and P = F - s h n.
    return np.array([x1 - c * ux - s * h * nx, y1 - c * uy - s * h * ny])


def fv_measured(p: PairObservation):
    """((ax, ay, bx, by), (area_a, area_b)) of a taillight pair whose two emitters were both
    measured in this frame (`a_seen`, `b_seen` of age 0), else None. A taillight pair is ranged
    from these measured centroids only: the pair's rigid-model positions `a_px`, `b_px` carry
    the baseline from its founding frame scaled by the square root of the emitters' envelope
    areas (an area measurement, a few % off on 10-50 px striped blobs) and rounded to whole
    pixels, and a partner emitter seen frames ago has moved by the camera's shake and the
    car's motion since."""
    a, b = p.a_seen, p.b_seen
    if a is None or b is None or a[2] != 0 or b[2] != 0:
        return None
    return (a[0][0], a[0][1], b[0][0], b[0][1]), (a[1], b[1])


def _drop_clipped_areas(res: dict, clipped: list) -> None:
    """`range_core`'s results (in place) without the area ranges of saturated emitters
    (`clipped`: per row (A saturated, B saturated)): a clipped blob's area is blur and bloom,
    2-3x the emitter's true image area, so the pair is ranged by its baseline alone and no
    emitter range from such a blob enters the host's pose. What the bloomed areas read stays as
    `area_bound` (NaN on rows without saturation): bloom only grows a blob, so it is a range at
    most the true one and, within `SATURATED_AREA_SPAN`, not far below it."""
    n = len(clipped)
    bound = [NAN] * n
    for k, (ca, cb) in enumerate(clipped):
        if not (ca or cb):
            continue
        bound[k] = res["oblique"][k]
        for name in ("oblique", "oblique_sigma", "eq18", "eq18_sigma"):
            res[name][k] = NAN
        if ca:
            res["d_a"][k] = res["s_a"][k] = NAN
        if cb:
            res["d_b"][k] = res["s_b"][k] = NAN
        ok = math.isfinite(res["baseline"][k]) and math.isfinite(res["baseline_sigma"][k])
        res["fused"][k] = res["baseline"][k] if ok else NAN
        res["fused_sigma"][k] = res["baseline_sigma"][k] if ok else NAN
        res["area_clash"][k] = False
        res["base_fused_only"][k] = ok
    res["area_bound"] = bound


def range_pair(pair: PairObservation, camera: CameraModel, led_map: LedMap,
               settings: VehicleSettings = VehicleSettings(), R_cw: np.ndarray | None = None,
               estimator: str | None = None) -> tuple[float, float, str] | None:
    """Distance (m), its 1-sigma (m) and the estimator name of one pair, or None (half a pair,
    unknown SL, missing sizes). `R_cw`: camera orientation (else the nominal tilt, yaw 0)."""
    loc = VehicleLocator(camera, led_map, settings)
    est = estimator or "fused"
    if est not in ESTIMATORS:
        raise ValueError(f"unknown estimator {est!r}")
    out = loc._range_pairs([pair], R_cw, R_cw is not None)
    if out is None or out[0][0][0] is None:
        return None
    res, k = out[0][0]
    return _pick(res, k, est)


# ------------------------------------------------------------------------------ locator

class VehicleLocator:
    """Streaming vehicle positioning (module doc). `hv_reason`: why the HV is not placed
    (None when it is); `fv_reason`: why taillight pairs are not ranged (None when they are, or
    no pair other than a decoded street light was seen)."""

    def __init__(self, camera: CameraModel, led_map: LedMap, settings: VehicleSettings = VehicleSettings()):
        self.camera = camera
        self.map = led_map
        self.s = settings
        self.focal = camera.focal_px
        # Per-emitter centroid sigma whose sqrt(2) multiple is a head's separation sigma
        # (`SL_SEPARATION_SIGMA_PX` with the two centroids' own `centroid_sigma_px`).
        self._sl_csig = math.sqrt(settings.centroid_sigma_px ** 2 + 0.5 * SL_SEPARATION_SIGMA_PX ** 2)
        self.R_nominal = nominal_rotation(settings)
        self._up = np.ascontiguousarray(self.R_nominal[:, 2])      # world up seen by the nominal camera
        self._W: np.ndarray | None = None                          # the pose's position-prior whitening
        self._rvec_of = (None, None)             # (R, its Rodrigues vector) of the last compiled solve
        self.kf = RoadKalman(accel_psd=ACCEL_PSD, yaw_accel_psd=YAW_ACCEL_PSD,
                             init_speed_sigma=INIT_SPEED_SIGMA_MPS,
                             init_omega_sigma=INIT_OMEGA_SIGMA_RPS,
                             gate_chi2=GATE_CHI2, max_rejects=MAX_REJECTS,
                             max_coast_s=settings.max_coast_s)
        self.R_last: np.ndarray | None = None     # last solved camera orientation
        self.z_last = settings.camera_height_m    # ... and height (m)
        self._tilt: tuple | None = None            # ... its pitch and roll (deg; `R_tilt`): the mounting, kept
        self._R_tilt: np.ndarray | None = None
        self._ypr = (None, None)                  # (R, rotation_to_ypr_deg(R)) of the last R asked (`_ypr_of`)
        self.pitch_ref: float | None = None       # camera pitch (rad) of the last full (2+ light) pose
        self._pending = None                      # (t_s, xy, cov, yaw, psi sigma): a start's first fix
        self._sep_hist: dict = {}                 # pair key -> [(t_s, separation px)] (`_keep_separations`)
        self._sep_t, self._sep_sorted = -math.inf, True   # last step's time; whether times never went back
        self.hv_reason: str | None = "no street light seen yet"
        self.unplaced: dict[str, int] = {}     # hv_reason -> frames left unplaced for it
        self.fv_reason: str | None = None         # why taillight pairs go unranged (None: they don't)
        self.last_fix: dict | None = None         # {"pose": (x, y) | None, "eq44-47": (x, y) | None}
        self.fv_tracks: dict = {}
        self._nstep = 0                            # step count (frames)
        self._seen_hist: dict = {}                # SL ID -> ({step: A px}, {step: B px}) (`_sl_centroids`)
        # Per-SL constants.
        self._sl = {}
        for led in led_map.leds.values():
            if led.mode != "s2psk" or not 0 <= led.id <= 0x7F:
                continue
            A = led.area_m2
            em = None if led.emitters is None else np.asarray(led.emitters, float)
            normal = getattr(led, "normal", None)
            nrm = DOWN if normal is None else np.asarray(normal, float) / np.linalg.norm(normal)
            if em is not None:
                B = em[1] - em[0]
            elif led.baseline_m is not None:
                B = None
            else:
                B = None
            w, h = _sides(led.shape, led.size)
            if B is not None:
                L = float(np.linalg.norm(B))
            else:
                L = led.baseline_m if led.baseline_m else math.nan
            Bw = B if B is not None else np.array([0.0, L, 0.0])
            row = np.concatenate([Bw, nrm, [np.nan if A is None else A, w, h, float(led.shape == "circle"),
                                            float(B is not None), 1.0, L]])
            self._sl[led.id] = dict(area=np.nan if A is None else A, w=w, h=h, row=row,
                                    circle=led.shape == "circle", em=em, B=B, baseline=led.baseline_m, normal=nrm, xyz=led.xyz,
                                    head=None if em is None else em.mean(0))
            self._sl[led.id]["head_t"] = None if em is None else tuple(self._sl[led.id]["head"].tolist())
            self._sl[led.id]["em_t"] = None if em is None else (tuple(em[0].tolist()), tuple(em[1].tolist()))
        # Mapped street-light heads (m, road frame): an undecoded pair on one is not a taillight pair.
        heads = [c["head"] if c["em"] is not None else np.asarray(c["xyz"], float) for c in self._sl.values()
                 if c["em"] is not None or c["xyz"] is not None]
        self._sl_heads = np.array(heads, float).reshape(-1, 3)
        self._heads_t = {i: c["head_t"] for i, c in self._sl.items() if c["em"] is not None}    # `_pose_ranges`
        # The heads of the lights with mapped emitters, their IDs and baselines (`_associate`).
        em_ids = [i for i, c in self._sl.items() if c["em"] is not None]
        self._em_heads = (em_ids, np.array([self._sl[i]["head"] for i in em_ids], float).reshape(-1, 3),
                          np.array([float(np.linalg.norm(self._sl[i]["B"])) for i in em_ids], float))
        self._sl_seen_at = (None, None, None)     # ((t_s, camera x, y, z), R, normalized points) of the heads
        self._roles: dict = {}                   # led_id -> `_role_of` (the map is fixed)
        tl = led_map.taillight
        self._tl = None
        if tl is not None and tl.get("baseline_m") and tl.get("shape") and tl.get("size"):
            w, h = _sides(tl["shape"], tl["size"])
            A = shape_area_m2(tl["shape"], tl["size"])
            Lb = float(tl["baseline_m"])
            self._tl = dict(area=A, w=w, h=h, circle=tl["shape"] == "circle", baseline=Lb,
                            row=np.array([0.0, 0, 0, 0, 0, 0, A, w, h, float(tl["shape"] == "circle"), 0, 0, Lb]))

    @property
    def R_tilt(self) -> np.ndarray | None:
        """The last solved camera's pitch and roll (yaw 0) as a rotation, or None before any fix
        (made when first asked: most frames do not)."""
        if self._tilt is None:
            return None
        if self._R_tilt is None:
            self._R_tilt = ypr_to_rotation(0.0, *self._tilt)
        return self._R_tilt

    def _ypr_of(self, R: np.ndarray) -> tuple[float, float, float]:
        """rotation_to_ypr_deg(R), kept for the last R (a frame asks for its pose's angles up to
        three times)."""
        if self._ypr[0] is not R:
            self._ypr = (R, rotation_to_ypr_deg(R))
        return self._ypr[1]

    # -------------------------------------------------------------------------- ranging
    def _role(self, p: PairObservation) -> str | None:
        """"SL" (a mapped street light's ID), "FV" (a taillight ID), "FV?" (undecoded, may be
        taillights) or None, by the pair's ID (`_role_of`, kept per ID: ~50 asks a frame)."""
        try:
            return self._roles[p.led_id]
        except KeyError:
            r = self._roles[p.led_id] = self._role_of(p.led_id)
            return r

    def _role_of(self, led_id) -> str | None:
        if led_id is not None and 0 <= led_id <= 0x7F:
            return "SL" if led_id in self._sl else None
        if led_id is not None and led_id > 0x7F:
            return "FV" if self._tl is not None else None
        return "FV?" if self._tl is not None else None

    def _range_pairs(self, pairs, R_cw, pose_known: bool):
        """Range every usable pair (vectorised). Returns (list aligned with pairs of (res, k) or
        (None, None), res dict) or None when no pair is usable."""
        R = (self.R_nominal if self.R_tilt is None else self.R_tilt) if R_cw is None else R_cw
        Lv = self.Lv = level_rotation(R)           # rows: ahead, left, up in camera frame
        idx, roles, consts, ab, eta, yaw, clipped = [], [], [], [], [], [], []
        for i, p in enumerate(pairs):
            role = self._role(p)
            if role is None:
                continue
            if role == "SL":
                if not p.both_visible:
                    continue
                ab.append(self._sl_centroids(p))
                eta.append((p.area_a_px, p.area_b_px))
                consts.append(self._sl[p.led_id]["row"])
            else:
                m = fv_measured(p)
                if m is None:
                    continue
                ab.append(m[0])
                eta.append(m[1])
                consts.append(self._tl["row"])
                tr = self.fv_tracks.get(p.key)
                yaw.append(0.0 if tr is None else tr["yaw"])
            if role == "SL":
                yaw.append(0.0)
            clipped.append((p.a_saturated, p.b_saturated))
            idx.append(i)
            roles.append(role)
        if not idx:
            return None
        n = len(idx)
        ab = np.array(ab, float)
        eta = np.array(eta, float)
        yaw = np.array(yaw, float)
        cst = np.array(consts)          # rows: B(3) normal(3) area w h circle has_B is_SL baseline (0-12)
        ua, ub, ja, jb = _undistort(self.camera, ab[:, :2], ab[:, 2:])
        osig = math.radians(ORIENT_SIGMA_POSE_DEG if pose_known else ORIENT_SIGMA_PRIOR_DEG)
        rays_m = _rays(0.5 * (ua + ub))
        lev = rays_m @ Lv.T                        # level-frame directions (ahead, left, up)
        bearing = np.arctan2(lev[:, 1], lev[:, 0])
        Bc, nc, S1, S2, bm = self._pair_geometry(R, Lv, cst, roles, yaw, rays_m, bearing, pose_known)
        s = self.s
        res = range_core(ua, ub, ja, jb, eta[:, 0], eta[:, 1], cst[:, 6], S1, S2, cst[:, 9] > 0, Bc, nc,
                         [osig] * n, bm, self.focal, s,
                         [self._sl_csig if r == "SL" else FV_CENTROID_SIGMA_PX for r in roles],
                         [AREA_MODEL_REL if r == "SL" else FV_AREA_MODEL_REL for r in roles])
        _drop_clipped_areas(res, clipped)
        res.update(ua=ua, ub=ub, lev=lev, bearing=bearing, idx=np.array(idx), roles=roles)
        aligned = [(None, None)] * len(pairs)
        for k, i in enumerate(idx):
            aligned[i] = (res, k)
        return aligned, res

    def _sl_centroids(self, p: PairObservation) -> tuple:
        """(ax, ay, bx, by) of a street-light head, distorted px: each emitter's own measured
        centroid (`a_seen`, `b_seen`), the one seen `age` frames ago moved on by the head's image
        velocity (px per frame: the other emitter, seen now, against its previous sighting,
        `_seen_hist`: the latest motion, camera shake included; else the stale one's own last
        two sightings). Own sightings would also carry the head's growth as it nears (~0.1 px a
        frame at 60 m), but are older: on the bundled recording, with its shake, raw p95
        1.58 m against 1.34 m. One emitter of a head is lit
        at a time, so one of the two is always a frame or more old; the pairing's rigid model
        (`a_px`, `b_px`: whole px, its separation scaled from the founding one) reads a far
        head's few-px separation 1-3 px short (ranges 10-30 % long: the raw pose outliers of
        the bundled recording). The model stands when a centroid is missing or no velocity is
        known."""
        if p.a_seen is None or p.b_seen is None:
            return p.a_px + p.b_px
        hist = self._seen_hist.get(p.led_id, ({}, {}))
        seen = (p.a_seen, p.b_seen)
        out = []
        for e in (0, 1):
            (cx, cy), _, age = seen[e]
            cx, cy, age = float(cx), float(cy), int(age)
            if age > 0:
                v = None
                (ox, oy), _, o_age = seen[1 - e]
                if int(o_age) == 0:
                    prev = [k for k in hist[1 - e] if k < self._nstep]
                    if prev:
                        k = max(prev)
                        px, py = hist[1 - e][k]
                        n = self._nstep - k
                        v = ((float(ox) - px) / n, (float(oy) - py) / n)
                if v is None:
                    ks = [k for k in hist[e] if k < self._nstep - age]
                    if not ks:
                        return p.a_px + p.b_px
                    k = max(ks)
                    px, py = hist[e][k]
                    n = self._nstep - age - k
                    v = ((cx - px) / n, (cy - py) / n)
                cx, cy = cx + v[0] * age, cy + v[1] * age
            out += [cx, cy]
        return tuple(out)

    def _keep_seen(self, pairs) -> None:
        """Record the emitters seen in this frame (age 0) of every decoded street light, a few
        steps deep, by its ID (`_sl_centroids`; pair keys may repeat within a frame; an ID seen
        twice in one frame is not kept)."""
        old = self._nstep - 8
        live, twice = {}, set()
        for p in pairs:
            if self._role(p) != "SL":
                continue
            if p.led_id in live:
                twice.add(p.led_id)
                continue            # dropped below
            h = self._seen_hist.get(p.led_id)
            if h is None:
                h = ({}, {})
            else:
                # Steps are added in increasing order (`_nstep`): the aged-out keys are the first
                # ones (as a rule one a frame), dropped in place (only this history holds them).
                for d in h:
                    while d:
                        k0 = next(iter(d))
                        if k0 > old:
                            break
                        del d[k0]
            for e, sn in enumerate((p.a_seen, p.b_seen)):
                if sn is not None and int(sn[2]) == 0:
                    h[e][self._nstep] = (float(sn[0][0]), float(sn[0][1]))
            live[p.led_id] = h
        for i in twice:
            del live[i]
        self._seen_hist = live

    def _pair_geometry(self, R, Lv, cst, roles, yaw, rays_m, bearing, pose_known: bool):
        """Per pair (lists of Python floats): the baseline B_cam (3,) and emitter normal n_cam
        (3,) in the camera frame, the emitter side vectors S1, S2 (3,) (`_area_range`) and the
        baseline model error (relative). SL: B and normal turned into the camera frame
        (orientation R); taillights: horizontal baseline across the FV's heading, facing back
        along it (module doc): the heading is the camera's turned by the track's yaw estimate
        (`_fv_yaw`; 0 until known). Scalar per pair; the rotations, cos/sin/tan stay numpy
        calls (their rounding is numpy's, as in the vectorised form this replaced)."""
        s = self.s
        sl_rows = [k for k, r in enumerate(roles) if r == "SL"]
        if sl_rows:
            Bsl, nsl = (cst[:, 0:3] @ R.T).tolist(), (cst[:, 3:6] @ R.T).tolist()
        fv_rows = len(sl_rows) < len(roles)
        if fv_rows:
            cy, sy_ = np.cos(yaw).tolist(), np.sin(yaw).tolist()
            tan_b = np.abs(np.tan(bearing)).tolist()
        C = cst.tolist()
        (l0x, l0y, l0z), (l1x, l1y, l1z), (l2x, l2y, l2z) = Lv.tolist()
        sy = math.radians(TAILLIGHT_YAW_SIGMA_DEG)
        Bs, ns, S1s, S2s, bms = [], [], [], [], []
        for k, role in enumerate(roles):
            c = C[k]
            L, w, h = c[12], c[7], c[8]
            if role == "SL":
                B, nrm = Bsl[k], nsl[k]
                known_b = c[10] > 0 and pose_known
                if not known_b:
                    # SL of unknown baseline azimuth: horizontal, perpendicular to the line of sight.
                    rx, ry, rz = rays_m[k].tolist()
                    px, py, pz = l2y * rz - l2z * ry, l2z * rx - l2x * rz, l2x * ry - l2y * rx
                    m = max(math.sqrt(px * px + py * py + pz * pz), 1e-12)
                    B = [L * (px / m), L * (py / m), L * (pz / m)]
                bm = BASELINE_MODEL_REL if known_b else 0.05
            else:
                ck, sk = cy[k], sy_[k]
                B = [L * (ck * l1x - sk * l0x), L * (ck * l1y - sk * l0y), L * (ck * l1z - sk * l0z)]
                nrm = [-(ck * l0x + sk * l1x), -(ck * l0y + sk * l1y), -(ck * l0z + sk * l1z)]
                bm = tan_b[k] * sy + 0.5 * sy * sy + BASELINE_MODEL_REL
            bx, by, bz = B
            nb = math.sqrt(bx * bx + by * by + bz * bz)
            ax, ay, az = _div(bx, nb), _div(by, nb), _div(bz, nb)
            if role == "SL":
                nx, ny, nz = nrm
                S2 = [(ny * az - nz * ay) * h, (nz * ax - nx * az) * h, (nx * ay - ny * ax) * h]
            else:
                S2 = [l2x * h, l2y * h, l2z * h]
            Bs.append(B)
            ns.append(nrm)
            S1s.append([ax * w, ay * w, az * w])
            S2s.append(S2)
            bms.append(bm)
        return Bs, ns, S1s, S2s, bms

    # -------------------------------------------------------------------------- HV pose
    def _init_pose(self, P_cam: np.ndarray, L: np.ndarray):
        """2-D registration (yaw, x, y) of camera-frame points P_cam (M, 3) onto map points L
        (M, 3) with the nominal tilt; returns (R0, C0) or None."""
        R_t = self.R_nominal
        Q = P_cam @ R_t                             # = R_t^T P: world axes rotated by the yaw
        q, l = Q[:, :2], L[:, :2]
        qc, lc = q - q.mean(0), l - l.mean(0)
        sxx = float(np.sum(qc * lc))
        sxy = float(np.sum(qc[:, 0] * lc[:, 1] - qc[:, 1] * lc[:, 0]))
        if abs(sxx) + abs(sxy) < 1e-9:
            return None
        yaw = math.atan2(sxy, sxx)
        Rz = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
        C = l.mean(0) - Rz @ q.mean(0)
        return ypr_to_rotation(math.degrees(yaw), self.s.camera_pitch_deg, 0.0), \
            np.array([C[0], C[1], self.s.camera_height_m])

    def _solve_pose(self, pairs, res, sl_k, R0, C0, max_iter=None, attitude=None, emitter_ranges=True):
        """Robust joint solve over the SL emitters (module doc). Returns (R, C, cov3) or None.
        `attitude`: {"yaw"|"pitch"|"roll": (rad, sigma rad)} priors, residuals of their own
        (`_with_attitude_prior`; the single-light solve, whose yaw the image leaves free)."""
        if _k is not None:
            return self._solve_pose_native(pairs, res, sl_k, R0, C0, max_iter, attitude, emitter_ranges)
        Ls, uvs, ds, sds = [], [], [], []
        flip = res["flip"]
        for k in sl_k:
            c = self._sl[pairs[res["idx"][k]].led_id]
            em = c["em"]
            ea, eb = (em[1], em[0]) if flip[k] else (em[0], em[1])
            Ls += [ea, eb]
            uvs += [res["ua"][k], res["ub"][k]]
            ds += [res["d_a"][k], res["d_b"][k]]
            sds += [res["s_a"][k], res["s_b"][k]]
        L = np.array(Ls)
        uv = np.array(uvs)
        d = np.array(ds)
        sd = np.array(sds)
        bad = ~(np.isfinite(d) & np.isfinite(sd) & (sd > 0)) | (not emitter_ranges)
        d[bad] = np.nan
        sd[bad] = 1.0
        sigma_uv = self.s.centroid_sigma_px / self.focal
        hs = CAMERA_HEIGHT_SIGMA_M
        C_prior = np.array([C0[0], C0[1], self.s.camera_height_m])
        cov = np.diag([1e8, 1e8, hs * hs])
        up = self.R_nominal[:, 2]
        rvec, _ = cv2.Rodrigues(np.asarray(R0, float))
        p0 = np.concatenate([rvec.ravel(), C0])
        n_iter = POSE_MAX_ITER if max_iter is None else max_iter
        fun = _split_pairs(_joint_fun(L, uv, sigma_uv, d, sd, up, math.radians(TILT_SIGMA_DEG), C_prior, cov),
                           len(sl_k), self._sep_gain)
        if attitude:
            fun = _with_attitude_prior(fun, **attitude)
        rot_tol, pos_tol = POSE_ROT_TOL_RAD, POSE_POS_TOL_M

        def done(dp, q, c, c_new):
            # Converged once a step moves the camera by less than the output's resolution
            # (a warm start from the road filter's prediction: 1-3 steps).
            return (float(np.max(np.abs(dp[:3]))) <= rot_tol and float(np.max(np.abs(dp[3:]))) <= pos_tol) \
                or c - c_new <= LM_FTOL * c

        # Absurd ranges may overflow the whitened residuals: no fix then (below), no warning.
        with np.errstate(over="ignore", invalid="ignore"):
            x, _, r, J = lm_iterate(fun.fun_jac, p0, done, loss="soft_l1", f_scale=POSE_F_SCALE, max_iter=n_iter)
        return self._pose_result(x, r, J, L)

    def _solve_pose_native(self, pairs, res, sl_k, R0, C0, max_iter, attitude, emitter_ranges):
        """`_solve_pose` by the compiled solve (`_solve_native`): the same inputs, gathered as
        plain floats."""
        idx, flip, d_a, d_b, s_a, s_b = res["idx"], res["flip"], res["d_a"], res["d_b"], res["s_a"], res["s_b"]
        Lf, ds, sds = [], [], []
        fin = math.isfinite
        for k in sl_k:
            e0, e1 = self._sl[pairs[idx[k]].led_id]["em_t"]
            Lf += (e1 + e0) if flip[k] else (e0 + e1)
            for d, sd in ((d_a[k], s_a[k]), (d_b[k], s_b[k])):
                ok = emitter_ranges and fin(d) and fin(sd) and sd > 0
                ds.append(d if ok else NAN)
                sds.append(sd if ok else 1.0)
        L = np.array(Lf).reshape(-1, 3)
        m = len(sl_k)
        uv = np.empty((2 * m, 2))
        uv[0::2] = res["ua"][sl_k]
        uv[1::2] = res["ub"][sl_k]
        s = self.s
        C_prior = np.array([float(C0[0]), float(C0[1]), s.camera_height_m])
        if R0 is self._rvec_of[0]:
            rvec = self._rvec_of[1]             # warm start from the last solved R: its own vector
        else:
            rvec = cv2.Rodrigues(np.asarray(R0, float))[0].ravel()
        p0 = np.concatenate([rvec, np.asarray(C0, float)])
        n_iter = POSE_MAX_ITER if max_iter is None else max_iter
        if self._W is None:
            hs = CAMERA_HEIGHT_SIGMA_M
            self._W = _prior_whitening(np.diag([1e8, 1e8, hs * hs]))
        x, r, J, R, cov6, status = _solve_native(L, uv, s.centroid_sigma_px / self.focal, np.array(ds), np.array(sds),
                                                 self._up, math.radians(TILT_SIGMA_DEG), C_prior, self._W, m,
                                                 self._sep_gain, attitude, p0, n_iter, s)
        if status == 3:
            return self._pose_result(x, r, J, L)     # J' J not positive definite: the pinv decides
        if status:
            return None
        self._rvec_of = (R, x[:3].copy())
        return R, x[3:].copy(), cov6[3:5, 3:5]

    @staticmethod
    def _pose_result(x, r, J, L):
        """(R, C, cov3) of a solved pose x (Rodrigues vector, C) with its final residuals r and
        Jacobian J, or None (not finite, the camera above a head, an unusable covariance)."""
        if not np.all(np.isfinite(x)):
            return None
        R, _ = cv2.Rodrigues(x[:3].reshape(3, 1))
        C = x[3:].copy()
        if C[2] >= float(L[:, 2].min()):
            return None
        # Covariance from the final residuals and Jacobian (not evaluated again).
        cov = _fix_covariance(r, J)[3:5, 3:5]
        if not np.all(np.isfinite(cov)):
            return None         # residuals overflowed (absurd centroids): no fix, not an infinite sigma
        return R, C, cov

    def _road_heading(self, head: np.ndarray) -> float | None:
        """The map's road direction (rad, counter-clockwise from +x) near a street-light head,
        whatever the heads' spacing: the `ROAD_HEADS` mapped heads nearest to it, split by the
        side of their first principal axis they stand on, and the common direction of the
        sides' lines (the principal axis of the scatter pooled within each side: a staggered
        or alternating layout's zig-zag, which tilts a plain fit by atan(road width / extent),
        drops out), pointing along +x (the map frame's x runs along the road). None with
        fewer than 2 heads in the map."""
        H = self._sl_heads[:, :2]
        if len(H) < 2:
            return None
        d2 = np.sum((H - head[:2]) ** 2, axis=1)
        near = H[np.argsort(d2, kind="stable")[:ROAD_HEADS]]
        c = near - near.mean(0)
        ax = np.linalg.eigh(c.T @ c)[1][:, 1]
        for _ in range(2):
            side = c @ np.array([-ax[1], ax[0]]) > 0
            S = np.zeros((2, 2))
            for g in (near[side], near[~side]):
                if len(g) >= 2:
                    gc = g - g.mean(0)
                    S += gc.T @ gc
            if np.trace(S) <= 0:
                break           # one head a side: the plain axis stands
            ax = np.linalg.eigh(S)[1][:, 1]
        ax = ax if ax[0] >= 0 else -ax
        return math.atan2(float(ax[1]), float(ax[0]))

    def _associate(self, t_s: float, pairs, R_prior) -> dict:
        """Map-aided association {pair index: mapped street-light ID} of UNDECODED pairs, while
        the road filter is sure (predicted 2D std <= `ASSOC_MAX_STD_M`): every mapped head not
        decoded in this frame is projected from the predicted camera (the filter's x, y; the
        last solved height and orientation turned to the predicted heading) with its 2x2
        covariance in normalized image units (the position's through the projection's Jacobian,
        plus the camera's yaw and pitch sigmas and the centroids'); a pair both of whose
        emitters were measured apart (`both_visible`) is matched to the one head whose
        Mahalanobis^2 to its midpoint is within `ASSOC_GATE_CHI2`, when no other head is in
        that gate, no other pair is in the head's, and its separation is within
        `ASSOC_SEP_TOL` of the head's predicted one (f B / distance). Ambiguity: no match."""
        s = self.s
        cand = [i for i, p in enumerate(pairs) if p.led_id is None and p.both_visible
                and p.a_seen is not None and p.b_seen is not None
                and max(int(p.a_seen[2]), int(p.b_seen[2])) <= ASSOC_MAX_AGE]
        if not cand or not len(self._sl_heads):
            return {}
        st, P = self.kf.predict_at(t_s)
        Pxy = P[:2, :2]
        if float(Pxy[0, 0] + Pxy[1, 1]) > ASSOC_MAX_STD_M ** 2:
            return {}
        decoded = {p.led_id for p in pairs if p.led_id is not None}
        ids, H, Bl = self._em_heads
        if _ka is not None:
            return self._associate_native(pairs, cand, st, Pxy, decoded, R_prior)
        keep = [i not in decoded for i in ids]
        if not all(keep):
            ids, H, Bl = [i for i, k in zip(ids, keep) if k], H[keep], Bl[keep]
        if not ids:
            return {}
        dpsi = float(st[2]) - float(self.kf.s[2])          # heading change since the last update
        c, sn = math.cos(dpsi), math.sin(dpsi)
        R = R_prior @ np.array([[c, sn, 0.0], [-sn, c, 0.0], [0.0, 0.0, 1.0]])    # turned by dpsi about z
        C = np.array([float(st[0]), float(st[1]), self.z_last])
        V = H - C
        X = V @ R.T
        ok = X[:, 2] > 1.0
        if not np.any(ok):
            return {}
        X, V, Bl, ids = X[ok], V[ok], Bl[ok], [i for i, o in zip(ids, ok) if o]
        z = X[:, 2]
        u = X[:, :2] / z[:, None]
        # d(u, v) / d(Cx, Cy): X = R (H - C) -> dX/dC = -R[:, :2].
        dX = -R[:, :2]                                       # (3, 2)
        J = (dX[None, :2, :] - u[:, :, None] * dX[None, 2:3, :]) / z[:, None, None]     # (n, 2, 2)
        cov = J @ Pxy @ np.transpose(J, (0, 2, 1))
        ang = math.radians(s.yaw_shake_sigma_deg) ** 2 + math.radians(s.pitch_sigma_deg) ** 2
        csig = (s.centroid_sigma_px / self.focal) ** 2
        cov = cov + np.eye(2) * (ang + csig)
        inv = np.linalg.inv(cov)
        sep_pred = self.focal * Bl / np.sqrt(np.sum(V * V, axis=1))
        und = self._undistorted_mids(pairs, cand)
        D = und[:, None, :] - u[None, :, :]                  # (pairs, heads, 2)
        m2 = np.einsum("phi,hij,phj->ph", D, inv, D)
        inside = m2 <= ASSOC_GATE_CHI2
        out = {}
        for a, i in enumerate(cand):
            hs = np.flatnonzero(inside[a])
            if len(hs) != 1 or np.count_nonzero(inside[:, hs[0]]) != 1:
                continue
            h = hs[0]
            sep = pairs[i].separation_px
            if not (sep > 0 and abs(sep / sep_pred[h] - 1.0) <= ASSOC_SEP_TOL):
                continue
            out[i] = ids[h]
        return out

    def _undistorted_mids(self, pairs, cand) -> np.ndarray:
        """(len(cand), 2) normalized, undistorted image midpoints of the candidate pairs."""
        mids = [(0.5 * (pairs[i].a_px[0] + pairs[i].b_px[0]), 0.5 * (pairs[i].a_px[1] + pairs[i].b_px[1]))
                for i in cand]
        return cv2.undistortPoints(np.array(mids, float).reshape(-1, 1, 2), self.camera.K,
                                   self.camera.dist).reshape(-1, 2)

    def _prior_camera(self, st, R_prior):
        """The predicted camera of `_associate`: R_prior turned about z by the heading change
        since the filter's last update, at the filter's predicted x, y and the last height."""
        dpsi = float(st[2]) - float(self.kf.s[2])          # heading change since the last update
        c, sn = math.cos(dpsi), math.sin(dpsi)
        R = R_prior @ np.array([[c, sn, 0.0], [-sn, c, 0.0], [0.0, 0.0, 1.0]])    # turned by dpsi about z
        return R, (float(st[0]), float(st[1]), self.z_last)

    def _associate_native(self, pairs, cand, st, Pxy, decoded, R_prior) -> dict:
        """`_associate` after its early checks, by the compiled kernel
        (receiver.locate._vehicle_step.associate): one call for every head and candidate."""
        s = self.s
        ids, H, Bl = self._em_heads
        use = bytes([i not in decoded for i in ids])
        if not any(use):
            return {}
        R, (cx, cy, cz) = self._prior_camera(st, R_prior)
        ang = math.radians(s.yaw_shake_sigma_deg) ** 2 + math.radians(s.pitch_sigma_deg) ** 2
        csig = (s.centroid_sigma_px / self.focal) ** 2
        und = self._undistorted_mids(pairs, cand)
        sep = np.array([float(pairs[i].separation_px) for i in cand])
        hit = np.empty(len(cand), np.int_)
        if not _ka.associate(H, Bl, use, np.ascontiguousarray(R), cx, cy, cz, np.ascontiguousarray(Pxy),
                             ang + csig, float(self.focal), np.ascontiguousarray(und, float), sep,
                             float(ASSOC_GATE_CHI2), float(ASSOC_SEP_TOL), hit):
            return {}
        return {i: ids[h] for i, h in zip(cand, hit.tolist()) if h >= 0}

    def _single_observation(self, t_s, pairs, res, k, R_prior):
        """While the road filter runs, one decoded street light updates it directly: the
        measurement is the head's undistorted midpoint (u, v, normalized) and its "fused" range
        (m), predicted from the filter's (x, y, heading) with the camera at the last solved
        height and pitch (`pitch_ref` when a full pose gave one), roll 0 and yaw = heading. What
        those assumptions leave out is folded into the noise through the measurement's
        Jacobian on each: the camera's yaw about the heading (`yaw_shake_sigma_deg`), pitch
        (`pitch_sigma_deg`, else `ORIENT_SIGMA_PRIOR_DEG`), roll (`roll_sigma_deg`) and height
        (`CAMERA_HEIGHT_SIGMA_M`); the midpoint carries the centroids' sigma
        (`centroid_sigma_px` / sqrt 2 per axis). A pose fix would need the heading prior from
        this same filter, and its position fed back would count that prior twice. Returns the
        fix record for `_update_hv` ("sl-1", n 1)."""
        s = self.s
        head = self._sl[pairs[res["idx"][k]].led_id]["head"]
        z0 = self.z_last
        pitch0 = rotation_to_ypr_deg(R_prior)[1] if self.pitch_ref is None else math.degrees(self.pitch_ref)
        psig = math.radians(s.pitch_sigma_deg if self.pitch_ref is not None else ORIENT_SIGMA_PRIOR_DEG)

        rots = {}       # the rotations asked so far: 7 distinct ones among the ~16 calls of a frame

        def g(x, y, psi, dyaw=0.0, dpitch=0.0, roll=0.0, dz=0.0):
            ypr = (math.degrees(psi + dyaw), pitch0 + math.degrees(dpitch), math.degrees(roll))
            R = rots.get(ypr)
            if R is None:
                R = rots[ypr] = ypr_to_rotation(*ypr)
            V = head - np.array([x, y, z0 + dz])
            X = R @ V
            if X[2] < 1e-3:
                return np.array([np.nan, np.nan, np.nan])
            return np.array([X[0] / X[2], X[1] / X[2], math.sqrt(float(V @ V))])

        st, P = self.kf.predict_at(t_s)
        if float(P[0, 0] + P[1, 1]) > SL1_MAX_STD_M ** 2:
            # One light's angles and range, linearised about a prediction metres off, pull the
            # filter along a wrong circle around the head (vehicle-road, tilted heads: 10 m off at
            # 1 m std): a single light only keeps a filter that is already sure.
            self.hv_reason = ONE_LIGHT
            return None
        x, y, psi = float(st[0]), float(st[1]), float(st[2])
        um = 0.5 * (np.asarray(res["ua"][k]) + np.asarray(res["ub"][k]))
        z = np.array([um[0], um[1], res["fused"][k]])
        sm = s.centroid_sigma_px / SQRT2 / self.focal
        d = float(res["fused"][k])
        Rm = np.diag([sm * sm, sm * sm, res["fused_sigma"][k] ** 2 + (SL1_RANGE_FLOOR_REL * d) ** 2])
        for j, (sig, e) in enumerate(((math.radians(s.yaw_shake_sigma_deg), 1e-5), (psig, 1e-5),
                                      (math.radians(s.roll_sigma_deg), 1e-5), (CAMERA_HEIGHT_SIGMA_M, 1e-3))):
            a = [0.0, 0.0, 0.0, 0.0]
            a[j] = e
            jp = g(x, y, psi, *a)
            a[j] = -e
            jn = g(x, y, psi, *a)
            col = (jp - jn) / (2 * e)
            Rm += np.outer(col, col) * sig * sig
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(Rm))):
            self.hv_reason = "street-light pose solve failed"
            return None
        self.hv_reason = None
        return dict(obs=(z, g, Rm), n=1, method="sl-1")

    def _single_fix(self, t_s, pairs, aligned, res, k, R_prior):
        """One decoded street light's two emitters (4 image coordinates, their ranges) with the
        camera-height and tilt priors of `_solve_pose` and a heading prior: while the road
        filter runs, its predicted heading (sigma: its own and the camera's yaw shake,
        `yaw_shake_sigma_deg`), else the map's road direction near the light
        (`road_heading_sigma_deg`). Returns (fix | None, aligned, res); the fix's covariance is
        the solve's (lateral ~ range x heading sigma). Its yaw is the prior's echo, so the
        filter takes the position only (`fix["yaw_free"]`)."""
        s = self.s
        head = self._sl[pairs[res["idx"][k]].led_id]["head"]
        if R_prior is not None:
            pred, P = self.kf.predict_at(t_s)
            yaw0 = float(pred[2])
            ysig = math.sqrt(max(float(P[2, 2]), 0.0) + math.radians(s.yaw_shake_sigma_deg) ** 2)
            pitch = rotation_to_ypr_deg(R_prior)[1] if self.pitch_ref is None else math.degrees(self.pitch_ref)
            R0 = ypr_to_rotation(math.degrees(yaw0), pitch, 0.0)
            C0 = np.array([pred[0], pred[1], self.z_last])
        else:
            yaw0 = self._road_heading(head)
            if yaw0 is None:
                self.hv_reason = f"{ONE_LIGHT} (the map gives no road direction near it)"
                return None, aligned, res
            ysig = math.radians(s.road_heading_sigma_deg)
            pitch = self.s.camera_pitch_deg if self.pitch_ref is None else math.degrees(self.pitch_ref)
            R0 = ypr_to_rotation(math.degrees(yaw0), pitch, 0.0)
            ray = _rays(0.5 * (res["ua"][k:k + 1] + res["ub"][k:k + 1]))[0]
            C0 = head - R0.T @ (res["fused"][k] * ray)
            C0[2] = s.camera_height_m
        # Ranges with this orientation (the baseline's direction, the panels' normals).
        aligned, res = self._range_pairs(pairs, R0, True)      # same pairs ranged: k stands
        if not math.isfinite(res["fused"][k]):
            self.hv_reason = "street-light pose solve failed"
            return None, aligned, res
        att = {"yaw": (yaw0, ysig), "roll": (0.0, math.radians(s.roll_sigma_deg)),
               "mid_range": (head, float(res["fused"][k]), float(res["fused_sigma"][k]))}
        if self.pitch_ref is not None:
            att["pitch"] = (self.pitch_ref, math.radians(s.pitch_sigma_deg))
        solved = self._solve_pose(pairs, res, [k], R0, C0, attitude=att, emitter_ranges=False)
        if solved is None:
            self.hv_reason = "street-light pose solve failed"
            return None, aligned, res
        R, C, cov = solved
        if float(np.trace(cov)) > SL1_START_MAX_STD_M ** 2:
            # Too unsure to start the filter on (a far head, lateral ~ range x heading sigma):
            # the single-light observations that follow would be linearised metres off.
            self.hv_reason = f"{ONE_LIGHT} (alone too unsure: std > {SL1_START_MAX_STD_M:g} m)"
            return None, aligned, res
        self.hv_reason = None
        return dict(pose=(C, cov, camera_yaw(R), R), n=1, method="pose-1sl", yaw_free=True,
                    heads=[(pairs[res["idx"][k]].key, head)]), aligned, res

    @property
    def _sep_gain(self) -> float:
        """Weight of a head's centroid difference relative to the centroids' own sigma:
        sqrt(2) sigma_c / sqrt(2 sigma_c^2 + sigma_sep^2) (`SL_SEPARATION_SIGMA_PX`)."""
        c = self.s.centroid_sigma_px
        return SQRT2 * c / math.sqrt(2 * c * c + SL_SEPARATION_SIGMA_PX ** 2)

    # -------------------------------------------------------------------------- step
    def step(self, t_s: float, pairs: list[PairObservation], speed_mps: float | None = None) -> VehicleResult:
        s = self.s
        pairs = list(pairs)
        self._nstep += 1
        if speed_mps is not None and not math.isfinite(speed_mps):
            speed_mps = None
        tracked = self.kf.started and not self.kf.expired(t_s)
        if self.kf.started and not tracked:
            self.kf.reset()
            self.R_last = None
        R_prior = self.R_last if tracked else None
        given = pairs
        assoc = self._associate(t_s, pairs, R_prior) if R_prior is not None else {}
        if assoc:
            pairs = [dataclasses.replace(p, led_id=assoc[i], kind="SL") if i in assoc else p
                     for i, p in enumerate(pairs)]
        out = self._range_pairs(pairs, R_prior, R_prior is not None)
        fix = None
        self.last_fix = None
        sl_k = []
        if out is not None:
            aligned, res = out
            fused_ok = np.isfinite(res["fused"])
            sl_k = [k for k, r in enumerate(res["roles"]) if r == "SL" and fused_ok[k]
                    and self._sl[pairs[res["idx"][k]].led_id]["em"] is not None]
            n_sl_any = res["roles"].count("SL")
            if n_sl_any and not sl_k:
                self.hv_reason = "the map gives no emitter positions for the street lights in view"
            elif not sl_k:
                self.hv_reason = self._unplaced_reason(pairs)
            elif len(sl_k) < MIN_LIGHTS and R_prior is not None:
                fix = self._single_observation(t_s, pairs, res, sl_k[0], R_prior)
            elif len(sl_k) < MIN_LIGHTS:
                fix, aligned, res = self._single_fix(t_s, pairs, aligned, res, sl_k[0], R_prior)
            else:
                if R_prior is not None:
                    pred = self.kf.predict_at(t_s)[0]
                    # The camera's height as last solved (it may sit off the prior by decimetres).
                    R0, C0 = R_prior, np.array([pred[0], pred[1], self.z_last])
                    init = (R0, C0)
                else:
                    P_cam = np.array([res["fused"][k] * _rays(0.5 * (res["ua"][k:k + 1] + res["ub"][k:k + 1]))[0]
                                      for k in sl_k])
                    Lm = np.array([self._sl[pairs[res["idx"][k]].led_id]["head"] for k in sl_k])
                    init = self._init_pose(P_cam, Lm)
                    if init is not None:
                        # Re-range with the initial orientation (baseline direction, normals).
                        out = self._range_pairs(pairs, init[0], True)
                        aligned, res = out
                # Warm start from the filter's prediction while tracking: a few iterations do.
                solved = None if init is None else self._solve_pose(
                    pairs, res, sl_k, *init, max_iter=POSE_TRACK_ITER if R_prior is not None else None)
                if solved is None:
                    self.hv_reason = "street-light pose solve failed"
                else:
                    R, C, cov = solved
                    if R_prior is None:
                        # Final ranges with the solved pose. While tracking, the ranges taken with
                        # the previous frame's orientation stand (one frame of rotation: negligible).
                        aligned, res = self._range_pairs(pairs, R, True)
                    yaw = math.radians(self._ypr_of(R)[0])
                    fix = dict(pose=(C, cov, yaw, R), n=len(sl_k),
                               heads=[(pairs[res["idx"][k]].key, self._sl[pairs[res["idx"][k]].led_id]["head"])
                                      for k in sl_k])
                    self.hv_reason = None
            if fix is not None or len(sl_k) >= 2:
                e = self._eq44_47(pairs, res, sl_k, fix)
                if fix is not None:
                    fix["eq44-47"] = e
                self.last_fix = {"pose": None if fix is None or "pose" not in fix else tuple(fix["pose"][0][:2]),
                                 "eq44-47": e}
        else:
            aligned, res = [(None, None)] * len(pairs), None
            if not self.kf.started:
                self.hv_reason = self._unplaced_reason(pairs)

        self._keep_seen(pairs)
        self._keep_separations(t_s, given)
        if fix is not None:
            fix["n_assoc"] = sum(1 for k in sl_k if res["idx"][k] in assoc)
        hv = self._update_hv(t_s, fix, speed_mps)
        if assoc:
            # The undecoded pairs matched to mapped heads served the host only: to the rest of
            # the step (forward vehicles, LED ranges) they are what they were, and no car.
            pairs = given
            aligned = [(None, None) if i in assoc else a for i, a in enumerate(aligned)]
        fv, not_fv, tracked = self._update_fv(t_s, pairs, aligned, res, hv)
        not_fv = set(not_fv) | set(assoc)
        ranges = [None if r is None or i in not_fv else _pick(r, k, "fused")
                  for i, (r, k) in enumerate(aligned)]
        for i, rng in tracked.items():
            if ranges[i] is None:
                ranges[i] = rng
        if fix is not None and "pose" in fix:
            self._pose_ranges(pairs, ranges, fix)
        ranges = tuple(ranges)
        any_pair = any(p.kind in ("SL", "FV") or self._role(p) is not None for p in pairs)
        if self._tl is None and self.fv_reason is None and any(p.kind != "SL" for p in pairs):
            # A pair that is no decoded street light may be a car's taillights: say why it is not.
            self.fv_reason = "the map has no taillight block with shape, size and baseline_m"
        vehicle = None
        if any_pair or hv is not None:
            e = None if self.last_fix is None else self.last_fix.get("eq44-47")
            # Thesis eqs. 44-47 beside the main fix (receiver.evaluate reads any hv_<name> object);
            # why the HV is unplaced as `unplaced_reason` (an hv_ name would be read as a fix).
            vehicle = {"hv": hv, "fv": fv,
                       "hv_eq44_47": None if e is None else {"x": _r(e[0]), "y": _r(e[1]), "method": "eq44-47"},
                       "unplaced_reason": None if hv is not None else self.hv_reason}
        if hv is None and self.hv_reason:
            self.unplaced[self.hv_reason] = self.unplaced.get(self.hv_reason, 0) + 1
        return VehicleResult(vehicle=vehicle, ranges=ranges)

    def _unplaced_reason(self, pairs) -> str:
        """Why no street light places the host in a frame whose pairs give no usable one:
        nothing in view, pairs none of which is decoded as a mapped street light, or a decoded
        one not yet seen with both emitters apart."""
        if not pairs:
            return NO_LIGHT
        if not any(self._role(p) == "SL" for p in pairs):
            return NOT_DECODED
        return "no decoded street light seen with both emitters apart"

    def run_reason(self) -> str | None:
        """Why the HV was left unplaced over the run so far: the reason of most unplaced frames
        (the last frame's alone may be the road's end), or the current one before any frame."""
        if not self.unplaced:
            return self.hv_reason
        return max(self.unplaced.items(), key=lambda kv: kv[1])[0]

    def _pose_ranges(self, pairs, ranges, fix):
        """SL pairs with mapped emitters: the distance from the frame's solved camera centre to
        the head (estimator "pose"; its sigma from the pose covariance along the line of
        sight). Far more exact than either image measurement of a small, foreshortened head."""
        (cx, cy, cz), ((c00, c01), (c10, c11)) = fix["pose"][0].tolist(), fix["pose"][1].tolist()
        hs = CAMERA_HEIGHT_SIGMA_M
        if _kr is not None:
            _kr.pose_ranges(pairs, self._heads_t, cx, cy, cz, c00, c01, c10, c11, hs, ranges)
            return
        for i, p in enumerate(pairs):
            c = self._sl.get(p.led_id) if p.kind == "SL" or (p.led_id is not None and p.led_id <= 0x7F) else None
            if c is None or c["em"] is None:
                continue
            hx, hy, hz = c["head_t"]
            vx, vy, vz = hx - cx, hy - cy, hz - cz
            d = math.sqrt(vx * vx + vy * vy + vz * vz)
            ux, uy = vx / d, vy / d
            q = ux * (ux * c00 + uy * c10) + uy * (ux * c01 + uy * c11)
            sd = math.sqrt(max(q, 0.0) + (hs * vz / d) ** 2 * 0.01)
            ranges[i] = (d, sd, "pose")

    def _eq44_47(self, pairs, res, sl_k, fix):
        """Thesis eqs. 44-47 from the two nearest ranged street lights (x, y) or None."""
        if len(sl_k) < 2:
            return None
        # The image's own ranges (the baseline: geometry only), not the pose's (circular).
        base, fused = res["baseline"], res["fused"]
        rng = {k: base[k] if math.isfinite(base[k]) else fused[k] for k in sl_k}
        ks = sorted(sl_k, key=lambda k: rng[k])[:2]
        k1, k2 = ks
        c1 = self._sl[pairs[res["idx"][k1]].led_id]
        c2 = self._sl[pairs[res["idx"][k2]].led_id]
        sl1 = c1["head"]
        sl2 = c2["head"]
        # Which is further left, in the level frame (positive bearing = left).
        left = bool(res["bearing"][k2] > res["bearing"][k1])
        p = eq44_47(float(rng[k1]), float(rng[k2]), sl1, sl2, self.s.camera_height_m, left)
        return None if p is None else (float(p[0]), float(p[1]))

    def _update_hv(self, t_s: float, fix, speed):
        s = self.s
        kf = self.kf
        raw, xy, meth = None, None, "kalman-coast"
        if fix is not None and "obs" in fix:
            # One light's image angles and range straight into the running filter (no raw fix).
            kf.predict(t_s)
            z, g, Rm = fix["obs"]
            if kf.update_observation(t_s, z, g, Rm, OBS_GATE_CHI2):
                meth = fix["method"] + ("+map" if fix.get("n_assoc") else "")
            fix = None if meth == "kalman-coast" else fix
        elif fix is not None:
            C, cov, yaw, R = fix["pose"]
            xy, meth = C[:2], fix.get("method", "pose") + ("+map" if fix.get("n_assoc") else "")
            cov = cov + np.eye(2) * FIX_FLOOR_M ** 2
        if xy is not None:
            raw = {"x": _r(xy[0]), "y": _r(xy[1]), "method": meth}
            psig = math.radians(HEADING_SIGMA_DEG)
            if fix.get("yaw_free"):
                # A single light's yaw is its heading prior's echo: the filter takes the position
                # only; a filter started from it takes the prior's sigma.
                psig = math.radians(s.road_heading_sigma_deg)
            if not kf.started:
                accepted = self._start(t_s, xy, cov, yaw, psig, speed, fix)
            else:
                kf.predict(t_s)
                held = self._speed_from_fixes(t_s, xy, cov) if speed is None else False
                accepted = kf.update_fix(t_s, xy, cov, None if fix.get("yaw_free") else yaw, psig,
                                         held_speed=held)
                if not accepted and kf.rejects >= MAX_REJECTS:
                    kf.reset()
                    accepted = self._start(t_s, xy, cov, yaw, psig, speed, fix)
            if accepted:
                self.R_last = R
                self.z_last = float(fix["pose"][0][2])
                _, pitch, roll = self._ypr_of(R)
                self._tilt, self._R_tilt = (pitch, roll), None
                if fix["n"] >= 2:
                    self.pitch_ref = math.radians(pitch)
            else:
                meth = "kalman-coast"
        elif kf.started and meth == "kalman-coast":
            if kf.expired(t_s):
                kf.reset()
                self.R_last = None
                self.hv_reason = self.hv_reason or "HV track lost"
            else:
                kf.predict(t_s)
        if not kf.started:
            return None
        if speed is not None:
            kf.update_speed(speed, s.speed_sigma_mps)
        st, P = kf.s, kf.P
        std = math.sqrt(max(P[0, 0] + P[1, 1], 0.0))
        hv = {"x": _r(st[0]), "y": _r(st[1]), "std_m": _r(std), "heading_deg": _r(math.degrees(st[2]), 3),
              "speed_mps": _r(st[3], 3), "method": meth, "n_lights": 0 if fix is None else fix["n"],
              "n_assoc": 0 if fix is None else fix.get("n_assoc", 0), "raw": raw}
        if hv["x"] is None or hv["y"] is None or hv["std_m"] is None:
            kf.reset()
            self.R_last = None
            self.hv_reason = "HV filter diverged"
            return None
        if std > s.hv_max_std_m:
            # The filter runs on (a single light's fix, coasting), but a position this unsure is
            # no placement: never a confident wrong one.
            self.hv_reason = f"host position std above {s.hv_max_std_m:g} m"
            return None
        return hv

    def _start(self, t_s: float, xy, cov, yaw: float, psig: float, speed, fix=None) -> bool:
        """Start the road filter on a fix: the speed from odometry, else from the fix's heads'
        image motion (`_speed_from_motion`), else unknown (0 +- 15 m/s, the fix held as
        `_pending` for `_speed_from_fixes`). Returns True."""
        s = self.s
        sv = s.speed_sigma_mps
        if speed is None and fix is not None and fix.get("heads"):
            got = self._speed_from_motion(t_s, fix["pose"][0], yaw, fix["heads"])
            if got is not None:
                speed, sv = got
        self.kf.start(t_s, xy, cov, yaw, psig, speed, sv)
        self._pending = None if speed is not None else (t_s, np.array(xy, float), cov, yaw)
        return True

    def _keep_separations(self, t_s: float, pairs) -> None:
        """Each pair's separation (px, when both emitters were measured apart) over the last
        `SPEED_HIST_S`, by pair key (`_speed_from_motion`; kept from before the pair decodes)."""
        keep = t_s - SPEED_HIST_S
        hist = {}
        old = self._sep_hist
        # Times added in step order: while they never went back, every list is sorted and its
        # aged-out entries are a prefix (the first ones, as a rule one a frame).
        self._sep_sorted = self._sep_sorted and t_s >= self._sep_t
        self._sep_t = t_s
        for p in pairs:
            h = old.get(p.key, ())
            if h and h[0][0] < keep:
                if self._sep_sorted:
                    j, n = 1, len(h)
                    while j < n and h[j][0] < keep:
                        j += 1
                    h = h[j:]
                else:
                    h = [e for e in h if e[0] >= keep]
            else:
                h = list(h)        # a key may repeat within a frame: each from the last frame's list
            if p.both_visible and p.separation_px > 0 and math.isfinite(p.separation_px):
                h.append((t_s, float(p.separation_px)))
            if h:
                hist[p.key] = h
        self._sep_hist = hist

    def _speed_from_motion(self, t_s: float, C, yaw: float, heads):
        """(speed m/s, sigma) of the HV from the image growth of the fix's heads, or None. A head's
        separation scales as 1 / distance: the slope k of ln(separation) over the last
        `SPEED_HIST_S` (>= `SPEED_HIST_MIN` samples) is -d'/d, and d d' = rho rho' with
        rho' = -v cos(beta) (rho the horizontal distance, beta the head's bearing from the
        heading, from the fix), so v = d^2 k / (rho cos beta); sigma from the fit's residuals.
        Heads are combined by inverse variance; none when they disagree beyond 3 sigma. The
        sigma is floored at `SPEED_MOTION_FLOOR_MPS` (the separations are the pairing's model:
        whole pixels scaled by the envelopes)."""
        s = self.s
        h = np.array([math.cos(yaw), math.sin(yaw)])
        vs, ws = [], []
        for key, head in heads:
            e = self._sep_hist.get(key, ())
            if len(e) < SPEED_HIST_MIN:
                continue
            t = np.array([x[0] for x in e])
            y = np.log([x[1] for x in e])
            tc = t - t.mean()
            stt = float(tc @ tc)
            if stt <= 0:
                continue
            k = float(tc @ (y - y.mean())) / stt
            r = y - y.mean() - k * tc
            sk = math.sqrt(max(float(r @ r) / max(len(e) - 2, 1), (0.3 / 20.0) ** 2) / stt)
            V = np.asarray(head, float) - np.asarray(C, float)
            d = math.sqrt(float(V @ V))
            rho = math.hypot(float(V[0]), float(V[1]))
            cb = float(h @ V[:2]) / max(rho, 1e-9)
            if cb < 0.3:
                continue
            g = d * d / (rho * cb)
            vs.append(g * k)
            ws.append(1.0 / (g * sk) ** 2)
        if not vs:
            return None
        vs, ws = np.array(vs), np.array(ws)
        v = float(ws @ vs / ws.sum())
        sv = 1.0 / math.sqrt(float(ws.sum()))
        if np.any(np.abs(vs - v) > 3.0 * np.sqrt(1.0 / ws + sv * sv)) or not math.isfinite(v):
            return None
        return v, max(sv, SPEED_MOTION_FLOOR_MPS)

    def _speed_from_fixes(self, t_s: float, xy, cov) -> bool:
        """While the speed is unknown (a start without odometry), the speed from the first fix and
        the first one at least `SPEED_INIT_MIN_DT_S` after it: their displacement along the
        heading over their time apart (sigma sqrt(h' (C1 + C2) h) / dt, h the heading's unit
        vector), set as the filter's speed with its cross-covariances cleared. Fixes before
        that update the position only (`held_speed`). A filter left to learn its speed from its
        cross-covariances took it from the next fix a frame later: two fixes 0.7 m apart the
        wrong way read -23 m/s (bundled vehicle recording). Returns whether the speed is still
        held (unknown)."""
        held = self._pending
        if held is None:
            return False
        t0, xy0, cov0, yaw0 = held
        dt = t_s - t0
        if dt < SPEED_INIT_MIN_DT_S:
            return True
        self._pending = None
        h = np.array([math.cos(yaw0), math.sin(yaw0)])
        v = float(h @ (np.asarray(xy, float) - xy0)) / dt
        sv = math.sqrt(max(float(h @ (cov0 + cov) @ h), 0.0)) / dt
        if math.isfinite(v) and math.isfinite(sv):
            self.kf.set_speed(v, max(sv, self.s.speed_sigma_mps))
        return False

    def _fv_directions(self, pairs, aligned) -> dict:
        """{pair index: (bearing rad, level-frame unit ray (3,))} of the tracked taillight pairs
        not ranged this frame: their midpoint from the emitter measured in this frame and the
        track's last measured separation (px, scaled by the distance ratio: the image scales as
        1 / distance), else the pair's predicted midpoint. The bearing follows the camera's
        shake every frame; the separation of one emitter and a partner seen frames ago does not
        range, but places the midpoint to a fraction of a pixel."""
        mids, where = [], []
        for i, p in enumerate(pairs):
            if aligned[i][0] is not None:
                continue
            tr = self.fv_tracks.get(p.key)
            if tr is None or self._role(p) not in ("FV", "FV?"):
                continue
            sep = tr.get("sep_px")
            a, b = p.a_seen, p.b_seen
            if tr["kf"].d <= 0:             # a coasting track's distance passed zero: no model
                sep = None
            k = 0.0 if sep is None else 0.5 * tr["sep_d"] / tr["kf"].d
            if sep is not None and a is not None and a[2] == 0:
                mids.append((a[0][0] + k * sep[0], a[0][1] + k * sep[1]))
            elif sep is not None and b is not None and b[2] == 0:
                mids.append((b[0][0] - k * sep[0], b[0][1] - k * sep[1]))
            else:
                mids.append((0.5 * (p.a_px[0] + p.b_px[0]), 0.5 * (p.a_px[1] + p.b_px[1])))
            where.append(i)
        if not where:
            return {}
        und = cv2.undistortPoints(np.array(mids, float).reshape(-1, 1, 2), self.camera.K, self.camera.dist)
        lev = _rays(und.reshape(-1, 2)) @ self.Lv.T
        bearing = np.arctan2(lev[:, 1], lev[:, 0])
        return {i: (float(bearing[j]), lev[j]) for j, i in enumerate(where)}

    def _update_fv(self, t_s, pairs, aligned, res, hv):
        s = self.s
        out = []
        dirs = self._fv_directions(pairs, aligned)
        seen = set()
        not_fv = set()          # undecoded pairs found not to be taillights (no range reported)
        tracked = {}            # pair index -> (d, sigma, "fv-track") of unranged tracked pairs
        v_hv = None if hv is None else hv["speed_mps"]
        R = self.R_last
        cpsi = spsi = None
        # Emitter tracks of the live pairs already tracked as FVs: one lamp is one car's.
        # (by founding track ids: an aliased pair's key holds LED ids)
        owner = {t: p.key for p in pairs if p.key in self.fv_tracks for t in (p.founding or p.key)}
        for i, p in enumerate(pairs):
            role = self._role(p)
            if role not in ("FV", "FV?"):
                continue
            key = p.key
            tr = self.fv_tracks.get(key)
            r, k = aligned[i]
            meas = None
            if r is not None:
                d, sd = r["fused"][k], r["fused_sigma"][k]
                lo, hi = SATURATED_AREA_SPAN
                if role == "FV?" and tr is None and (r["area_clash"][k] or not lo * d <= r["area_bound"][k] <= hi * d
                                                     if math.isfinite(r["area_bound"][k]) else r["area_clash"][k]):
                    # Area and baseline ranges of a new undecoded pair disagree (saturated: the
                    # bloomed areas' range is not within the span bloom allows): no taillight
                    # pair (a street light's halves are far larger for their spacing: 3-4x).
                    # A decoded or tracked pair keeps its baseline range (`range_core` dropped
                    # the area one): an unflagged saturated lamp reads its area range short.
                    not_fv.add(i)
                    continue
                if np.isfinite(d) and np.isfinite(sd) and sd > 0:
                    lev = r["lev"][k]
                    if role == "FV?" and tr is None and any(owner.get(t, p.key) != p.key for t in (p.founding or p.key)):
                        # A new pairing of a lamp an FV track already owns with another lamp: at
                        # 50+ m one taillight of each of two cars side by side pass the area
                        # test (tiny blobs read large), so the lamp stays with its car.
                        not_fv.add(i)
                        continue
                    if role == "FV?" and tr is None and self._would_hide_lamps(p, pairs):
                        not_fv.add(i)
                        continue
                    if role == "FV?" and not self._taillight_like(p, r, k):
                        not_fv.add(i)
                        self.fv_tracks.pop(key, None)
                        continue
                    if role == "FV?" and self._on_mapped_sl(t_s, r["ua"][k], r["ub"][k], hv, R):
                        # Two far street-light heads (undecoded yet) line up as a taillight pair:
                        # areas and spacing agree by chance (vfar scene: 200 m heads read as a car
                        # at 30 m). The placed HV projects the map's heads; one on an emitter
                        # settles it.
                        not_fv.add(i)
                        self.fv_tracks.pop(key, None)
                        continue
                    if role == "FV?" and tr is None and d > UNDECODED_FV_MAX_RANGE_M:
                        not_fv.add(i)
                        continue
                    if role == "FV?" and self._tilt is not None:
                        # Height window only once the camera's tilt is known (the nominal tilt
                        # may be off by degrees: metres of height at 30 m).
                        z = s.camera_height_m + d * lev[2]
                        if not s.fv_min_height_m <= z <= s.fv_max_height_m:
                            not_fv.add(i)
                            continue
                    m = fv_measured(p)[0]
                    meas = (float(d), float(sd), float(r["bearing"][k]), lev, (m[2] - m[0], m[3] - m[1]))
            if meas is None and tr is None:
                continue
            if tr is None:
                tr = {"kf": RangeKalman(t_s, meas[0], meas[1], FV_RATE_SIGMA_MPS, FV_ACCEL_PSD, FV_GATE_CHI2),
                      "id": None, "bearing": meas[2], "lev": meas[3], "ykf": None, "yaw": 0.0, "n_meas": 1}
                self.fv_tracks[key] = tr
            else:
                tr["kf"].predict(t_s)
                if meas is not None and not tr["kf"].update(t_s, meas[0], meas[1]):
                    if tr["kf"].rejects >= FV_MAX_REJECTS:
                        tr["kf"] = RangeKalman(t_s, meas[0], meas[1], FV_RATE_SIGMA_MPS, FV_ACCEL_PSD,
                                               FV_GATE_CHI2)
                        tr["n_meas"] = 1
                    else:
                        meas = None
                elif meas is not None:
                    tr["n_meas"] = tr.get("n_meas", 1) + 1
            if meas is None and tr["id"] is None and not (p.led_id is not None and p.led_id > 0x7F) \
                    and tr.get("n_meas", 1) < 2 and t_s - tr["kf"].t_meas > FV_CONFIRM_S:
                # Ranged once, never again: no car's taillights (FV_CONFIRM_S); forget it.
                del self.fv_tracks[key]
                continue
            if meas is not None:
                tr["bearing"], tr["lev"] = meas[2], meas[3]
                tr["sep_px"], tr["sep_d"] = meas[4], meas[0]
            elif i in dirs:
                tr["bearing"], tr["lev"] = dirs[i]
            if p.led_id is not None and p.led_id > 0x7F:
                tr["id"] = int(p.led_id)
            seen.add(key)
            kf = tr["kf"]
            d, rate = kf.d, kf.v
            std = math.sqrt(max(kf.p00, 0.0))
            lev = tr["lev"]
            hnorm = math.hypot(lev[0], lev[1])
            flat = d * hnorm                     # horizontal distance
            x = flat * math.cos(tr["bearing"])
            y = flat * math.sin(tr["bearing"])
            if meas is not None or i in dirs:
                self._fv_yaw(tr, t_s, x, y, flat, rate, v_hv)
            ttc = d / -rate if rate < -CLOSING_MIN_MPS else None
            zone = self._zone(d, v_hv, ttc)
            road_x = road_y = None
            if hv is not None:
                if cpsi is None:        # the HV heading: once per frame
                    psi = math.radians(hv["heading_deg"]) if R is None else math.radians(self._ypr_of(R)[0])
                    cpsi, spsi = math.cos(psi), math.sin(psi)
                road_x = hv["x"] + cpsi * x - spsi * y       # eq. 53
                road_y = hv["y"] + spsi * x + cpsi * y
            if meas is None and i in dirs and (tr["id"] is not None or tr.get("n_meas", 1) >= 2):
                # A tracked pair without a range of its own this frame: its LED observations
                # carry the track's filtered distance (estimator "fv-track"), once the track is
                # decoded or ranged twice (a pair ranged once may be no car: `FV_CONFIRM_S`).
                tracked[i] = (float(d), float(std), "fv-track")
            out.append({"id": tr["id"], "distance_m": _r(d), "angle_deg": _r(math.degrees(tr["bearing"])),
                        "x": _r(x), "y": _r(y), "std_m": _r(std), "rel_speed_mps": _r(rate, 3),
                        "ttc_s": _r(ttc, 3), "zone": zone, "road_x": _r(road_x), "road_y": _r(road_y),
                        "coasting": meas is None})
        for key in [k for k, tr in self.fv_tracks.items() if k not in seen and t_s - tr["kf"].t_meas > s.fv_drop_s]:
            del self.fv_tracks[key]
        return self._dedupe_fv(out), not_fv, tracked

    def _would_hide_lamps(self, p: PairObservation, pairs) -> bool:
        """Would a car whose taillights are the undecoded pair `p` hide another taillight-role
        pair's lamp seen in this frame? That lamp's own blob measured now (age 0), between p's
        emitters in image x, from 0.3 separations above p's lamps to one below (a car's body: the
        roof about 0.4 m above its lamps, bumper and body down to the road below them, in units
        of the ~1.4 m lamp baseline), on a pair whose separation is `FV_OCCLUSION_RATIO` times
        smaller (it is farther): p's body would stand in that lamp's sight line, so p is no car
        (two lamps of different objects paired by chance: vehicle scene, FVs at 53-56 m, far heads
        across the road read as a car at 21-39 m above the host lane's car)."""
        (xa, ya), (xb, yb) = p.a_px, p.b_px
        lo, hi, yc, sep = min(xa, xb), max(xa, xb), 0.5 * (ya + yb), p.separation_px
        if not sep > 0:
            return False
        for q in pairs:
            if q is p or q.key == p.key or self._role(q) not in ("FV", "FV?"):
                continue
            if not q.separation_px * FV_OCCLUSION_RATIO < sep:
                continue
            for seen in (q.a_seen, q.b_seen):
                if seen is not None and seen[2] == 0 and lo < seen[0][0] < hi and -0.3 * sep < seen[0][1] - yc < sep:
                    return True
        return False

    def _taillight_like(self, p: PairObservation, res: dict, k: int) -> bool:
        """An undecoded pair's two measured emitters look like one car's taillights: level (their
        baseline within `FV_MAX_TILT_DEG` of horizontal in the camera's level frame; a car's
        lamps are mounted level) and of like area (within `FV_MAX_AREA_RATIO`). Two far
        street-light heads paired across the road are neither, as a rule (vehicle scene, FVs at
        53-56 m: heads 3 px apart vertically over 42 px, areas 24 and 11 px^2, read as a car at 40 m)."""
        s = self.s
        a_area, b_area = fv_measured(p)[1]
        if not (p.a_saturated or p.b_saturated) and \
                max(a_area, b_area) > FV_MAX_AREA_RATIO * max(min(a_area, b_area), 1e-9):
            return False        # (saturated blobs' areas are bloom: no size test)
        la, lb = self.Lv @ res["ra"][k], self.Lv @ res["rb"][k]
        rise = abs(float(lb[2] - la[2]))
        run = math.hypot(float(lb[0] - la[0]), float(lb[1] - la[1]))
        return rise <= math.tan(math.radians(FV_MAX_TILT_DEG)) * run

    def _on_mapped_sl(self, t_s: float, ua, ub, hv: dict | None, R) -> bool:
        """Whether either emitter (normalized image points ua, ub) lies within
        `FV_SL_GATE_DEG` of a mapped street-light head projected from the placed HV (camera at
        hv x, y and the last solved height, orientation R); False while the HV is unplaced."""
        if hv is None or R is None or not len(self._sl_heads):
            return False
        key = (t_s, hv["x"], hv["y"], self.z_last)
        if self._sl_seen_at[0] != key or self._sl_seen_at[1] is not R:
            X = (self._sl_heads - np.array([hv["x"], hv["y"], self.z_last])) @ R.T
            X = X[X[:, 2] > 1.0]
            self._sl_seen_at = (key, R, X[:, :2] / X[:, 2:3])
        P = self._sl_seen_at[2]
        if not len(P):
            return False
        g2 = math.tan(math.radians(FV_SL_GATE_DEG)) ** 2
        if _kr is not None and P.flags.c_contiguous:
            (ax, ay), (bx, by) = ua.tolist(), ub.tolist()
            return _kr.near_any(P, ax, ay, bx, by, g2)
        for u in (ua, ub):
            d = P - u
            if float(np.min(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])) < g2:
                return True
        return False

    def _fv_yaw(self, tr: dict, t_s: float, x: float, y: float, flat: float, rate: float, v_hv) -> None:
        """Update the track's lateral filter (y, level frame, a `RangeKalman`) and from it its
        heading relative to the camera (`tr["yaw"]`, rad, positive left): the FV's ground
        velocity in the HV frame is (V_HV + dx/dt - omega y, dy/dt + omega x) (omega: the HV's
        turn rate). A lane change yaws a car by 10-15 deg, which shortens its taillight baseline
        as seen by cos(yaw) (thesis eqs. 52-53 take it across the line of sight): ~3 % of range.
        0 until V_HV is known and the filter has `FV_YAW_MIN_FRAMES` positions."""
        s = self.s
        sig = max(FV_LATERAL_SIGMA_M, flat * math.radians(FV_BEARING_SIGMA_DEG))
        yk = tr["ykf"]
        if yk is None:
            tr["ykf"] = yk = RangeKalman(t_s, y, sig, FV_LATERAL_RATE_SIGMA_MPS, FV_LATERAL_ACCEL_PSD,
                                         FV_GATE_CHI2)
            tr["n_y"] = 1
        else:
            yk.predict(t_s)
            if yk.update(t_s, y, sig):
                tr["n_y"] += 1
            elif yk.rejects >= FV_MAX_REJECTS:
                tr["ykf"] = yk = RangeKalman(t_s, y, sig, FV_LATERAL_RATE_SIGMA_MPS, FV_LATERAL_ACCEL_PSD,
                                             FV_GATE_CHI2)
                tr["n_y"] = 1
        tr["yaw"] = 0.0
        if v_hv is None or tr["n_y"] < FV_YAW_MIN_FRAMES:
            return
        omega = float(self.kf.s[4]) if self.kf.started else 0.0
        xdot = rate * (x / max(math.hypot(x, y), 1e-6))       # d-dot along the line of sight
        vx, vy = v_hv + xdot - omega * y, yk.v + omega * x
        if vx > FV_YAW_MIN_SPEED_MPS:
            tr["yaw"] = max(-FV_YAW_MAX_RAD, min(FV_YAW_MAX_RAD, math.atan2(vy, vx)))

    def _dedupe_fv(self, out: list[dict]) -> list[dict]:
        """One entry per forward vehicle: a pair re-formed under a new key, or a stale coasting
        track, shows up at the bearing of the live one. Entries are kept decoded first, then
        measured this frame, then the surest; one within `FV_DUP_DEG` of a kept entry's bearing is
        dropped, as is a coasting one whose std exceeds `FV_COAST_MAX_REL` of its distance."""
        s = self.s
        out = [e for e in out if not e["coasting"] or (e["std_m"] or 0.0) <= FV_COAST_MAX_REL * (e["distance_m"] or 0.0)]
        if len(out) < 2:
            return out
        order = sorted(out, key=lambda e: (e["id"] is None, e["coasting"], e["std_m"] if e["std_m"] is not None else 1e9))
        kept = []
        for e in order:
            a = e["angle_deg"]
            if a is not None and any(k["angle_deg"] is not None and abs(k["angle_deg"] - a) < FV_DUP_DEG for k in kept):
                continue
            kept.append(e)
        return [e for e in out if any(e is k for k in kept)]

    def _zone(self, d: float, v_hv: float | None, ttc: float | None) -> str:
        """Thesis Figure 27 zones (module doc; thresholds in VehicleSettings)."""
        s = self.s
        if v_hv is not None and v_hv > 1.0:
            hw = d / v_hv
            zone = 0 if hw >= s.headway_safe_s else (1 if hw >= s.headway_min_s else 2)
        else:
            zone = 0 if d >= s.safe_distance_m else (1 if d >= s.min_distance_m else 2)
        if ttc is not None:
            if ttc < s.ttc_critical_s:
                zone = 2
            elif ttc < s.ttc_min_s:
                zone = max(zone, 1)
        return ZONES[zone]


def zone_for(d: float, v_hv: float | None, ttc: float | None,
             settings: VehicleSettings = VehicleSettings()) -> str:
    """The Figure 27 zone of a forward vehicle at d m, HV speed v_hv (m/s or None), ttc (s or None)."""
    loc = VehicleLocator.__new__(VehicleLocator)
    loc.s = settings
    return loc._zone(d, v_hv, ttc)
