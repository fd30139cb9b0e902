"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.locate.kalman import DEFAULT_ACCEL_PSD, DEFAULT_MAX_COAST_S
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS
from receiver.locate.pose import DEFAULT_TILT_SIGMA_DEG
from receiver.locate.ranging import DEFAULT_EDGE_OFFSET_PX

# A blob whose envelope comes this close (px) to the image edge is cut by it: its area and
# centroid are biased (the detector's `border` flag misses envelopes extrapolated past the edge).
# Rolling-shutter envelopes end at the last lit stripe, so a blob cut by the edge can end up to a
# dark run (several rows) short of it: the margin covers that.
DEFAULT_BORDER_MARGIN_PX = 10.0


@dataclass(frozen=True)
class PositionerSettings:
    """Tunables of `Positioner` (defaults in brackets).

    `ranging`: "oblique" (default, see receiver.locate.ranging) or "eq18".
    `solver`: "auto" (ranges + angles), "multilateration" (ranges only) or "pnp" (angles only).
    `pixel_sigma_px`: 1-sigma of an LED image point, px (0.3: envelope centroids of blobs of
        hundreds of pixels are good to a fraction of a pixel).
    `edge_sigma_px`, `model_rel_sigma`: range error model (receiver.locate.ranging.range_sigma_m).
    `edge_offset_px`: contour-to-true-edge offset for the area bias (receiver.locate.ranging).
    `kalman`: filter the fixes (PositionKalman with `accel_psd` m^2/s^3, `max_coast_s`).
    `loss`, `f_scale`: robust loss of the refinements (scipy names; f_scale in sigmas).
    `ranging_iterations`: with "oblique" ranging, how often the ranges are recomputed with the
        orientation of the frame's own fix and the fix solved again (the first pass uses the
        previous frame's orientation, or "looking straight up"). Default 0: each re-solve costs
        a least-squares run (~5 ms) and moves the walk's median error by only ~3 mm; the
        reported distances always use the frame's own orientation (no re-solve needed for that).
    `ranges_only_iterations`: the same for the "multilateration" solver, whose ranges have no
        other source of orientation (the tilt feeds back into the foreshortening term).
    `tilt_prior`: "up" (default: a phone held up at the ceiling, within `tilt_sigma_deg` of
        vertical) or "previous" (the previous frame's orientation): the prior that fixes the
        rotation about the LED line when the usable LEDs are collinear (a single row of panels,
        the common case on the bundled walk) or only 2. Chaining "previous" lets the tilt random
        walk; a fixed weak prior does not.
    `track_prior`: also pull collinear fixes toward the Kalman prediction (off by default: the
        filter already fuses the fix, whose covariance is large along the unobserved direction).

    `border_margin_px`: blobs whose envelope comes this close to the image edge are left out, as
        are blobs flagged `border`: their area and centroid are cut by the frame edge.
    LEDs whose ID the map does not know are counted in `unknown_ids`.
    `handedness`: "right" or "left" overrides the map's own (`PoseFilter`); None: the map's, or
        told from the images when the map does not say.
    `outline` [True]: where the pipeline measured a decoded LED's stripe edge points
        (`LedObservation.edge_px`) and the map knows its shape and size, the pose is refined on
        the LEDs' outlines (receiver.locate.outline_pose; LEDs cut by the image border still
        contribute their visible edges) and those LEDs' ranges are the distances to the fitted
        fixtures (`distance_estimator` "outline"); the others keep `ranging`. False: today's
        centroid + area solve only.
    `centroid_sigma_px` [1.5]: 1-sigma of an envelope centroid in the outline solve (its caps
        can miss up to two chips).
    `edge_model_sigma_px` [0.25]: added in quadrature to each edge point's own sigma for what the
        outline model leaves out, chiefly the rolling shutter: the camera moves while the rows
        are read (the bundled walk's outline residuals are ~0.3 px RMS against ~0.04 px of
        noise on the still indoor-static scene).
    """

    ranging: str = "oblique"
    solver: str = "auto"
    pixel_sigma_px: float = 0.3
    edge_sigma_px: float = 0.1
    model_rel_sigma: float = 0.002
    edge_offset_px: float = DEFAULT_EDGE_OFFSET_PX
    kalman: bool = True
    accel_psd: float = DEFAULT_ACCEL_PSD
    max_coast_s: float = DEFAULT_MAX_COAST_S
    loss: str = DEFAULT_LOSS
    f_scale: float = DEFAULT_F_SCALE
    ranging_iterations: int = 0
    border_margin_px: float = DEFAULT_BORDER_MARGIN_PX
    tilt_prior: str = "up"
    tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG
    track_prior: bool = False
    ranges_only_iterations: int = 3
    handedness: str | None = None
    outline: bool = True
    centroid_sigma_px: float = 1.5
    edge_model_sigma_px: float = 0.25


@dataclass(frozen=True)
class VehicleSettings:
    """All settings of vehicle positioning (module doc), with their defaults' reasons."""

    # Ranging ----------------------------------------------------------------------------------
    range_estimator: str = "fused"      # reported in VehicleResult.ranges (one of ESTIMATORS)
    centroid_sigma_px: float = 0.2      # 1-sigma of one emitter centroid, px
    sl_separation_sigma_px: float = 0.3  # street-light head: 1-sigma of the emitters' separation
                                        # (the difference of the two centroids), px. One emitter of
                                        # a head is lit at a time: the other's position is the
                                        # pairing's model (whole px, a frame or more old), and far
                                        # heads are sub-pixel tall bars: their separation is off
                                        # by 0.5-1 px (bundled recording), not sqrt(2) x 0.2 px.
                                        # Weighs the baseline range and, in the pose solve, the
                                        # separation of the two centroids (their midpoint keeps
                                        # `centroid_sigma_px`); a range from 6 px is then ~12 %.
    edge_offset_px: float = 0.0         # envelope vs true edge: with the lens blur (bundled vehicle
                                        # recording) the envelope of a small taillight is its true
                                        # area (eq. 18 median -0.2 %); 0.5 px read 20 % short at 40 m
    fv_centroid_sigma_px: float = 0.2   # taillight centroids, both measured in the same frame
                                        # (vehicle.fv_measured): bundled recording, separation
                                        # error |median| 0.39 % of 44-125 px (~0.2 px each)
    fv_area_model_rel: float = 0.05     # taillight eq. 18 model error: striped 10-50 px envelopes,
                                        # cut by clock edges (bundled recording: "oblique" +3.1 %
                                        # signed, 4.0 % |median|), relative
    edge_sigma_px: float = 0.1          # edge location 1-sigma all around, px (range_sigma_m)
    area_model_rel: float = 0.01        # eq. 18 model error (small patch, calibration), relative
    baseline_model_rel: float = 0.002   # baseline ranging model error with a known baseline
    taillight_yaw_sigma_deg: float = 5.0  # FV heading vs HV heading (taillight baseline direction)
    consistency_sigmas: float = 4.0     # area vs baseline range disagreement that drops the area one
    orient_sigma_pose_deg: float = 0.3  # camera orientation 1-sigma when the pose is solved
    orient_sigma_prior_deg: float = 5.0  # ... when only the nominal tilt is known
    # Camera mounting (weak priors) -----------------------------------------------------------
    camera_height_m: float = 1.2        # above the road; thesis Table 2 car camera ~1.2 m
    camera_height_sigma_m: float = 0.3
    camera_pitch_deg: float = 0.0       # nominal pitch (up positive), roll assumed 0
    tilt_sigma_deg: float = 10.0        # weak prior on the tilt (matters with one light only)
    # Host vehicle -----------------------------------------------------------------------------
    hv_method: str = "pose"             # the fix fed to the filter: "pose" or "eq44-47"
    min_lights: int = 2                 # street lights (pairs) needed for a full pose fix
    single_light: bool = True           # with one light in view: a fix from its two emitters and a
                                        # heading prior (vehicle.VehicleLocator._single_fix,
                                        # method "pose-1sl", n_lights 1)
    yaw_shake_sigma_deg: float = 0.3    # camera yaw about the HV heading (mount, shake): vehicle-road
                                        # truth 0.12 deg std, 0.29 deg max
    road_heading_sigma_deg: float = 3.0  # HV heading about the map's road direction near a light
                                        # (before the filter runs): a lane change yaws the car by
                                        # up to 6.4 deg (vehicle-road truth), most frames < 3 deg
    hv_max_std_m: float = 1.0           # the HV is reported only while its filtered 2D std is at most
                                        # this (a fix 3 std off is then within ~2-3 m)
    roll_sigma_deg: float = 1.0         # single-light solve: camera roll about 0 (mount, body roll)
    pitch_sigma_deg: float = 0.5        # ... and pitch about the last full pose's (shake: vehicle-road
                                        # truth 0.19 deg std, bundled vehicle 0.14 deg)
    pose_loss: str = "soft_l1"
    pose_f_scale: float = 3.0           # sigmas
    pose_max_iter: int = 20
    pose_track_iter: int = 2            # iterations warm-started from the road filter's prediction
                                        # (x, y) and the last solved orientation and height; bundled
                                        # vehicle: 4 -> HV filtered 0.04 / 0.16 m, raw p95 1.51 m;
                                        # 8 -> 0.04 / 0.16 m, raw p95 2.65 m (5.3 vs 8.6 evaluations).
                                        # Issue 11 (replay of the vehicle stage, 150 frames, callgrind,
                                        # start-up subtracted): 4 -> 3.75 M instructions a frame,
                                        # filtered 0.06 / 0.17 m, raw p95 1.33 m; 2 -> 3.21 M, 0.05 /
                                        # 0.17 m, raw 0.69 m; 1 -> 2.90 M, 0.05 / 0.18 m, raw 0.24 m
                                        # (a single step leans on the prediction it starts from, which
                                        # the filter then counts again: not taken)
    pose_rot_tol_rad: float = 1e-5      # the solve stops once a step turns the camera by less
    pose_pos_tol_m: float = 1e-3        # ... and moves it by less (the output's resolution ~1e-4 m)
    fix_floor_m: float = 0.15           # added in quadrature to each pose fix's sigma (x and y) for
                                        # the filter: the solve's covariance knows the centroid and
                                        # range noise, not the heads' model errors (bundled vehicle:
                                        # fixes claiming 0.01 m off by 0.1-0.3 m gated the next
                                        # ones out and restarted the filter)
    heading_sigma_deg: float = 1.0      # camera yaw as HV heading measurement (mounting, pitch)
    accel_psd: float = 2.0              # car: accelerations ~2 m/s^2 persisting ~1 s, m^2/s^3
    yaw_accel_psd: float = 0.05         # rad^2/s^3
    init_speed_sigma_mps: float = 15.0
    init_omega_sigma_rps: float = 0.2
    speed_sigma_mps: float = 0.3        # odometry 1-sigma
    gate_chi2: float = 13.8             # chi-square 2 dof, 99.9 %
    max_rejects: int = 3
    sl1_range_floor_rel: float = 0.05   # added in quadrature to a single light's range sigma for the
                                        # filter: one head's range errors persist over frames
                                        # (bundled vehicle, one light kept per frame: 0.03 -> worst
                                        # error 3.3 std, 0.05 -> 2.0 std)
    sl1_max_std_m: float = 1.5          # a single light updates the filter only while its predicted 2D
                                        # std is at most this (vehicle-road, tilted heads: updates of a
                                        # filter tens of metres off left it 10 m off at 1 m std)
    sl1_start_max_std_m: float = 0.7    # ... and starts it only from a single-light pose this sure
                                        # (bundled vehicle, one light kept per frame: 1.0 -> 17 frames
                                        # placed, one 2.1 m off; 0.7 -> 75, worst 1.5 m, 2.4 std)
    speed_init_min_dt_s: float = 0.12   # first two fixes this far apart give the initial speed (bundled
                                        # vehicle: 1 frame apart read -52 m/s from fixes 0.7 and 1.1 m off)
    speed_hist_s: float = 0.3           # the heads' image growth over this long gives the HV speed at a
    speed_hist_min: int = 5             # filter start without odometry (at least this many samples)
    speed_motion_floor_mps: float = 1.0  # ... with its sigma at least this
    map_assoc: bool = True              # undecoded pairs matched to mapped heads serve the host solve
                                        # (vehicle.VehicleLocator._associate; never reported as IDs)
    assoc_max_std_m: float = 1.0        # ... only while the filter's predicted 2D std is at most this
    assoc_gate_chi2: float = 9.21       # ... Mahalanobis^2 gate of a pair's midpoint to a projected head
                                        # (chi-square 2 dof, 99 %)
    assoc_max_age: int = 1              # ... and both its emitters' own blobs seen within this many
                                        # frames (else the pairing's whole-pixel model stands in)
    assoc_sep_tol: float = 0.3          # ... and its separation within this of the head's predicted one
    obs_gate_chi2: float = 16.3         # one light's (u, v, range) into the filter: chi-square 3 dof, 99.9 %
    max_coast_s: float = 2.0            # forget the HV track after this long without a fix
    # Forward vehicles -------------------------------------------------------------------------
    fv_accel_psd: float = 4.0           # relative acceleration density, m^2/s^3
    fv_rate_sigma_mps: float = 10.0     # initial range-rate uncertainty
    fv_drop_s: float = 1.0              # forget an FV track unseen this long
    fv_confirm_s: float = 0.6           # an undecoded pair's track ranged once only is forgotten when
                                        # no second range comes within this long, and its LEDs carry
                                        # no "fv-track" distance until then: bundled vehicle, two
                                        # 170-185 m heads paired across the road once passed for a
                                        # car at 21 m and coasted 23 frames ("fv-track" p95 88 %);
                                        # 0.3 s dropped 35 right FV entries on vehicle-road seed 1
                                        # (taillights there are ranged seldom, occluded)
    fv_gate_chi2: float = 9.0           # range innovation gate (3 sigma) of an FV track
    fv_max_rejects: int = 4             # consecutive gated ranges that restart the track
    fv_dup_deg: float = 0.5             # FV entries closer in bearing are one vehicle (one kept)
    fv_coast_max_rel: float = 0.05      # a coasting FV entry is reported while its std <= this x d
    fv_lateral_sigma_m: float = 0.05    # FV lateral position (level frame) 1-sigma floor, m
    fv_bearing_sigma_deg: float = 0.05  # ... and its bearing's 1-sigma (bundled recording 0.04 deg)
    fv_lateral_rate_sigma_mps: float = 2.0  # initial lateral-rate uncertainty
    fv_lateral_accel_psd: float = 0.5   # lateral relative acceleration density (lane change), m^2/s^3
    fv_yaw_min_frames: int = 10         # lateral positions before the FV's yaw is estimated
    fv_yaw_min_speed_mps: float = 3.0   # ... and FV ground speed needed (yaw = atan2(vy, vx))
    fv_yaw_max_rad: float = 0.5         # |yaw| clipped here (~29 deg)
    fv_min_height_m: float = 0.0        # undecoded pairs within these heights are taillights
    fv_max_height_m: float = 2.5
    fv_max_tilt_deg: float = 3.0        # an undecoded pair is a taillight pair only if its baseline is
                                        # this level (camera's level frame; road cross-slope, body roll)
    fv_max_area_ratio: float = 2.0      # ... and its two emitters' areas within this ratio
    fv_sl_gate_deg: float = 0.5         # an undecoded pair with an emitter this close to a mapped street
                                        # light (projected from the placed HV) is no taillight pair
    fv_occlusion_ratio: float = 1.1     # a new undecoded pair is no car when a lamp of a taillight-role
                                        # pair with a separation this many times smaller (farther) is
                                        # seen inside its body's image: its body would hide that lamp
    closing_min_mps: float = 0.2        # ttc only when closing faster than this
    headway_safe_s: float = 2.0         # Figure 27: "safe" at >= 2 s headway (two-second rule)
    headway_min_s: float = 1.0          # "min" between 1 and 2 s, "critical" below 1 s
    ttc_critical_s: float = 2.0         # ttc below this is "critical" whatever the headway
    ttc_min_s: float = 4.0              # ttc below this is at least "min"
    safe_distance_m: float = 30.0       # without V_HV: distance thresholds instead of headway
    min_distance_m: float = 15.0
