"""Indoor positioner: a frame's decoded ceiling LEDs -> ranges (`receiver.locate.ranging`) and
undistorted image points -> `PoseFilter` -> the INTERFACES.md `position` object.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from receiver.core.native import require
from receiver.core.records import LedObservation, LocateResult
from receiver.core.settings import resolve_settings
from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap
from receiver.locate import map_prior
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS
from receiver.locate.outline_pose import (
    OutlineFrame,
    fixture_half_extents,
    panel_start_poses,
    solve_outline_pose,
)
from receiver.locate.pose import align_rays
from receiver.locate.posefilter import PoseFilter
from receiver.locate.ranging import ESTIMATORS, Ranger, Undistorter, ray_unit
from receiver.locate.settings import PositionerSettings

# the compiled packing of a frame's outline targets (receiver/locate/_ranging.pyx)
_kr = require("receiver.locate._ranging")

# With "oblique" ranging, how often a frame's ranges are recomputed with the orientation of its own
# fix and the fix solved again (the first pass uses the previous frame's orientation, or "looking
# straight up"): none, as each re-solve is a least-squares run and moves the walk's median error by
# ~3 mm; the reported distances use the frame's own orientation anyway (no re-solve needed). The
# ranges-only solver has no other source of orientation (its tilt feeds the foreshortening): 3.
RANGING_ITERATIONS = 0
RANGES_ONLY_ITERATIONS = 3
# Added in quadrature to each outline edge point's own sigma (px) for what the outline model leaves
# out, chiefly the rolling shutter: the camera moves while the rows are read (the bundled walk's
# outline residuals are ~0.3 px RMS against ~0.04 px of noise on the still indoor-static scene).
EDGE_MODEL_SIGMA_PX = 0.25
# An outline fit this good (chi^2 per dof) is taken without trying the other starting poses.
GOOD_OUTLINE_CHI2_DOF = 4.0
# ... and this good when it started from the tracked pose (`Positioner._outline_warm`): a warm start
# on the wrong branch or symmetry fits far worse (the solve rejects beyond MAX_CHI2_DOF, 50), while
# indoor-sparse's tilted panels fit at 4-9 from every start (at 4.0 each such frame paid the centroid
# solve and two more outline solves, ~3x a warm frame, to move the fix by 0-0.9 mm).
WARM_OUTLINE_CHI2_DOF = 10.0
# Outline points that may veto a centroid fix they cannot be fitted from.
MIN_VETO_POINTS = 40
# Starts from the panels alone (`Positioner._panel_fix`): two solved poses closer than
# START_MERGE_M are one; a second pose more than AMBIGUOUS_M from the best whose chi^2 per dof is
# within AMBIGUOUS_CHI2_RATIO of it makes the frame ambiguous (no fix); with a tracked orientation
# only starts turned at most TRACKED_TURN_DEG plus TURN_RATE_DEG_S times its age from it (a phone
# turns at 10-30 deg/s; a lone square's other sides are 90 degrees away).
START_MERGE_M = 0.02
AMBIGUOUS_M = 0.10
AMBIGUOUS_CHI2_RATIO = 4.0
TRACKED_TURN_DEG = 20.0
TURN_RATE_DEG_S = 60.0
# Each panel start's solve is repeated from its result while chi^2 per dof drops by more than
# POLISH_GAIN, at most POLISH_SOLVES times (`Positioner._polished`).
POLISH_SOLVES = 3
POLISH_GAIN = 0.05
# The tilt prior's "up": a phone held up at the ceiling (world z).
_UP = np.array([0.0, 0.0, 1.0])


def derotate_rows(uv: np.ndarray, rows_px: np.ndarray, w_cam: np.ndarray, row_s: float, ref_row: float) -> np.ndarray:
    """Normalized undistorted image points `uv` (N, 2) of a rolling-shutter frame, each read at
    image row `rows_px` (N,), as the camera would have seen them at the instant of row `ref_row`:
    the camera turns at `w_cam` (rad/s, camera frame, `PoseFilter.angular_rate`) and a row is read
    `row_s` seconds after the one above it, so a point read tau = (row - ref_row) row_s later
    lies on the ray Exp(tau w) x_ref; its reference ray is Exp(-tau w) x (Rodrigues' formula per
    point). The camera's translation over tau (a few mm) is left to `Positioner._at_frame_time`."""
    rate = math.sqrt(float(w_cam @ w_cam))
    if rate == 0.0:
        return np.array(uv, float)
    k0, k1, k2 = (np.asarray(w_cam, float) / rate).tolist()
    a = (np.asarray(rows_px, float) - ref_row) * (-row_s * rate)
    c, s = np.cos(a), np.sin(a)
    u, v = uv.T.copy()  # both columns contiguous, once
    # Rodrigues: x c + (k x x) s + k (k . x) (1 - c), x = (u, v, 1); each sum in the order
    # written, accumulated in place
    kx = k0 * u                                 # (k0 u + k1 v + k2) (1 - c)
    kx += k1 * v
    kx += k2
    kx *= 1.0 - c
    z = k0 * v                                  # c + (k0 v - k1 u) s + k2 kx
    z -= k1 * u
    z *= s
    z += c
    z += k2 * kx
    out = np.empty((len(u), 2))
    t = np.subtract(k1, k2 * v)                 # (u c + (k1 - k2 v) s + k0 kx) / z
    t *= s
    t += u * c
    t += k0 * kx
    t /= z
    out[:, 0] = t
    t = k2 * u                                  # (v c + (k2 u - k0) s + k1 kx) / z
    t -= k0
    t *= s
    t += v * c
    t += k1 * kx
    t /= z
    out[:, 1] = t
    return out


def detranslate_rows(uv: np.ndarray, rows_px: np.ndarray, z_plane: np.ndarray, R_cw: np.ndarray, C: np.ndarray,
                     v: np.ndarray, row_s: float, ref_row: float) -> np.ndarray:
    """Normalized undistorted image points `uv` (N, 2) of a rolling-shutter frame, each read at
    image row `rows_px` (N,) by a camera of orientation `R_cw` (the reference row's: `derotate_rows`
    first) moving at `v` (m/s, solving frame), as seen from `C`, its centre at the instant of row
    `ref_row`. Point i lies on the horizontal plane z = `z_plane[i]` (a face-down ceiling LED's)
    and was read tau = (row - ref_row) row_s later from C + v tau, at camera depth
    Z = (z_plane - C_z - v_z tau) / (R^T x)_z along its ray x = (u, v, 1): seen from C it lies on
    Z x + R v tau. A walking phone moves ~1 cm while a frame's rows are read: at 2 m from the
    ceiling a shift of 5 mrad between the first and the last rows' LEDs (5 px at 1000 px focal
    length), which no single camera pose explains."""
    tau = (np.asarray(rows_px, float) - ref_row) * row_s
    x = np.column_stack([uv, np.ones(len(uv))])
    with np.errstate(divide="ignore", invalid="ignore"):     # a ray along the plane: inf / NaN out
        Z = (np.asarray(z_plane, float) - C[2] - v[2] * tau) / (x @ R_cw[:, 2])
        # Y = x Z + tau R v, column by column (x's third column is 1: Y_z = Z + tau (R v)_z)
        rv = (R_cw @ v).tolist()
        yz = Z + tau * rv[2]
        out = np.empty((len(uv), 2))
        np.divide(x[:, 0] * Z + tau * rv[0], yz, out=out[:, 0])
        np.divide(x[:, 1] * Z + tau * rv[1], yz, out=out[:, 1])
        return out


def _pack_outline(chosen, model_sigma_px: float, focal_px: float):
    """(points (M + T, 2) px: every target's edge points in turn, then the T centroids; sigma (M,)
    normalized: hypot(point sigma, model sigma) / focal; ends (T + 1,) int64; centres (T, 3) map
    m; half extents (T, 2)) of `Positioner._outline_targets`' (observation, edges, fixture)
    list, by the compiled packing; edge arrays that are not float64 C-contiguous are converted first."""
    try:
        return _kr.pack_outline(chosen, model_sigma_px, focal_px)
    except (ValueError, TypeError, BufferError):
        f64 = [(o, (np.ascontiguousarray(e[0], np.float64).reshape(-1, 2), np.ascontiguousarray(e[1], np.float64).ravel()),
                fx) for o, e, fx in chosen]
        return _kr.pack_outline(f64, model_sigma_px, focal_px)


class Positioner:
    """Decoded LEDs of one frame -> distances and camera position, Kalman-filtered over frames.

    Tunables: `PositionerSettings` (receiver.locate.settings), given as `settings=` or as keyword
    overrides of its fields. LEDs whose ID the map does not know are counted in `unknown_ids`.
    """

    def __init__(self, camera: CameraModel, led_map: LedMap, *, settings: PositionerSettings | None = None,
                 **overrides):
        s = self.settings = resolve_settings(settings, PositionerSettings, overrides)
        if s.ranging not in ESTIMATORS:
            raise ValueError(f"unknown ranging estimator {s.ranging!r}")
        self.camera, self.led_map = camera, led_map
        self.ranging, self.solver = s.ranging, s.solver
        self.ranger = Ranger(camera, led_map, s)
        self._undistort = Undistorter(camera)
        self._row_s = (camera.row_readout_us or 0.0) * 1e-6
        self._tau_s = 0.0       # the last outline frame's mean point read time after its first row's, s
        self._read_travel = None  # (T, 3) m: the camera's travel to each target's centroid row (`_outline_targets`)
        self._fixtures: dict = {}  # LED id -> `_outline_fixture` (the map does not change during a run)
        self._prior_lights = None  # (ids, solving-frame positions, half sizes m) of `map_prior`
        self.last_reason: str | None = None  # why the last frame had no position (`_no_fix_reason`)
        self._ambiguous = False  # the frame's panel start gave poses that fit alike (`_panel_fix`)
        self.pose = PoseFilter(handedness=s.handedness or led_map.handedness,
                               sigma_uv=s.pixel_sigma_px / camera.focal_px, solver=s.solver, kalman=s.kalman,
                               accel_psd=s.accel_psd, max_coast_s=s.max_coast_s, tilt_sigma_deg=s.tilt_sigma_deg)

    def _outline_fixture(self, led_id: int):
        """(map LED, (hx, hy) half extents, (x, y, z) map m) of an LED the outline solve can fit
        (known shape and size, facing down, not S2-PSK), or None; looked up once per ID."""
        try:
            return self._fixtures[led_id]
        except KeyError:
            pass
        led = self.led_map.lookup(led_id)
        fx = None
        if led is not None and led.mode != "s2psk" and (led.normal is None or led.normal[2] <= -0.999):
            half = fixture_half_extents(led.shape, led.size)
            if half is not None:
                fx = (led, (float(half[0]), float(half[1])), (led.x, led.y, led.z))
        self._fixtures[led_id] = fx
        return fx

    def _outline_targets(self, t_s, leds, items, pred=None):
        """(`OutlineFrame` or None, item index or None per target) of the LEDs with measured edge
        points and a known shape and size (receiver.locate.outline_pose); LEDs cut by the image
        border (not in `items`) come with their edges only. The points are moved to the view of
        the frame's first row (`derotate_rows`, `detranslate_rows`) as far as the track knows the
        camera's motion; `pred`: the filter's prediction at t_s when the caller has it."""
        fixture = self._outline_fixture
        chosen = []
        for obs in leds:
            edges = obs.edge_px
            if edges is None or obs.id is None or obs.mode == "s2psk":
                continue
            fx = fixture(obs.id)
            if fx is None or len(edges[0]) < 6:
                continue
            chosen.append((obs, edges, fx))
        if not chosen:
            return None, []
        index = {id(o): i for i, (o, _, _) in enumerate(items)}
        where = [index.get(id(o)) for o, _, _ in chosen]
        packed = _pack_outline(chosen, EDGE_MODEL_SIGMA_PX, self.camera.focal_px)
        # One undistortion for every edge point and centroid of the frame.
        und = self._undistort(packed[0])
        w = self.pose.angular_rate(t_s) if self._row_s > 0 else None
        _, sig, ends, xyz, half = packed
        m = len(sig)
        if w is not None:
            # Every point to the instant of the frame's time stamp (its first row): one camera
            # orientation for the whole frame.
            und = derotate_rows(und, packed[0][:, 1], w, self._row_s, 0.0)
        L = self.pose.to_solving(xyz)
        travel = self._travel(t_s, pred) if self._row_s > 0 else None
        if travel is not None:
            # ... and one camera centre: the tracked one at the time stamp, from which each point
            # is seen where the moving camera read it.
            z = L[:, 2]
            moved = detranslate_rows(und, packed[0][:, 1], np.concatenate([np.repeat(z, np.diff(ends)), z]), *travel,
                                     self._row_s, 0.0)
            if not np.isfinite(moved).all():    # a ray that misses the ceiling plane: a track far off
                travel = None
            else:
                und = moved
                self._tau_s = 0.0
                # the camera's travel from the time stamp to each LED's centroid row, m
                self._read_travel = np.outer(packed[0][m:, 1] * self._row_s, travel[2])
        if travel is None:
            self._read_travel = None
            # The instant the points' position information stems from, after the frame's time
            # stamp (their weighted mean read time): `_at_frame_time` moves the fix back to it.
            wt = 1.0 / (sig * sig)
            self._tau_s = float(wt @ packed[0][:m, 1]) / float(wt.sum()) * self._row_s
        uv = und[m:]
        if None in where:
            uv = uv.copy()
            uv[[k for k, i in enumerate(where) if i is None]] = np.nan
        frame = OutlineFrame(und[:m], sig, ends, L, half, tuple(fx[0].shape for _, _, fx in chosen), uv)
        return frame, where

    def _travel(self, t_s, pred=None):
        """(R_cw, C, v) of `detranslate_rows` at t_s: the tracked orientation and the filter's
        predicted position and velocity (solving frame), or None while the track has none."""
        R = self.pose.R_prior(t_s)
        if R is None or self.pose.kf is None:
            return None
        if pred is None:
            pred = self.pose.kf.predict_at(t_s)
        if pred is None:
            return None
        x = pred[0].reshape(6)
        return R, x[:3], x[3:]

    def _solve_outline(self, targets, R0, C0, C_prior, C_cov):
        return solve_outline_pose(targets, R0, C0, focal_px=self.camera.focal_px, up_prior=_UP,
                                  tilt_sigma_rad=math.radians(self.settings.tilt_sigma_deg), C_prior=C_prior,
                                  C_prior_cov=C_cov, loss=DEFAULT_LOSS, f_scale=DEFAULT_F_SCALE)

    def _with_outline_ranges(self, ofix, targets, where, d, names):
        """The ranges of the fitted LEDs: their distances to the fitted camera centre (np.vecdot:
        each the number np.linalg.norm gives, in one call for the frame); with the points moved to
        the first row's view, from where the camera was when the LED's centroid row was read
        (`_read_travel`)."""
        d = np.array(d, float)
        names = list(names)
        D = targets.xyz - ofix.C
        if self._read_travel is not None and len(self._read_travel) == len(D):
            D = D - self._read_travel
        dist = np.sqrt(np.vecdot(D, D)).tolist()
        for k, i in enumerate(where):
            if i is not None:
                d[i] = dist[k]
                names[i] = "outline"
        return d, names

    def _outline_warm(self, t_s, leds, items, R_prior, pred=None):
        """Warm start: the outline solve from the tracked orientation and the filter's predicted
        position (`pred`, the filter's prediction at t_s when given), before (and instead of) the
        centroid solve. Returns (fix, d, names) when that
        fit passes `WARM_OUTLINE_CHI2_DOF`; else (None, (targets, where, the warm candidate or
        None)) for `_outline`, which then tries its other starts only."""
        if pred is None:
            pred = self.pose.kf.predict_at(t_s)
        targets, where = self._outline_targets(t_s, leds, items, pred)
        if targets is None:
            return None, (targets, where, None)
        C_prior = C_cov = None
        if targets.shapes == ("circle",):
            C_prior, C_cov = pred[0][:3], pred[1][:3, :3] + np.eye(3) * 1e-6
        cand = self._solve_outline(targets, R_prior, pred[0][:3], C_prior, C_cov)
        if cand is None or cand.chi2 / cand.dof > WARM_OUTLINE_CHI2_DOF:
            return None, (targets, where, cand)
        # Only the LEDs without a fitted outline need an envelope range.
        fitted = {i for i in where if i is not None}
        d, _, names = self.ranger.ranges(items, cand.R_cw if self.ranging == "oblique" else R_prior, skip=fitted)
        d, names = self._with_outline_ranges(cand, targets, where, d, names)
        return (cand, d, names), None

    def _outline(self, t_s, leds, items, fix, d, names, R_prior, warm=None):
        """The frame's fix and ranges refined on the LEDs' outlines (`PositionerSettings.outline`),
        or the given ones when no outline is usable. `warm`: (targets, where, candidate) of a
        failed warm start (`_outline_warm`), whose start is not tried again."""
        targets, where = self._outline_targets(t_s, leds, items) if warm is None else warm[:2]
        if targets is None:
            return fix, d, names
        # Starting poses: this frame's centroid fix, else (or when the outlines reject it: with
        # 2 LEDs and a tilted phone the tilt prior can put it on the wrong branch) the tracked
        # orientation with this frame's range or the tracked position.
        starts = []
        if fix is not None and fix.R_cw is not None:
            starts.append((fix.R_cw, fix.C))
        if R_prior is not None:
            k = next((j for j, i in enumerate(where) if i is not None and math.isfinite(d[i])), None)
            if k is not None:
                starts.append((R_prior, targets.xyz[k] - d[where[k]] * (R_prior.T @ ray_unit(targets.uv[k]))))
            pred = self.pose.kf.predict_at(t_s) if self.pose.kf is not None else None
            if pred is not None and warm is None:
                starts.append((R_prior, pred[0][:3]))
        ofix = warm[2] if warm is not None else None
        C_prior = C_cov = None
        if targets.shapes == ("circle",):
            pred = self.pose.kf.predict_at(t_s) if self.pose.kf is not None else None
            if pred is None:
                return fix, d, names
            C_prior, C_cov = pred[0][:3], pred[1][:3, :3] + np.eye(3) * 1e-6
        for R0, C0 in starts:
            cand = self._solve_outline(targets, R0, C0, C_prior, C_cov)
            if cand is not None and (ofix is None or cand.chi2 / cand.dof < ofix.chi2 / ofix.dof):
                ofix = cand
            if ofix is not None and ofix.chi2 / ofix.dof <= GOOD_OUTLINE_CHI2_DOF:
                break
        if (ofix is None or ofix.chi2 / ofix.dof > WARM_OUTLINE_CHI2_DOF) and C_prior is None:
            # No start explains the frame (or there was none: no track, fewer than two whole
            # LEDs for a centroid fix): start again from the panels themselves.
            cold = self._panel_fix(targets, R_prior, t_s)
            if cold is not None and (ofix is None or cold.chi2 / cold.dof < ofix.chi2 / ofix.dof):
                ofix = cold
        if ofix is None and fix is not None and targets.n_points >= MIN_VETO_POINTS:
            # The frame's own outlines contradict the centroid fix from every start: no fix
            # (the filter coasts) rather than a confident wrong one.
            return None, d, names
        if ofix is None:
            return fix, d, names
        d, names = self._with_outline_ranges(ofix, targets, where, d, names)
        return ofix, d, names

    def _panel_fix(self, targets, R_prior, t_s=None):
        """The outline fix from the panels alone (`panel_start_poses`): the best of the solves
        from every start, or None when another pose more than `AMBIGUOUS_M` away fits nearly as
        well (within `AMBIGUOUS_CHI2_RATIO`: a lone square seen from any of its four sides). With
        a tracked orientation (of `PoseFilter.R_prior`, at frame time `t_s`) only the starts
        within `TRACKED_TURN_DEG` + `TURN_RATE_DEG_S` x its age of it are tried."""
        starts = panel_start_poses(targets, self.camera.focal_px)
        if R_prior is not None:
            age = (self.pose.orientation_age_s(t_s) if t_s is not None else None) or 0.0
            cos_max = math.cos(math.radians(min(180.0, TRACKED_TURN_DEG + TURN_RATE_DEG_S * max(age, 0.0))))
            starts = [(R, C) for R, C in starts if (np.trace(R @ R_prior.T) - 1) / 2 >= cos_max]
        fits = []
        for R0, C0 in starts:
            if any(np.linalg.norm(C0 - f.C) < START_MERGE_M for f in fits):
                continue        # a start next to a pose already solved lands on it
            cand = self._polished(targets, self._solve_outline(targets, R0, C0, None, None))
            if cand is not None and all(np.linalg.norm(cand.C - f.C) > START_MERGE_M for f in fits):
                fits.append(cand)
        if not fits:
            return None
        fits.sort(key=lambda f: f.chi2 / f.dof)
        best = fits[0]
        for other in fits[1:]:
            if (np.linalg.norm(other.C - best.C) > AMBIGUOUS_M
                    and other.chi2 / other.dof < AMBIGUOUS_CHI2_RATIO * max(best.chi2 / best.dof, 1.0)):
                self._ambiguous = True
                return None
        return best

    def _polished(self, targets, fix):
        """`fix` solved again from itself while that lowers its chi^2 per dof by more than
        `POLISH_GAIN` (at most `POLISH_SOLVES` times). A panel start is far from its branch's
        optimum, and one solve may stop short of it: the ambiguity test of `_panel_fix` must
        compare the branches' optima, or a lone small panel seen nearly square-on, whose
        tilted-and-shifted branches fit equally well, yields whichever branch happened to
        converge (a first fix 0.8-1.2 m off, which the track then followed)."""
        for _ in range(POLISH_SOLVES if fix is not None else 0):
            again = self._solve_outline(targets, fix.R_cw, fix.C, None, None)
            if again is None or again.chi2 / again.dof >= (1.0 - POLISH_GAIN) * fix.chi2 / fix.dof:
                break
            fix = again
        return fix

    def _at_frame_time(self, fix):
        """An outline fix moved from its points' mean read time to the frame's time stamp (the
        instant its first row is read, the `t` the position is reported at) with the tracked
        velocity (the orientation is there already: `derotate_rows`)."""
        if fix is None or fix.method != "outline" or not self._row_s or self.pose.kf is None:
            return fix
        state = self.pose.kf.state
        if state is None or not self._tau_s:
            return fix
        return dataclasses.replace(fix, C=fix.C - self._tau_s * state[0].reshape(6)[3:])

    def map_prior(self, t_s: float) -> map_prior.MapPrior | None:
        """Where the map's lights should appear in the frame stamped `t_s` (`receiver.locate.map_prior`),
        from the filter's prediction and the last fix's orientation turned on by the tracked rate;
        None without a tracked pose (or with the handedness still undecided)."""
        pose = self.pose
        R = pose.R_prior(t_s)
        if R is None or pose.kf is None or pose.handedness_source == "default":
            return None
        pred = pose.kf.predict_at(t_s)
        if pred is None:
            return None
        age = pose.orientation_age_s(t_s) or 0.0
        w = pose.angular_rate(t_s)
        if w is not None and age > 0:
            R = cv2.Rodrigues(np.asarray(w, float) * age)[0] @ R
        if self._prior_lights is None:
            leds = [led for led in self.led_map.leds.values() if led.mode != "s2psk"]
            half = [max(fixture_half_extents(led.shape, led.size) or (0.0, 0.0)) for led in leds]
            self._prior_lights = (np.array([led.id for led in leds], np.int64),
                                  pose.to_solving(np.array([led.xyz for led in leds]).reshape(-1, 3)),
                                  np.array(half, float))
        ids, L, half = self._prior_lights
        if not len(ids):
            return None
        return map_prior.predict(self.camera, ids, L, half, R, pred[0][:3], pred[1][:3, :3],
                                 map_prior.orient_sigma_rad(age), t_s)

    @property
    def unknown_ids(self) -> set[int]:
        """Decoded IDs the map does not know (counted by the ranger)."""
        return self.ranger.unknown_ids

    @property
    def n_fixes(self) -> int:
        return self.pose.n_fixes

    def _no_fix_reason(self, leds, items) -> str:
        """Why this frame gave no position (`last_reason`), in a few words."""
        indoor = [o for o in leds if o.mode != "s2psk"]
        if not indoor:
            return "no LED seen"
        decoded = [o for o in indoor if o.id is not None]
        if not decoded:
            return "no decoded ID"
        if not items:
            known = [o for o in decoded if self.led_map.lookup(o.id) is not None]
            return "LEDs cut by image edge" if known else "ID not in map"
        if self.pose.handedness_undecided and self.pose.handedness_source == "default":
            return "handedness undecided"
        if self._ambiguous:
            # e.g. one square panel without a tracked orientation: it fits from any of its sides
            return "panel pose ambiguous"
        if len(items) < 3:
            return "too few LEDs"
        return "solver rejected"

    def _result(self, t_s: float, fix, leds, items, d, names) -> LocateResult:
        position = self.pose.update(t_s, fix, len(items))
        # A few words on a frame without a position (None with one): receiver.cli.run's "no_fix".
        self.last_reason = None if position is not None else self._no_fix_reason(leds, items)
        return LocateResult(position=position, leds=self.ranger.annotate(leds, items, d, names))

    def step(self, t_s: float, leds: list[LedObservation]) -> LocateResult:
        self._ambiguous = False
        items = self.ranger.usable(leds)
        R_prior = self.pose.R_prior(t_s)
        outline = self.settings.outline and not self.pose.mirrored
        warm = pred = None
        if outline and R_prior is not None and self.pose.kf is not None and self.pose.handedness_source != "default":
            pred = self.pose.kf.predict_at(t_s)
        if pred is not None:
            # Tracking: the outlines from the last pose first; the centroid solve only when that fails.
            done, warm = self._outline_warm(t_s, leds, items, R_prior, pred)
            if done is not None:
                fix, d, names = done
                fix = self._at_frame_time(fix)
                return self._result(t_s, fix, leds, items, d, names)
        d, sd, names = self.ranger.ranges(items, R_prior)
        fix = None
        if items:
            L = np.array([led.xyz for _, led, _ in items])
            uv = self.ranger.image_points(items)
            fix = self.pose.solve(t_s, L, uv, d, sd, R_prior)
            n_iter = RANGES_ONLY_ITERATIONS if self.solver == "multilateration" else RANGING_ITERATIONS
            for _ in range(n_iter if self.ranging == "oblique" else 0):
                if fix is None:
                    break
                # Foreshortening with this frame's own orientation, then solve again. Ranges-only
                # fixes carry no orientation: align the camera rays with the LED directions.
                R = fix.R_cw
                if R is not None:
                    d, sd, names = self.ranger.ranges(items, R)
                else:
                    # Tilt error and range error feed each other back here with a gain of about
                    # -2/3 (ceiling LEDs), so the plain loop oscillates; averaging old and new
                    # ranges damps the loop gain to about 1/6.
                    R = align_rays(ray_unit(uv), self.pose.to_solving(L) - fix.C)
                    d_new, sd, names = self.ranger.ranges(items, R)
                    d = np.where(np.isfinite(d), 0.5 * (d + d_new), d_new)
                fix = self.pose.solve(t_s, L, uv, d, sd, R) or fix
            if fix is not None and fix.R_cw is not None and self.ranging == "oblique":
                # The reported distances use this frame's own orientation (cheap: no new solve).
                d, sd, names = self.ranger.ranges(items, fix.R_cw)
        if outline:
            fix, d, names = self._outline(t_s, leds, items, fix, d, names, R_prior, warm)
            fix = self._at_frame_time(fix)
        return self._result(t_s, fix, leds, items, d, names)
