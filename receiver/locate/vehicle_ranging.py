"""Ranging of S2-PSK pairs for the vehicle locator (receiver.locate.vehicle, whose module doc
gives the estimators): per-pair scalar math (`range_core`), saturated areas dropped
(`_drop_clipped_areas`), and `PairRanging`, the locator's part that gathers a frame's pairs,
their emitter centroids and the map's geometry and ranges them."""

from __future__ import annotations

import math

import cv2
import numpy as np

from receiver.core.records import PairObservation
from receiver.io.camera import CameraModel
from receiver.locate.pose import ypr_to_rotation
from receiver.locate.settings import VehicleSettings

ESTIMATORS = ("eq18", "oblique", "baseline", "fused")
DOWN = np.array([0.0, 0.0, -1.0])
# Model constants of ranging (what the model assumes, not what a user sets), unit and why.
CENTROID_SIGMA_PX = 0.2         # px, 1-sigma of a street-light emitter's centroid (sub-pixel envelope)
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
# The range a saturated pair's bloomed areas may read, relative to its baseline range: bloom only
# grows a blob (at most the true range, 1.25: the envelope's edge noise) and by 2-3x, up to 4x
# on a small far one (at least half the true range). A street-light head's halves taken for
# taillights read 0.2-0.4 of their baseline range.
SATURATED_AREA_SPAN = (0.5, 1.25)


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
    area_model_rel: scalars or (N,) (default: `CENTROID_SIGMA_PX`, `AREA_MODEL_REL`). Returns a dict of length-N lists
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
    csig = CENTROID_SIGMA_PX if centroid_sigma_px is None else centroid_sigma_px
    cols = [_floats(v, n) for v in (ja, jb, eta_a, eta_b, area_m2, orient_sigma_rad, base_model_rel, amr, csig,
                                    ua, ub, S1, S2, B_cam, n_cam)]
    cols += [circle.tolist() if isinstance(circle, np.ndarray) else list(circle), R2[:n], R2[n:], cos3[:n], cos3[n:]]
    off, esig, cons = s.edge_offset_px, EDGE_SIGMA_PX, CONSISTENCY_SIGMAS
    keys = ("eq18", "eq18_sigma", "oblique", "oblique_sigma", "baseline", "baseline_sigma", "fused", "fused_sigma",
            "d_a", "d_b", "s_a", "s_b", "flip", "base_fused_only", "area_clash")
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


class PairRanging:
    """The locator's ranging of a frame's pairs (a mixin of `VehicleLocator`, whose state it
    reads: the camera, the map's per-light constants `_sl`, `_tl`, the fitted tilt)."""

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
