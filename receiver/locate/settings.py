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
