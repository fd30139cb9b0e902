"""Cars ahead for the vehicle locator (receiver.locate.vehicle, whose module doc gives the
method): a range track per taillight pair, bearing every frame (thesis eq. 52), the road
position (eq. 53), the tests that tell an undecoded pair from taillights, the Figure 27 zones.
`CarsAhead` is the locator's part that does it."""

from __future__ import annotations

import math

import cv2
import numpy as np

from receiver.core.records import PairObservation
from receiver.locate.road_kalman import RangeKalman
from receiver.locate.vehicle_ranging import SATURATED_AREA_SPAN, _r, _rays, fv_measured

# Model constants of the cars ahead (what the model assumes, not what a user sets), unit and why.
FV_ACCEL_PSD = 4.0              # m^2/s^3, relative acceleration of a car ahead
FV_MIN_HEIGHT_M = 0.0           # m, an undecoded pair is taken for taillights only this high or higher (the road)
FV_DROP_S = 1.0                 # s, a car unseen this long is forgotten
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
# An undecoded pair ranged as taillights beyond this (m) is taken for no car: thesis Table 2's
# detection range ends at 150 m, and a far street-light head's halves (0.6 m apart) taken for
# taillights (1.4 m) read 2.3x their range, 200-250 m, with areas too small to tell them apart.
UNDECODED_FV_MAX_RANGE_M = 150.0
ZONES = ("safe", "min", "critical")


class CarsAhead:
    """The locator's cars ahead (a mixin of `VehicleLocator`: `fv_tracks`, the road filter's
    turn rate, the last solved orientation)."""

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
                        if not FV_MIN_HEIGHT_M <= z <= s.fv_max_height_m:
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
        for key in [k for k, tr in self.fv_tracks.items() if k not in seen and t_s - tr["kf"].t_meas > FV_DROP_S]:
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
