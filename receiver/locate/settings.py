"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.core.settings import knob

from receiver.locate.kalman import DEFAULT_ACCEL_PSD, DEFAULT_MAX_COAST_S
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS
from receiver.locate.pose import DEFAULT_TILT_SIGMA_DEG
from receiver.locate.ranging import DEFAULT_EDGE_OFFSET_PX

# Most re-rangings of `ranging_iterations` a settings file may ask for (each is a whole re-fit;
# the ranges settle in a few).
MAX_RANGING_ITERATIONS = 100

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
    pixel_sigma_px: float = knob(0.3, above=0.0)
    edge_sigma_px: float = 0.1
    model_rel_sigma: float = 0.002
    edge_offset_px: float = DEFAULT_EDGE_OFFSET_PX
    kalman: bool = True
    accel_psd: float = DEFAULT_ACCEL_PSD
    max_coast_s: float = DEFAULT_MAX_COAST_S
    loss: str = DEFAULT_LOSS
    f_scale: float = DEFAULT_F_SCALE
    ranging_iterations: int = knob(0, 0, MAX_RANGING_ITERATIONS)
    border_margin_px: float = DEFAULT_BORDER_MARGIN_PX
    tilt_prior: str = "up"
    tilt_sigma_deg: float = knob(DEFAULT_TILT_SIGMA_DEG, hi=180.0, above=0.0)
    track_prior: bool = False
    ranges_only_iterations: int = knob(3, 0, MAX_RANGING_ITERATIONS)
    handedness: str | None = None
    outline: bool = True
    centroid_sigma_px: float = 1.5
    edge_model_sigma_px: float = 0.25


@dataclass(frozen=True)
class VehicleSettings:
    """What a user sets for vehicle positioning (receiver.locate.vehicle): the camera's mounting,
    the detector's edge offset, odometry, when to report, the tallest taillights, and the
    warning zones of thesis Figure 27. Emitter geometry (head emitters, sizes, normals, the
    taillight block) comes from the map; the model's constants (centroid noise, camera shake,
    road heading, coasting and forgetting times) are in the receiver.locate.vehicle_* modules."""

    camera_height_m: float = 1.2        # m above the road; 1.2: a car's dash camera (thesis Table 2)
    camera_pitch_deg: float = 0.0       # deg, nominal pitch (up +) until a pose is solved; 0: dash cameras look level
    edge_offset_px: float = 0.0         # px, envelope beyond the emitter's true edge; 0: lens blur offsets the half pixel
    speed_sigma_mps: float = 0.3        # m/s, 1-sigma of the --odometry speed; 0.3: a wheel-speed log
    hv_max_std_m: float = 1.0           # m, the host is reported only this sure (filtered 2D std); 1: tells the lane
    fv_max_height_m: float = 2.5        # m, highest taillights an undecoded pair may be; 2.5: trucks' lamps
    headway_safe_s: float = 2.0         # s, Figure 27 "safe" at this headway or more; 2: the two-second rule
    headway_min_s: float = 1.0          # s, "min" down to this headway, "critical" below (thesis Figure 27)
    ttc_critical_s: float = 2.0         # s, time to collision below this is "critical" whatever the headway
    ttc_min_s: float = 4.0              # s, time to collision below this is at least "min"
    safe_distance_m: float = 30.0       # m, without the host speed: "safe" at this distance or more (2 s at 54 km/h)
    min_distance_m: float = 15.0        # m, ... "min" down to this, "critical" below (1 s at 54 km/h)
