"""Host-vehicle placement for the vehicle locator (receiver.locate.vehicle, whose module doc
gives the method): the camera pose from decoded street lights (`_solve_pose`; thesis eqs.
44-47 beside it), a single light's start and updates, the map's road direction, the road
filter's start and speed. `HostPlacement` is the locator's part that does it."""

from __future__ import annotations

import math

import cv2
import numpy as np

from receiver.core.native import require
from receiver.locate.lsq import LM_FTOL, LM_LAMBDA0, LM_LAMBDA_MAX, covariance_at
from receiver.locate.pose import rotation_to_ypr_deg, ypr_to_rotation
from receiver.locate.road_kalman import wrap_pi

from receiver.locate.vehicle_ranging import (CENTROID_SIGMA_PX, NAN, ORIENT_SIGMA_PRIOR_DEG, SL_SEPARATION_SIGMA_PX,
                                             SQRT2, _r, _rays)

# Model constants of host placement (what the model assumes, not what a user sets), unit and why.
CAMERA_HEIGHT_SIGMA_M = 0.3     # m, the camera height prior's 1-sigma (load, suspension, mount)
YAW_SHAKE_SIGMA_DEG = 0.3       # deg, camera yaw about the host heading (mount, shake ~0.3 deg rms)
PITCH_SIGMA_DEG = 0.5           # deg, camera pitch about the last solved one (shake, braking)
ROLL_SIGMA_DEG = 1.0            # deg, camera roll about 0 (mount, body roll)
ROAD_HEADING_SIGMA_DEG = 3.0    # deg, host heading about the map's road direction (lane changes)
MAX_COAST_S = 2.0               # s, the host track is forgotten after this long without a fix
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
# m, a road filter whose predicted 2D position std exceeds this is no prior for associating
# undecoded heads nor for a `POSE_TRACK_ITER` warm start: the decoded heads get a full solve
# from its prediction with a cold solve's checks (`off_road`, `_reprojects`), and a fix from them
# updates the filter, or restarts it when the gate rejects it (the heads are trusted over a
# prediction this unsure); without a fix it coasts until `MAX_COAST_S` after its last one. Past
# the single-light update limit only a pose solve can correct it, and at this std a 99.9 % gate
# (3.7 sigma) reaches about half the 12.5 m spacing of staggered heads: a short warm start or an
# association could take a neighbouring head.
MAX_TRACK_STD_M = SL1_MAX_STD_M
SPEED_INIT_MIN_DT_S = 0.12      # s, the first two fixes this far apart give the speed (one frame apart, fix noise dominates)
SPEED_HIST_S = 0.3              # s, the heads' image growth over this long gives the speed at a start without odometry
SPEED_HIST_MIN = 5              # ... from at least this many separations
SPEED_MOTION_FLOOR_MPS = 1.0    # m/s, ... its sigma at least this
OBS_GATE_CHI2 = 16.3            # one light's (u, v, range) into the filter: chi-square 3 dof, 99.9 %
# Mapped heads that give the road direction near a light (`_road_heading`): two or three a side
# of the road, whatever their spacing (a staggered layout's 12.5 m, an alternating one's 30 m).
ROAD_HEADS = 6
# deg, a cold pose solve whose heading is farther than this from the map's road line near its
# heads is a wrong one (heads confused or a degenerate geometry): the host drives along the road.
ROAD_OFF_MAX_DEG = 45.0
# A cold pose solve (no road filter yet, or one too unsure to be a prior) is a fix only if it puts every decoded head's midpoint
# where the image shows it (`_reprojects`): Mahalanobis^2 per head within this (chi-square 2 dof,
# 99.9 %). Ranges alone fit the camera mirrored across the heads' line as well as the true one
# (thesis eqs. 44-47's two sides); the robust loss can settle there with the angles as outliers.
REPROJ_GATE_CHI2 = 13.8
# Why the host is unplaced, by what the frame holds (`VehicleLocator.hv_reason`).
NO_LIGHT = "no light in view"
NOT_DECODED = "lights in view, not decoded yet"
ONE_LIGHT = "one street light decoded, waiting for a second"
REPROJ_FAILED = "street-light pose solve failed (it does not reproject the decoded heads)"


_k = require("receiver.locate._vehicle_pose")     # the pose solve's one implementation
_W_CACHE: dict = {}


def _prior_whitening(cov: np.ndarray) -> np.ndarray:
    """W with W^T W = cov^-1, kept per covariance."""
    key = cov.tobytes()
    W = _W_CACHE.get(key)
    if W is None:
        W = _W_CACHE[key] = np.ascontiguousarray(np.linalg.cholesky(np.linalg.inv(cov)).T)
    return W


def _solve_native(L, uv, sigma_uv, d, sd, up, up_sigma, C_prior, W, n_pairs, sep_gain, attitude, p0, max_iter):
    """The host pose by the compiled soft-L1 Levenberg-Marquardt (receiver.locate._vehicle_pose,
    whose module doc lists the residual rows): the angles of the M points L (M, 3) seen at uv
    (M, 2, normalized; each of the first `n_pairs` pairs as its midpoint and its centroid
    difference times `sep_gain`), the finite ranges d (sigma sd), the tilt prior (world up
    `up`, sigma `up_sigma`), the position prior C_prior whitened by W (`_prior_whitening`) and
    `attitude`'s rows: {"yaw"|"pitch"|"roll": (rad, sigma rad), "mid_range": (M (3,), D m,
    sigma m)}. With a single street light the image fixes the camera on a circle around the
    head: the heading prior picks the point (lateral sigma ~ range x sigma), the roll and pitch
    priors keep the two emitters' slant from turning the camera, and the head's midpoint range
    stands in for its two emitters' own (noisy) area ranges, whose difference would turn the
    camera (the bundled recording: yaw 3-5 deg off). From p0 (Rodrigues vector, C) for at most
    `max_iter` steps, stopping once a step turns the camera by less than `POSE_ROT_TOL_RAD` and
    moves it by less than `POSE_POS_TOL_M`. Returns (x, r, J, R, cov6, status) at the solution
    (status: `solve_pose`'s; 0 = a fix)."""
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


class HostPlacement:
    """The locator's host placement (a mixin of `VehicleLocator`, whose state it reads and
    keeps: the road filter `kf`, the last solved orientation and height, `hv_reason`)."""

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
        """Robust joint solve over the SL emitters (module doc; `_solve_native`) from (R0, C0).
        Returns (R, C, cov3) or None. `attitude`: {"yaw"|"pitch"|"roll": (rad, sigma rad),
        "mid_range": (M, D, sigma)} priors, rows of their own (the single-light solve, whose yaw
        the image leaves free); `emitter_ranges` False: no emitter range rows."""
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
        x, r, J, R, cov6, status = _solve_native(L, uv, CENTROID_SIGMA_PX / self.focal, np.array(ds), np.array(sds),
                                                 self._up, math.radians(TILT_SIGMA_DEG), C_prior, self._W, m,
                                                 self._sep_gain, attitude, p0, n_iter)
        if status == 3:
            # J' J not positive definite: the covariance by the pseudo-inverse decides.
            with np.errstate(over="ignore", invalid="ignore"):
                cov = covariance_at(r, J, J.shape[1])[0][3:5, 3:5]
            if not np.all(np.isfinite(cov)):
                return None     # residuals overflowed (absurd centroids): no fix, not an infinite sigma
            return cv2.Rodrigues(x[:3].reshape(3, 1))[0], x[3:].copy(), cov
        if status:
            return None
        self._rvec_of = (R, x[:3].copy())
        return R, x[3:].copy(), cov6[3:5, 3:5]

    def _reprojects(self, pairs, res, sl_k, R: np.ndarray, C: np.ndarray) -> bool:
        """Whether the camera (R_cw, C) puts each decoded head k of `sl_k` where it is seen: the
        mapped head (its emitters' mean) projected against the measured midpoint of its two
        emitters (normalized, undistorted), within their uncertainty: the midpoint's
        (`CENTROID_SIGMA_PX` / sqrt 2 per axis) and the head's model error `FIX_FLOOR_M` seen
        at its distance. Mahalanobis^2 per head at most `REPROJ_GATE_CHI2`; a head behind the
        camera fails."""
        csig2 = 0.5 * (CENTROID_SIGMA_PX / self.focal) ** 2
        for k in sl_k:
            X = R @ (self._sl[pairs[res["idx"][k]].led_id]["head"] - C)
            z = float(X[2])
            if not z > 0.0:
                return False
            ex = float(X[0]) / z - 0.5 * float(res["ua"][k][0] + res["ub"][k][0])
            ey = float(X[1]) / z - 0.5 * float(res["ua"][k][1] + res["ub"][k][1])
            sig2 = csig2 + FIX_FLOOR_M ** 2 / float(X @ X)
            if not (ex * ex + ey * ey) / sig2 <= REPROJ_GATE_CHI2:
                return False
        return True

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

    def off_road(self, yaw_rad: float, head: np.ndarray) -> bool:
        """Whether heading `yaw_rad` (map frame) is more than `ROAD_OFF_MAX_DEG` off the map's road
        line near `head` (either way along it); False when the map gives no road direction."""
        road = self._road_heading(head)
        if road is None:
            return False
        d = abs(wrap_pi(yaw_rad - road))
        return min(d, math.pi - d) > math.radians(ROAD_OFF_MAX_DEG)

    def _single_observation(self, t_s, pairs, res, k, R_prior):
        """While the road filter runs, one decoded street light updates it directly: the
        measurement is the head's undistorted midpoint (u, v, normalized) and its "fused" range
        (m), predicted from the filter's (x, y, heading) with the camera at the last solved
        height and pitch (`pitch_ref` when a full pose gave one), roll 0 and yaw = heading. What
        those assumptions leave out is folded into the noise through the measurement's
        Jacobian on each: the camera's yaw about the heading (`YAW_SHAKE_SIGMA_DEG`), pitch
        (`PITCH_SIGMA_DEG`, else `ORIENT_SIGMA_PRIOR_DEG`), roll (`ROLL_SIGMA_DEG`) and height
        (`CAMERA_HEIGHT_SIGMA_M`); the midpoint carries the centroids' sigma
        (`CENTROID_SIGMA_PX` / sqrt 2 per axis). A pose fix would need the heading prior from
        this same filter, and its position fed back would count that prior twice. Returns the
        fix record for `_update_hv` ("sl-1", n 1)."""
        head = self._sl[pairs[res["idx"][k]].led_id]["head"]
        z0 = self.z_last
        pitch0 = rotation_to_ypr_deg(R_prior)[1] if self.pitch_ref is None else math.degrees(self.pitch_ref)
        psig = math.radians(PITCH_SIGMA_DEG if self.pitch_ref is not None else ORIENT_SIGMA_PRIOR_DEG)

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
        sm = CENTROID_SIGMA_PX / SQRT2 / self.focal
        d = float(res["fused"][k])
        Rm = np.diag([sm * sm, sm * sm, res["fused_sigma"][k] ** 2 + (SL1_RANGE_FLOOR_REL * d) ** 2])
        for j, (sig, e) in enumerate(((math.radians(YAW_SHAKE_SIGMA_DEG), 1e-5), (psig, 1e-5),
                                      (math.radians(ROLL_SIGMA_DEG), 1e-5), (CAMERA_HEIGHT_SIGMA_M, 1e-3))):
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
        `YAW_SHAKE_SIGMA_DEG`), else the map's road direction near the light
        (`ROAD_HEADING_SIGMA_DEG`). Returns (fix | None, aligned, res); the fix's covariance is
        the solve's (lateral ~ range x heading sigma). Its yaw is the prior's echo, so the
        filter takes the position only (`fix["yaw_free"]`)."""
        s = self.s
        head = self._sl[pairs[res["idx"][k]].led_id]["head"]
        if R_prior is not None:
            pred, P = self.kf.predict_at(t_s)
            yaw0 = float(pred[2])
            ysig = math.sqrt(max(float(P[2, 2]), 0.0) + math.radians(YAW_SHAKE_SIGMA_DEG) ** 2)
            pitch = rotation_to_ypr_deg(R_prior)[1] if self.pitch_ref is None else math.degrees(self.pitch_ref)
            R0 = ypr_to_rotation(math.degrees(yaw0), pitch, 0.0)
            C0 = np.array([pred[0], pred[1], self.z_last])
        else:
            yaw0 = self._road_heading(head)
            if yaw0 is None:
                self.hv_reason = f"{ONE_LIGHT} (the map gives no road direction near it)"
                return None, aligned, res
            ysig = math.radians(ROAD_HEADING_SIGMA_DEG)
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
        att = {"yaw": (yaw0, ysig), "roll": (0.0, math.radians(ROLL_SIGMA_DEG)),
               "mid_range": (head, float(res["fused"][k]), float(res["fused_sigma"][k]))}
        if self.pitch_ref is not None:
            att["pitch"] = (self.pitch_ref, math.radians(PITCH_SIGMA_DEG))
        solved = self._solve_pose(pairs, res, [k], R0, C0, attitude=att, emitter_ranges=False)
        if solved is None:
            self.hv_reason = "street-light pose solve failed"
            return None, aligned, res
        R, C, cov = solved
        if R_prior is None and not self._reprojects(pairs, res, [k], R, C):
            self.hv_reason = REPROJ_FAILED
            return None, aligned, res
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
        c = CENTROID_SIGMA_PX
        return SQRT2 * c / math.sqrt(2 * c * c + SL_SEPARATION_SIGMA_PX ** 2)

    def _pose_ranges(self, pairs, ranges, fix):
        """SL pairs with mapped emitters: the distance from the frame's solved camera centre to
        the head (estimator "pose"; its sigma from the pose covariance along the line of
        sight). Far more exact than either image measurement of a small, foreshortened head."""
        (cx, cy, cz), ((c00, c01), (c10, c11)) = fix["pose"][0].tolist(), fix["pose"][1].tolist()
        hs = CAMERA_HEIGHT_SIGMA_M
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
                psig = math.radians(ROAD_HEADING_SIGMA_DEG)
            if not kf.started:
                accepted = self._start(t_s, xy, cov, yaw, psig, speed, fix)
            else:
                kf.predict(t_s)
                held = self._speed_from_fixes(t_s, xy, cov) if speed is None else False
                accepted = kf.update_fix(t_s, xy, cov, None if fix.get("yaw_free") else yaw, psig,
                                         held_speed=held)
                if not accepted and (fix.get("over_unsure") or kf.rejects >= MAX_REJECTS):
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
