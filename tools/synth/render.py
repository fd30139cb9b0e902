"""Frame renderer: the scene's lights through the camera model into 8-bit gray frames.

Per frame k (start time ``t_k = k / fps + jitter``):

1. Background: every pixel is an independent draw of ``black + ambient + noise`` (thesis
   eq. 4 with S = ambient), quantised and clamped to 0..255. Because the quantised
   background takes one value almost everywhere, it is drawn exactly but sparsely: the
   pixels that differ from the most likely value form a Bernoulli process, sampled by
   geometric gaps; only those pixels are touched.
2. Each light whose centre is in front of the camera and near the field of view: its
   emitters' outlines are projected (perspective + lens distortion) with the camera and
   carrier poses at the light's own exposure time, ``t_k + cy * t_row + t_exp / 2``
   (so rolling-shutter skew of moving scenes is reproduced, to first order). The outline
   polygon's anti-aliased coverage (`tools.synth.raster`) times the row's exposure mean of
   the firmware waveform (`tools.synth.waveform`) times the radiance gives the signal.
   Radiance: thesis eq. 10 gives the received power ``P_r ~ I(0) cos^m(phi) cos(psi) / d^2``
   with the Lambertian pattern of eq. 1 (order m, eq. 8); spread over the LED's image area,
   which grows as ``cos(phi) / (d^2 cos^3(psi))``, this is a per-pixel level
   ``led_peak_dn * brightness * cos^(m-1)(phi) * cos^4(psi)``, independent of distance
   (phi: emission angle from the LED normal, psi: angle off the optical axis).
3. Lens blur (Gaussian PSF; with `halo_frac` a share of the flux through a wide Gaussian:
   veiling glare, which grows a saturating light's blob), then for every pixel of each LED patch a fresh noisy value
   ``black + S + N(0, alpha*S + beta)`` (eq. 4, S = ambient + LED signal), saturation at the
   white level 255, rounding to 8 bits. With `bloom_frac`, that share of the expected charge
   above the white level spills along its column first (`tools.synth.phone.column_bloom`).

Truth per light (INTERFACES.md plus extra fields):
``cx, cy``: area centroid of the true projected (distorted) outline polygon, in pixels;
``distance_m``: camera centre to light centre (pair: midpoint of the two emitters);
``visible``: every outline point inside the image, the light's front facing the camera and,
in scenes with vehicle bodies, not more than ``OCCLUDED_MAX`` of its area hidden by a body;
``area_px``: true projected area (pair: mean of the two emitters); ``mode``;
``t``: the time the light's geometry was taken at; pairs add ``emitters`` (A, B) with
per-emitter ``cx, cy, area_px, visible``. Lights far outside the view are not listed.
The camera pose in a truth line is the pose at the frame start time ``t``.

Occlusion (scenes with `Scene.bodies`): each vehicle body is an opaque box. For every emitter,
the bodies in front of it (the camera-to-emitter ray enters the box before reaching the
emitter; if the ray misses the box, a body nearer than the emitter is taken as in front) are
projected, their silhouette is the convex hull of the projected box edges, and the emitter's
coverage is multiplied per pixel by ``1 - coverage(silhouette)`` before the PSF. Inside a pixel
the product treats the two shapes as independent (exact when the silhouette covers a pixel
fully or not at all). Truth then adds ``occluded_frac`` (the hidden fraction of the emitter's
in-image area) per light (pairs: per emitter too); cx, cy and area_px stay the unoccluded
geometric values, so an evaluator sees where the light would be.
"""

from __future__ import annotations

import inspect
import math

import cv2
import numpy as np

from tools.synth.camera import (Pose, max_normalized_radius, project_camera_points, rotation_cam_to_world,
                                world_to_camera)
from tools.synth.model import Scene
from tools.synth.phone import bloom_reach_px, column_bloom, finish_frame, vignette_map
from tools.synth.raster import coverage, coverage_exact, polygon_area_centroid

NEAR_M = 0.05  # closer than this to the camera plane is not drawn
# Above this hidden fraction an emitter is not `visible`: its blob is cut, so its centroid and
# area (thesis eq. 52/53's n_IS and Hd_IS) are no longer the light's. 1 % leaves room for
# the per-pixel product's spurious overlap along edges the two shapes share within a pixel.
OCCLUDED_MAX = 0.01
BOX_EDGE_SAMPLES = 8  # points per box edge, so lens distortion can bend a silhouette's edges
TRUTH_DIGITS_PX = 4
TRUTH_DIGITS_M = 5
WHITE_DN = 255.0  # the sensor's white level: an 8-bit frame's full scale


def _rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise in (u, v)) of (N, 2) points, Andrew's monotone chain."""
    pts = sorted(set(map(tuple, np.asarray(points, dtype=np.float64))))
    if len(pts) < 3:
        return np.array(pts, dtype=np.float64)

    def half(seq):
        h = []
        for q in seq:
            while len(h) >= 2 and ((h[-1][0] - h[-2][0]) * (q[1] - h[-2][1])
                                   - (h[-1][1] - h[-2][1]) * (q[0] - h[-2][0])) <= 0:
                h.pop()
            h.append(q)
        return h

    lower, upper = half(pts), half(reversed(pts))
    return np.array(lower[:-1] + upper[:-1], dtype=np.float64)


def _box_edge_points(corners: np.ndarray) -> np.ndarray:
    """Points along the 12 edges of a box given by its 8 corners (index bits = x, y, z)."""
    s = np.linspace(0.0, 1.0, BOX_EDGE_SAMPLES)[:, None]
    out = []
    for i in range(8):
        for bit in (4, 2, 1):
            if not i & bit:
                out.append(corners[i] + s * (corners[i | bit] - corners[i]))
    return np.concatenate(out)


def _ray_box_entry(origin: np.ndarray, target: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Slab test of the ray origin + u (target - origin), u >= 0, against an axis-aligned box:
    the entry parameter u (1 = at the target) or None if the ray misses the box."""
    d = target - origin
    u0, u1 = 0.0, math.inf
    for a in range(3):
        if abs(d[a]) < 1e-15:
            if origin[a] < lo[a] or origin[a] > hi[a]:
                return None
            continue
        ta, tb = (lo[a] - origin[a]) / d[a], (hi[a] - origin[a]) / d[a]
        u0, u1 = max(u0, min(ta, tb)), min(u1, max(ta, tb))
    return u0 if u0 <= u1 else None


def background_pmf(level_dn: float, sigma_dn: float) -> np.ndarray:
    """Probabilities of the 256 output values of ``clip(round(level + N(0, sigma)), 0, 255)``."""
    edges = np.arange(-0.5, 256.5, 1.0)
    if sigma_dn <= 0:
        p = np.zeros(256)
        p[int(np.clip(np.floor(level_dn + 0.5), 0, 255))] = 1.0
        return p
    z = (edges - level_dn) / (sigma_dn * math.sqrt(2.0))
    cdf = 0.5 * (1.0 + np.array([math.erf(v) for v in z]))
    cdf[0], cdf[-1] = 0.0, 1.0
    return np.diff(cdf)


def sparse_background(rng: np.random.Generator, shape, pmf: np.ndarray) -> np.ndarray:
    """A uint8 image whose pixels are i.i.d. with distribution `pmf` (exact, sparse sampling)."""
    n = int(shape[0] * shape[1])
    mode = int(np.argmax(pmf))
    img = np.full(n, mode, dtype=np.uint8)
    q = 1.0 - float(pmf[mode])
    if q > 1e-12:
        # Positions of the non-mode pixels: a Bernoulli(q) process, i.e. geometric gaps.
        expect = n * q
        gaps = rng.geometric(q, size=int(expect + 6 * math.sqrt(expect) + 16))
        pos = np.cumsum(gaps) - 1
        while pos[-1] < n:
            more = np.cumsum(rng.geometric(q, size=len(gaps))) + pos[-1]
            pos = np.concatenate([pos, more])
        pos = pos[pos < n]
        cond = pmf.copy()
        cond[mode] = 0.0
        cdf = np.cumsum(cond / cond.sum())
        vals = np.searchsorted(cdf, rng.random(len(pos)), side="right")
        img[pos] = np.minimum(vals, 255).astype(np.uint8)
    return img.reshape(shape)


class FrameRenderer:
    """Renders frame k of `scene` for a given `seed` (each frame has its own RNG stream,
    so frames can be rendered in any order with identical results)."""

    def __init__(self, scene: Scene, seed: int = 0):
        self.scene = scene
        self.seed = int(seed)
        cam = scene.camera
        self.cam = cam
        p = scene.params
        self.t_row_s = cam.row_readout_us * 1e-6
        self.t_exp_s = cam.exposure_us * 1e-6
        self.r_max = max_normalized_radius(cam)
        self.bg_pmf = background_pmf(p.black_level_dn + p.ambient_dn,
                                     math.sqrt(p.shot_noise_alpha * p.ambient_dn + p.read_noise_dn ** 2))
        self.canvas = np.zeros((cam.height, cam.width), dtype=np.float32)
        spread = max(p.psf_sigma_px, p.halo_sigma_px if p.halo_frac > 0 else 0.0)
        self.margin = int(math.ceil(3 * spread)) + 1 if spread > 0 else 0
        # Rows below and above each light that its column bloom can reach (sparse path only:
        # the phone path draws the whole frame).
        self.bloom_rows = bloom_reach_px(p.bloom_len_px) if p.bloom_frac > 0 and not p.phone else 0
        if p.rs_band_rows > 0:
            self.margin += 8        # a phone turning at ~30 deg/s moves a light ~4 px while it is read
        # Phone effects (tools.synth.phone): the whole frame in linear DN, the lit ceiling behind
        # the lights as its own canvas (bezels hide it).
        self.phone = p.phone
        if self.phone:
            self.ambient = np.full((cam.height, cam.width), p.ambient_dn, dtype=np.float32)
            self.vignette = vignette_map(cam.height, cam.width, p.vignetting) if p.vignetting > 0 else None
        self.outlines = [[e.outline_local() for e in light.emitters] for light in scene.lights]
        self.radius_m = np.array([max(np.linalg.norm(o - light.offset, axis=1).max() for o in outl)
                                  for light, outl in zip(scene.lights, self.outlines)])
        self.bodies = list(getattr(scene, "bodies", None) or [])
        self.body_corners = [b.corners_local() for b in self.bodies]
        self.body_edges = [_box_edge_points(c) for c in self.body_corners]
        extra = scene.extra_truth
        self.extra_takes_leds = extra is not None and len(inspect.signature(extra).parameters) >= 2

    # -- geometry -------------------------------------------------------------------------
    def _to_world(self, light, pts, vecs, t_s):
        if light.carrier is None:
            return pts, vecs
        pos, yaw = self.scene.carriers[light.carrier](t_s)
        R = _rot_z(yaw)
        return pts @ R.T + pos, [v @ R.T for v in vecs]

    def _project(self, light, li, t_s, pose: Pose):
        """Per emitter: (poly (M,2) or None, area, cx, cy, visible, centre_w, cos_phi, cos_psi)."""
        out = []
        R = rotation_cam_to_world(pose.yaw, pose.pitch, pose.roll)
        for e, outline in zip(light.emitters, self.outlines[li]):
            pts, (centre, normal) = self._to_world(light, outline, [e.offset, e.normal], t_s)
            if light.carrier is not None:
                pos, _ = self.scene.carriers[light.carrier](t_s)
                centre = centre + pos  # offsets are points: translate (vectors were only rotated)
            pc = (pts - pose.position) @ R
            cc = (centre - pose.position) @ R
            if pc[:, 2].min() <= NEAR_M:
                out.append(None)
                continue
            rn = np.hypot(pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2])
            if rn.max() > self.r_max:
                out.append(None)
                continue
            poly = project_camera_points(pc, self.cam)
            area, cx, cy = polygon_area_centroid(poly)
            to_cam = pose.position - centre
            d = float(np.linalg.norm(to_cam))
            cos_phi = float(to_cam @ normal) / (d * float(np.linalg.norm(normal)))
            cos_psi = float(cc[2]) / float(np.linalg.norm(cc))
            inside = bool(poly[:, 0].min() >= -0.5 and poly[:, 0].max() <= self.cam.width - 0.5
                          and poly[:, 1].min() >= -0.5 and poly[:, 1].max() <= self.cam.height - 0.5)
            out.append(dict(poly=poly, area=area, cx=cx, cy=cy, visible=inside and cos_phi > 0,
                            centre=centre, cos_phi=cos_phi, cos_psi=cos_psi))
        return out

    def _candidates(self, pose: Pose, t_s: float):
        """Indices of lights whose centre is in front and within the (extended) field of view."""
        idx = []
        R = rotation_cam_to_world(pose.yaw, pose.pitch, pose.roll)
        for li, light in enumerate(self.scene.lights):
            c = light.offset
            if light.carrier is not None:
                pos, yaw = self.scene.carriers[light.carrier](t_s)
                c = _rot_z(yaw) @ c + pos
            pc = (c - pose.position) @ R
            if pc[2] <= NEAR_M:
                continue
            slack = self.radius_m[li] / pc[2]
            if math.hypot(pc[0] / pc[2], pc[1] / pc[2]) - slack <= self.r_max:
                idx.append(li)
        return idx

    def _occluders(self, light, geo, t_s: float, pose: Pose):
        """Per emitter: the image silhouettes (convex polygons) of the bodies in front of it."""
        out = [[] for _ in geo]
        if not self.bodies:
            return out
        R = rotation_cam_to_world(pose.yaw, pose.pitch, pose.roll)
        cam_w = pose.position
        for body, corners, edges in zip(self.bodies, self.body_corners, self.body_edges):
            if body.carrier == light.carrier:
                continue  # a car's own body is behind its taillights, never in front
            pos, yaw = self.scene.carriers[body.carrier](t_s)
            Rb = _rot_z(yaw)
            cw = corners @ Rb.T + pos
            pc = (edges @ Rb.T + pos - cam_w) @ R
            if pc[:, 2].min() <= NEAR_M:
                continue  # straddles the camera plane: not a case of a forward scene
            uv = project_camera_points(pc, self.cam)
            u_lo, v_lo = uv.min(axis=0)
            u_hi, v_hi = uv.max(axis=0)
            hull = None
            # Depth order in the body frame, where the box is axis-aligned.
            cam_b = Rb.T @ (cam_w - pos)
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            near = float(np.linalg.norm(cw - cam_w, axis=1).min())
            for ei, g in enumerate(geo):
                if g is None:
                    continue
                e_lo, e_hi = g["poly"].min(axis=0) - 1.0, g["poly"].max(axis=0) + 1.0
                if e_hi[0] < u_lo or e_lo[0] > u_hi or e_hi[1] < v_lo or e_lo[1] > v_hi:
                    continue  # the image boxes do not meet (street lights above the traffic)
                tgt_b = Rb.T @ (g["centre"] - pos)
                u = _ray_box_entry(cam_b, tgt_b, lo, hi)
                in_front = u < 1.0 if u is not None else near < float(np.linalg.norm(g["centre"] - cam_w))
                if not in_front:
                    continue
                if hull is None:
                    hull = convex_hull(uv)
                out[ei].append(hull)
        return out

    def _cover(self, poly, r0, r1, c0, c1):
        """Pixel coverage of `poly`: exact for shapes under `exact_coverage_rows` rows tall."""
        p = self.scene.params
        if float(np.ptp(poly[:, 1])) < p.exact_coverage_rows:
            return coverage_exact(poly, r0, r1, c0, c1)
        return coverage(poly, r0, r1, c0, c1, p.subrows)

    # -- rendering ------------------------------------------------------------------------
    def frame_time(self, k: int, rng: np.random.Generator) -> float:
        fps = self.cam.fps or 30.0
        jitter = rng.normal() * self.scene.params.frame_jitter_us * 1e-6
        return max(0.0, k / fps + jitter)

    def render(self, k: int):
        """Frame k: (uint8 image (H, W), truth dict)."""
        scene, cam, p = self.scene, self.cam, self.scene.params
        rng = np.random.default_rng([self.seed, int(k)])
        t_k = self.frame_time(k, rng)
        img = None if self.phone else sparse_background(rng, (cam.height, cam.width), self.bg_pmf)
        pose0 = scene.trajectory(t_k)
        t_mid = t_k + 0.5 * cam.height * self.t_row_s + 0.5 * self.t_exp_s
        leds, regions = [], []
        for li in self._candidates(scene.trajectory(t_mid), t_mid):
            light = scene.lights[li]
            first = self._project(light, li, t_mid, scene.trajectory(t_mid))
            ok = [g for g in first if g is not None]
            if not ok:
                continue
            cy0 = float(np.mean([g["cy"] for g in ok]))
            t_led = t_k + min(max(cy0, 0.0), cam.height - 1) * self.t_row_s + 0.5 * self.t_exp_s
            pose = scene.trajectory(t_led)
            geo = self._project(light, li, t_led, pose)
            if any(g is None for g in geo):
                continue
            occ = self._occluders(light, geo, t_led, pose)
            for ei, (e, g) in enumerate(zip(light.emitters, geo)):
                g["occluded"] = 0.0
                if g["cos_phi"] <= 0:
                    continue
                reg = self._draw_emitter(light, li, ei, e, g, t_k, t_led, occ[ei])
                if reg is not None:
                    regions.append(reg)
            leds.append(self._truth(light, geo, pose, t_led))
        if self.phone:
            img = finish_frame(self.canvas, self.ambient, p, rng, self.vignette)
            self.canvas[:] = 0.0
            self.ambient[:] = np.float32(p.ambient_dn)
        else:
            if self.bloom_rows and regions:
                self._bloom(regions)
            self._noise(img, regions, rng)
        truth = {"frame": int(k), "t": round(t_k, 9), "camera": pose0.as_dict(), "leds": leds}
        if scene.extra_truth is not None:
            truth.update(scene.extra_truth(t_k, leds) if self.extra_takes_leds else scene.extra_truth(t_k))
        return img, truth

    def _draw_emitter(self, light, li, ei, e, g, t_k, t_led, occluders=()):
        cam, p = self.cam, self.scene.params
        poly = g["poly"]
        m = self.margin
        r0 = max(int(math.floor(poly[:, 1].min() + 0.5)) - m, 0)
        r1 = min(int(math.floor(poly[:, 1].max() + 0.5)) + 1 + m, cam.height)
        c0 = max(int(math.floor(poly[:, 0].min() + 0.5)) - m, 0)
        c1 = min(int(math.floor(poly[:, 0].max() + 0.5)) + 1 + m, cam.width)
        if p.bezel_frac > 0:
            grow = int(math.ceil(p.bezel_frac * 0.5 * float(np.ptp(poly, axis=0).max()))) + 1
            r0, r1, c0, c1 = max(r0 - grow, 0), min(r1 + grow, cam.height), max(c0 - grow, 0), min(c1 + grow, cam.width)
        if r1 <= r0 or c1 <= c0:
            return None
        bezel = None
        if p.rs_band_rows > 0 and self.t_row_s > 0:
            # In-frame motion: each band of rows with the camera (and carrier) pose of its read time.
            cov = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
            bezel = np.zeros_like(cov) if p.bezel_frac > 0 else None
            for b0 in range(r0, r1, p.rs_band_rows):
                b1 = min(b0 + p.rs_band_rows, r1)
                t_b = t_k + 0.5 * (b0 + b1 - 1) * self.t_row_s + 0.5 * self.t_exp_s
                gb = self._project(light, li, t_b, self.scene.trajectory(t_b))[ei]
                if gb is None:
                    continue
                cov[b0 - r0:b1 - r0] = self._shaded(gb, b0, b1, c0, c1, bezel, b0 - r0)
        elif p.motion_blur_samples > 1:
            cov = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
            for s in np.linspace(0.0, self.t_exp_s, p.motion_blur_samples):
                gs = self._project(light, li, t_led - 0.5 * self.t_exp_s + s,
                                   self.scene.trajectory(t_led - 0.5 * self.t_exp_s + s))[ei]
                if gs is not None:
                    cov += self._cover(gs["poly"], r0, r1, c0, c1)
            cov /= p.motion_blur_samples
        else:
            bezel = np.zeros((r1 - r0, c1 - c0), dtype=np.float32) if p.bezel_frac > 0 else None
            cov = self._shaded(g, r0, r1, c0, c1, bezel, 0)
        if bezel is not None:
            if p.psf_sigma_px > 0:
                bezel = cv2.GaussianBlur(bezel, (0, 0), p.psf_sigma_px, borderType=cv2.BORDER_CONSTANT)
            self.ambient[r0:r1, c0:c1] *= 1.0 - np.clip(bezel, 0.0, 1.0)
        if occluders:
            mask = np.ones_like(cov)
            for hull in occluders:
                if (hull[:, 0].max() < c0 - 0.5 or hull[:, 0].min() > c1 - 0.5
                        or hull[:, 1].max() < r0 - 0.5 or hull[:, 1].min() > r1 - 0.5):
                    continue
                mask *= 1.0 - self._cover(hull, r0, r1, c0, c1)
            total = float(cov.sum(dtype=np.float64))
            cov = cov * mask
            if total > 0:
                g["occluded"] = max(0.0, 1.0 - float(cov.sum(dtype=np.float64)) / total)
        rows = t_k + np.arange(r0, r1, dtype=np.float64) * self.t_row_s
        level = e.drive.exposure_mean(rows, self.t_exp_s).astype(np.float32)
        radiance = (p.led_peak_dn * light.brightness * g["cos_phi"] ** (light.lambertian_m - 1.0)
                    * g["cos_psi"] ** 4)
        sig = cov * (level[:, None] * np.float32(radiance))
        halo = None
        if p.halo_frac > 0 and p.halo_sigma_px > 0:
            halo = cv2.GaussianBlur(sig, (0, 0), p.halo_sigma_px, borderType=cv2.BORDER_CONSTANT)
        if p.psf_sigma_px > 0:
            sig = cv2.GaussianBlur(sig, (0, 0), p.psf_sigma_px, borderType=cv2.BORDER_CONSTANT)
        if halo is not None:
            sig = np.float32(1.0 - p.halo_frac) * sig + np.float32(p.halo_frac) * halo
        self.canvas[r0:r1, c0:c1] += sig
        return (max(r0 - self.bloom_rows, 0), min(r1 + self.bloom_rows, cam.height), c0, c1)

    def _shaded(self, g, r0, r1, c0, c1, bezel, row0):
        """Coverage of the emitter outline `g["poly"]` over rows r0..r1-1, columns c0..c1-1,
        brighter towards its centre by `centre_gain` (quadratic in the distance from its
        centroid over its half extent); with `bezel` (an array whose rows row0.. match), the
        coverage of the dark frame around it (the outline grown by `bezel_frac`) is added there."""
        p = self.scene.params
        poly = g["poly"]
        cov = self._cover(poly, r0, r1, c0, c1)
        if p.centre_gain > 0:
            half = np.maximum(0.5 * np.ptp(poly, axis=0), 1.0)
            y = ((np.arange(r0, r1, dtype=np.float32) - np.float32(g["cy"])) / np.float32(half[1]))[:, None]
            x = ((np.arange(c0, c1, dtype=np.float32) - np.float32(g["cx"])) / np.float32(half[0]))[None, :]
            cov = cov * (1.0 + np.float32(p.centre_gain) * np.clip(1.0 - x * x - y * y, 0.0, 1.0))
        if bezel is not None:
            c = np.array([g["cx"], g["cy"]])
            grown = self._cover(c + (poly - c) * (1.0 + p.bezel_frac), r0, r1, c0, c1)
            bezel[row0:row0 + (r1 - r0)] += np.clip(grown - self._cover(poly, r0, r1, c0, c1), 0.0, 1.0)
        return cov

    def _bloom(self, regions):
        """Spill `bloom_frac` of the expected charge above the white level along the columns,
        over the box that holds every region (the regions include the bloom's reach)."""
        p = self.scene.params
        r0, r1 = min(r[0] for r in regions), max(r[1] for r in regions)
        c0, c1 = min(r[2] for r in regions), max(r[3] for r in regions)
        box = self.canvas[r0:r1, c0:c1]
        excess = np.maximum(box + np.float32(p.ambient_dn + p.black_level_dn - WHITE_DN), np.float32(0.0))
        if excess.any():
            box += np.float32(p.bloom_frac) * column_bloom(excess, p.bloom_len_px)

    def _noise(self, img, regions, rng):
        p = self.scene.params
        beta = p.read_noise_dn ** 2
        for r0, r1, c0, c1 in regions:
            s = self.canvas[r0:r1, c0:c1] + np.float32(p.ambient_dn)
            std = np.sqrt(np.float32(p.shot_noise_alpha) * s + np.float32(beta))
            v = s + np.float32(p.black_level_dn) + std * rng.standard_normal(s.shape, dtype=np.float32)
            img[r0:r1, c0:c1] = np.clip(np.rint(v), 0, WHITE_DN).astype(np.uint8)
        for r0, r1, c0, c1 in regions:
            self.canvas[r0:r1, c0:c1] = 0.0

    def _truth(self, light, geo, pose: Pose, t_led: float) -> dict:
        occl = bool(self.bodies)
        for g in geo:
            if occl and g["occluded"] > OCCLUDED_MAX:
                g["visible"] = False
        centre = np.mean([g["centre"] for g in geo], axis=0)
        d = float(np.linalg.norm(centre - pose.position))
        cx = float(np.mean([g["cx"] for g in geo]))
        cy = float(np.mean([g["cy"] for g in geo]))
        rec = {"id": int(light.id), "cx": round(cx, TRUTH_DIGITS_PX), "cy": round(cy, TRUTH_DIGITS_PX),
               "distance_m": round(d, TRUTH_DIGITS_M), "visible": all(g["visible"] for g in geo),
               "area_px": round(float(np.mean([g["area"] for g in geo])), 3), "mode": light.mode,
               "t": round(t_led, 9)}
        if occl:  # only in scenes with bodies, so the other scenes' truth files keep their bytes
            rec["occluded_frac"] = round(float(np.mean([g["occluded"] for g in geo])), 4)
        if len(geo) == 2:
            rec["emitters"] = [{"cx": round(g["cx"], TRUTH_DIGITS_PX), "cy": round(g["cy"], TRUTH_DIGITS_PX),
                                "area_px": round(g["area"], 3), "visible": g["visible"]} for g in geo]
            if occl:
                for em, g in zip(rec["emitters"], geo):
                    em["occluded_frac"] = round(float(g["occluded"]), 4)
        return rec


def render_frames(scene: Scene, n_frames: int | None = None, seed: int = 0, start: int = 0):
    """Iterator of (gray uint8 image (H, W), truth dict) for frames start .. start+n_frames-1."""
    r = FrameRenderer(scene, seed)
    n = scene.n_frames if n_frames is None else int(n_frames)
    for k in range(start, start + n):
        yield r.render(k)
