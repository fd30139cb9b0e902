"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.core.settings import knob

from receiver.locate.kalman import DEFAULT_ACCEL_PSD, DEFAULT_MAX_COAST_S
from receiver.locate.pose import DEFAULT_TILT_SIGMA_DEG
from receiver.locate.ranging import DEFAULT_EDGE_OFFSET_PX

# A blob whose envelope comes this close (px) to the image edge is cut by it: its area and
# centroid are biased (the detector's `border` flag misses envelopes extrapolated past the edge).
# Rolling-shutter envelopes end at the last lit stripe, so a blob cut by the edge can end up to a
# dark run (several rows) short of it: the margin covers that.
DEFAULT_BORDER_MARGIN_PX = 10.0


@dataclass(frozen=True)
class PositionerSettings:
    """What a user sets for indoor positioning (`receiver.locate.indoor.Positioner`); the
    solver's model constants are in receiver.locate.indoor, pose and outline_pose."""

    # LED ranges from blob areas: "oblique" (foreshortened by the orientation) or "eq18" (thesis eq. 18)
    ranging: str = "oblique"
    # "auto" (ranges + image angles), "multilateration" (ranges only) or "pnp" (angles only)
    solver: str = "auto"
    # px, 1-sigma of an LED's image point: envelope centroids of blobs of hundreds of px
    pixel_sigma_px: float = knob(0.3, above=0.0)
    # px, 1-sigma of a blob's contour all around, in the range error model (ranging.range_sigma_m)
    edge_sigma_px: float = 0.1
    # px, offset of the true edge outside the contour, corrected in the area (ranging module doc)
    edge_offset_px: float = DEFAULT_EDGE_OFFSET_PX
    # px, blobs this close to the image edge (or flagged `border`) are left out: cut area and centroid
    border_margin_px: float = DEFAULT_BORDER_MARGIN_PX
    # filter the fixes over frames (constant-velocity Kalman, receiver.locate.kalman); False: raw fixes
    kalman: bool = True
    # m^2/s^3, the filter's white-acceleration density: a walking phone, ~1 m/s^2 over ~0.5 s
    accel_psd: float = DEFAULT_ACCEL_PSD
    # s, the filter coasts (and the last orientation stays a prior) this long without a fix
    max_coast_s: float = DEFAULT_MAX_COAST_S
    # deg, a phone held up at the ceiling: the prior that fixes the turn about a line of LEDs
    tilt_sigma_deg: float = knob(DEFAULT_TILT_SIGMA_DEG, hi=180.0, above=0.0)
    # "right" or "left" overrides the map's handedness; None: the map's, or told from the images
    handedness: str | None = None
    # refine the pose on the LEDs' outlines where the map knows their shape and size; False: centroids only
    outline: bool = True


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
