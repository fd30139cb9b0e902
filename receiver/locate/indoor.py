"""Indoor positioner: a frame's decoded ceiling LEDs -> ranges (`receiver.locate.ranging`) and
undistorted image points -> `PoseFilter` -> the INTERFACES.md `position` object.
"""

from __future__ import annotations

import math

import numpy as np

from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap
from receiver.locate.kalman import DEFAULT_ACCEL_PSD, DEFAULT_MAX_COAST_S
from receiver.locate.ranging import DEFAULT_EDGE_OFFSET_PX, ESTIMATORS, contour_geometry, distance_eq18, distance_oblique, range_sigma_m, ray_unit, undistort_points
from receiver.core.records import LedObservation, LocateResult
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS
from receiver.locate.pose import DEFAULT_TILT_SIGMA_DEG, align_rays
from receiver.locate.posefilter import PoseFilter
# A blob whose envelope comes this close (px) to the image edge is cut by it: its area and
# centroid are biased (the detector's `border` flag misses envelopes extrapolated past the edge).
# Rolling-shutter envelopes end at the last lit stripe, so a blob cut by the edge can end up to a
# dark run (several rows) short of it: the margin covers that.
DEFAULT_BORDER_MARGIN_PX = 10.0


class Positioner:
    """Decoded LEDs of one frame -> distances and camera position, Kalman-filtered over frames.

    Options (keywords, documented defaults):
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

    def __init__(self, camera: CameraModel, led_map: LedMap, *, ranging: str = "oblique",
                 solver: str = "auto", pixel_sigma_px: float = 0.3, edge_sigma_px: float = 0.1,
                 model_rel_sigma: float = 0.002, edge_offset_px: float = DEFAULT_EDGE_OFFSET_PX,
                 kalman: bool = True, accel_psd: float = DEFAULT_ACCEL_PSD,
                 max_coast_s: float = DEFAULT_MAX_COAST_S, loss: str = DEFAULT_LOSS,
                 f_scale: float = DEFAULT_F_SCALE, ranging_iterations: int = 0,
                 border_margin_px: float = DEFAULT_BORDER_MARGIN_PX, tilt_prior: str = "up",
                 tilt_sigma_deg: float = DEFAULT_TILT_SIGMA_DEG, track_prior: bool = False,
                 ranges_only_iterations: int = 3, handedness: str | None = None):
        if ranging not in ESTIMATORS:
            raise ValueError(f"unknown ranging estimator {ranging!r}")
        self.camera, self.led_map = camera, led_map
        self.ranging, self.solver = ranging, solver
        self.edge_sigma_px, self.model_rel_sigma = edge_sigma_px, model_rel_sigma
        self.edge_offset_px = edge_offset_px
        self.ranging_iterations = ranging_iterations
        self.ranges_only_iterations = ranges_only_iterations
        self.border_margin_px = border_margin_px
        self.pose = PoseFilter(handedness=handedness or led_map.handedness,
                               sigma_uv=pixel_sigma_px / camera.focal_px, solver=solver, kalman=kalman,
                               accel_psd=accel_psd, max_coast_s=max_coast_s, loss=loss, f_scale=f_scale,
                               tilt_prior=tilt_prior, tilt_sigma_deg=tilt_sigma_deg, track_prior=track_prior)
        self.unknown_ids: set[int] = set()

    @property
    def n_fixes(self) -> int:
        return self.pose.n_fixes

    def _ranges(self, items, R_cw):
        d = np.full(len(items), np.nan)
        sd = np.full(len(items), np.nan)
        names = [""] * len(items)
        for i, (obs, led, geo) in enumerate(items):
            A = led.area_m2
            if not A:
                continue
            if self.ranging == "oblique" and geo is not None:
                Rw = np.eye(3) if R_cw is None else R_cw
                d[i] = distance_oblique(geo["area_norm"], A, ray_unit(geo["centroid_norm"]), Rw)
                names[i] = "oblique-up" if R_cw is None else "oblique-pose"
                area_px, perim = geo["area_px"], geo["perimeter_px"]
            else:
                d[i] = distance_eq18(obs.area_px, A, self.camera.focal_px)
                names[i] = "eq18"
                area_px = obs.area_px
                perim = 4.0 * math.sqrt(max(area_px, 0.0))   # square-ish blob without a contour
            sd[i] = range_sigma_m(d[i], area_px, perim, self.edge_sigma_px, self.model_rel_sigma)
        return d, sd, names

    def _touches_edge(self, obs: LedObservation) -> bool:
        if obs.contour is None or len(obs.contour) == 0:
            return False
        c = np.asarray(obs.contour, float).reshape(-1, 2)
        m = self.border_margin_px
        lo = c.min(axis=0)
        hi = c.max(axis=0)
        return bool(lo[0] <= m or lo[1] <= m or hi[0] >= self.camera.width - 1 - m
                    or hi[1] >= self.camera.height - 1 - m)

    def measure(self, leds: list[LedObservation]) -> list:
        """The frame's usable LEDs: (observation, map LED, contour geometry or None) for every
        decoded, uncut OOK or tone LED the map knows (unknown IDs are counted in `unknown_ids`).
        S2-PSK lights are left out: a street-light head or a taillight pair is seen as two
        emitter blobs, not one fixture of the map's size, from a camera looking along the road,
        not up at a ceiling; placing the vehicle from them is thesis eqs. 44-53, not this
        indoor solver (whose fixes and ranges from them were metres off on the vehicle scene)."""
        items = []
        for obs in leds:
            if obs.id is None or obs.border or obs.mode == "s2psk" or self._touches_edge(obs):
                continue
            led = self.led_map.lookup(obs.id)
            if led is None:
                self.unknown_ids.add(obs.id)
                continue
            if led.mode == "s2psk":
                continue
            geo = None
            if obs.contour is not None and len(obs.contour) >= 3:
                geo = contour_geometry(obs.contour, self.camera, self.edge_offset_px)
            items.append((obs, led, geo))
        return items

    def image_points(self, items) -> np.ndarray:
        """(N, 2) undistorted normalized image points of `measure`'s items."""
        if not items:
            return np.zeros((0, 2))
        return undistort_points(np.array([[o.cx, o.cy] for o, _, _ in items]), self.camera)

    def step(self, t_s: float, leds: list[LedObservation]) -> LocateResult:
        items = self.measure(leds)
        R_prior = self.pose.R_prior(t_s)
        d, sd, names = self._ranges(items, R_prior)
        fix = None
        if items:
            L = np.array([led.xyz for _, led, _ in items])
            uv = self.image_points(items)
            fix = self.pose.solve(t_s, L, uv, d, sd, R_prior)
            n_iter = self.ranges_only_iterations if self.solver == "multilateration" else self.ranging_iterations
            for _ in range(n_iter if self.ranging == "oblique" else 0):
                if fix is None:
                    break
                # Foreshortening with this frame's own orientation, then solve again. Ranges-only
                # fixes carry no orientation: align the camera rays with the LED directions.
                R = fix.R_cw
                if R is not None:
                    d, sd, names = self._ranges(items, R)
                else:
                    # Tilt error and range error feed each other back here with a gain of about
                    # -2/3 (ceiling LEDs), so the plain loop oscillates; averaging old and new
                    # ranges damps the loop gain to about 1/6.
                    R = align_rays(ray_unit(uv), self.pose.to_solving(L) - fix.C)
                    d_new, sd, names = self._ranges(items, R)
                    d = np.where(np.isfinite(d), 0.5 * (d + d_new), d_new)
                fix = self.pose.solve(t_s, L, uv, d, sd, R) or fix
            if fix is not None and fix.R_cw is not None and self.ranging == "oblique":
                # The reported distances use this frame's own orientation (cheap: no new solve).
                d, sd, names = self._ranges(items, fix.R_cw)
        return LocateResult(distances=self.distances(items, d, names),
                            position=self.pose.update(t_s, fix, len(items)))

    @staticmethod
    def distances(items, d: np.ndarray, names: list[str]) -> dict:
        """`LocateResult.distances` of `measure`'s items: track -> (distance m, estimator) for
        every finite range."""
        return {obs.track: (round(float(d[i]), 5), names[i])
                for i, (obs, _, _) in enumerate(items) if math.isfinite(d[i])}
