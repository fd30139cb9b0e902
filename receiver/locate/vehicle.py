"""Vehicle positioning from S2-PSK pairs (thesis chapter 5.3): the host vehicle (HV) placed from
street lights (SL), forward vehicles (FV) located from their taillights.

`VehicleLocator` (here: its state, each pair's role, the frame's step) composes one part per
concern: pair ranging (`vehicle_ranging.PairRanging`), host placement
(`vehicle_host.HostPlacement`), map-aided association (`vehicle_assoc.MapAssociation`) and the
cars ahead (`vehicle_cars.CarsAhead`); each file holds its model constants. What a user sets is
`VehicleSettings` (receiver.locate.settings); user documentation: docs/vehicle-locator.md.

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
* A filter whose predicted 2D position std exceeds `MAX_TRACK_STD_M` is no prior for the
  map-aided association nor a few-iteration warm start: its decoded heads get a full solve from
  its prediction with a cold solve's checks (heading along the road, reprojection; a single
  light: `_single_fix`), and such a fix updates the filter or, when its gate rejects it,
  restarts it. The filter is forgotten `MAX_COAST_S` after its last fix.
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
midpoint, ranged as a taillight pair, lies between `FV_MIN_HEIGHT_M` and `fv_max_height_m`
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
Python (numpy's per-call overhead would dominate small arrays); the host's pose solve is compiled
(receiver.locate._vehicle_pose, its one implementation; docs/kernels.md).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from receiver.core.records import PairObservation
from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap, shape_area_m2
from receiver.locate.road_kalman import RoadKalman
from receiver.locate.settings import VehicleSettings
from receiver.locate.vehicle_assoc import MapAssociation
from receiver.locate.vehicle_cars import CarsAhead, ZONES, FV_CONFIRM_S, FV_SL_GATE_DEG  # noqa: F401 (re-exported)
from receiver.locate.vehicle_host import (ACCEL_PSD, GATE_CHI2, INIT_OMEGA_SIGMA_RPS, INIT_SPEED_SIGMA_MPS,
                                          MAX_REJECTS, MIN_LIGHTS, NO_LIGHT, NOT_DECODED, ONE_LIGHT,  # noqa: F401
                                          MAX_COAST_S, MAX_TRACK_STD_M, POSE_TRACK_ITER, REPROJ_FAILED, SPEED_HIST_S, YAW_ACCEL_PSD, HostPlacement,
                                          eq44_47)  # noqa: F401 (re-exported)
from receiver.locate.vehicle_ranging import (CENTROID_SIGMA_PX, DOWN, ESTIMATORS, SL_SEPARATION_SIGMA_PX, PairRanging, _pick,  # noqa: F401
                                             _r, _rays, _sides, fv_measured, level_rotation, nominal_rotation)
from receiver.locate.pose import rotation_to_ypr_deg, ypr_to_rotation


@dataclass(frozen=True)
class VehicleResult:
    """`vehicle`: INTERFACES.md vehicle object {"hv": {...} | None, "fv": [...]}, or None when no
    pair is in view and no HV track is kept. `ranges`: aligned with the input pairs, each
    (distance_m, sigma_m, estimator) or None."""

    vehicle: dict | None
    ranges: tuple = field(default_factory=tuple)


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


class VehicleLocator(PairRanging, HostPlacement, MapAssociation, CarsAhead):
    """Streaming vehicle positioning (module doc). `hv_reason`: why the HV is not placed
    (None when it is); `fv_reason`: why taillight pairs are not ranged (None when they are, or
    no pair other than a decoded street light was seen)."""

    def __init__(self, camera: CameraModel, led_map: LedMap, settings: VehicleSettings = VehicleSettings()):
        self.camera = camera
        self.map = led_map
        self.s = settings
        self.focal = camera.focal_px
        # Per-emitter centroid sigma whose sqrt(2) multiple is a head's separation sigma
        # (`SL_SEPARATION_SIGMA_PX` with the two centroids' own `CENTROID_SIGMA_PX`).
        self._sl_csig = math.sqrt(CENTROID_SIGMA_PX ** 2 + 0.5 * SL_SEPARATION_SIGMA_PX ** 2)
        self.R_nominal = nominal_rotation(settings)
        self._up = np.ascontiguousarray(self.R_nominal[:, 2])      # world up seen by the nominal camera
        self._W: np.ndarray | None = None                          # the pose's position-prior whitening
        self._rvec_of = (None, None)             # (R, its Rodrigues vector) of the last compiled solve
        self.kf = RoadKalman(accel_psd=ACCEL_PSD, yaw_accel_psd=YAW_ACCEL_PSD,
                             init_speed_sigma=INIT_SPEED_SIGMA_MPS,
                             init_omega_sigma=INIT_OMEGA_SIGMA_RPS,
                             gate_chi2=GATE_CHI2, max_rejects=MAX_REJECTS,
                             max_coast_s=MAX_COAST_S)
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
        # A track this unsure is no prior for association nor a few-iteration warm start: its
        # heads get a full solve from its prediction and a cold solve's checks, and a fix from
        # them updates the filter, or restarts it if gated out.
        unsure = tracked and self.kf.position_std_m(t_s) > MAX_TRACK_STD_M
        R_prior = self.R_last if tracked else None
        cold = R_prior is None or unsure
        given = pairs
        assoc = self._associate(t_s, pairs, R_prior) if not cold else {}
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
            elif len(sl_k) < MIN_LIGHTS and not cold:
                fix = self._single_observation(t_s, pairs, res, sl_k[0], R_prior)
            elif len(sl_k) < MIN_LIGHTS:
                fix, aligned, res = self._single_fix(t_s, pairs, aligned, res, sl_k[0], None)
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
                    pairs, res, sl_k, *init, max_iter=None if cold else POSE_TRACK_ITER)
                if solved is None:
                    self.hv_reason = "street-light pose solve failed"
                else:
                    R, C, cov = solved
                    if R_prior is None:
                        # Final ranges with the solved pose. While tracking, the ranges taken with
                        # the previous frame's orientation stand (one frame of rotation: negligible).
                        aligned, res = self._range_pairs(pairs, R, True)
                    yaw = math.radians(self._ypr_of(R)[0])
                if solved is not None and cold and self.off_road(
                        yaw, self._sl[pairs[res["idx"][sl_k[0]]].led_id]["head"]):
                    self.hv_reason = "street-light pose solve failed (its heading is off the road)"
                elif solved is not None and cold and not self._reprojects(pairs, res, sl_k, R, C):
                    self.hv_reason = REPROJ_FAILED
                elif solved is not None:
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
            fix["over_unsure"] = unsure
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


def zone_for(d: float, v_hv: float | None, ttc: float | None,
             settings: VehicleSettings = VehicleSettings()) -> str:
    """The Figure 27 zone of a forward vehicle at d m, HV speed v_hv (m/s or None), ttc (s or None)."""
    loc = VehicleLocator.__new__(VehicleLocator)
    loc.s = settings
    return loc._zone(d, v_hv, ttc)
