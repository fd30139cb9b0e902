"""Ranging: camera-to-LED distance from the LED's projected area (photogrammetry).

Two estimators, selected by name:

* ``"eq18"`` -- thesis eq. 18, ``d = f/rho * sqrt(A_LED / eta)``: the LED is assumed to face the
  camera on the optical axis, the lens has no distortion and eta is exact.
* ``"oblique"`` -- what eq. 18 ignores, removed:

  1. lens distortion: the blob contour is undistorted (``cv2.undistortPoints``) into normalized
     image coordinates (pinhole plane at unit focal length) before its area is taken;
  2. perspective and foreshortening. A small planar patch of area A at distance d, whose normal
     makes the angle theta with the viewing ray, subtends the solid angle
     ``Omega = A cos(theta) / d^2``. A patch of the image plane z = 1 seen along a ray at the angle
     alpha from the optical axis lies at 1/cos(alpha) and is tilted by alpha, so it subtends
     ``Omega = a cos(alpha)^3`` per unit normalized area a. Equating both:

         a = A cos(theta) / (d^2 cos(alpha)^3)   =>   d = sqrt(A cos(theta) / (a cos(alpha)^3))

     which is eq. 18 when theta = alpha = 0 (a = eta / (f/rho)^2). theta needs the LED normal in
     the camera frame: LEDs face straight down (world -z) and the camera orientation comes from
     the previous pose; without one the camera is assumed to look straight up, so theta = alpha
     and ``d = f/rho * sqrt(A/eta) / cos(alpha)`` (the depth of a fronto-parallel patch, divided
     by cos(alpha)). The small-patch approximation errs by O((size/d)^2): 4e-4 for 10 cm at 2.5 m;
  3. threshold / blur bias of eta: a contour traced through the centres of the boundary pixels
     (as ``cv2.findContours`` returns it) lies half a pixel inside the true edge. For a convex
     shape grown outward by delta pixels the area is ``A + P delta + pi delta^2`` (Steiner's
     formula, P the perimeter), so eta is corrected with ``edge_offset_px`` (default 0.5 px).
     The bias matters most for small blobs: its relative size is about 2 delta / sqrt(eta).

Frames: image points are OpenCV pixels (x right, y down), distorted as in the frame; the camera
frame is OpenCV's (x right, y down, z along the optical axis); the world frame has z up.
``R_cw`` below is the world-to-camera rotation (``X_cam = R_cw @ (X_world - C)``).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from receiver.core.native import require
from receiver.core.records import LedObservation
from receiver.io.camera import CameraModel

# the per-frame glue (receiver/locate/_ranging.pyx): edge touch, polygon sums, the ranges' records
_kr = require("receiver.locate._ranging")

ESTIMATORS = ("eq18", "oblique")

# Contour through the boundary pixel centres: the true edge is half a pixel further out.
DEFAULT_EDGE_OFFSET_PX = 0.5
# Relative 1-sigma of a range for what the area model leaves out (the small-patch approximation,
# residual calibration error): 0.2 %.
MODEL_REL_SIGMA = 0.002
# LEDs are mounted on the ceiling facing down (world frame, z up).
LED_NORMAL_WORLD = np.array([0.0, 0.0, -1.0])
# A camera looking straight up with image x along world x: camera axes = world axes.
R_LOOKING_UP = np.eye(3)


def distance_eq18(area_px: float, area_m2: float, focal_px: float) -> float:
    """Thesis eq. 18: ``d = f/rho * sqrt(A_LED / eta)`` in metres (eta in px^2, f/rho in px)."""
    if area_px <= 0 or area_m2 <= 0:
        return float("nan")
    return focal_px * math.sqrt(area_m2 / area_px)


def undistort_points(points_px: np.ndarray, camera: CameraModel) -> np.ndarray:
    """(N, 2) distorted pixel coordinates -> (N, 2) normalized image coordinates (x/z, y/z):
    cv2.undistortPoints (`Undistorter`)."""
    return Undistorter(camera)(points_px)


# An undistorted point must reproject onto its pixel within this (px). OpenCV's undistortion runs a
# fixed 5 fixed-point iterations, which near the corners of a strongly distorted lens (k1 ~ -0.3
# without a k2 to balance it) leave errors of pixels; such points are undistorted again with
# `UNDISTORT_MORE_ITERATIONS`.
UNDISTORT_TOL_PX = 0.01
UNDISTORT_MORE_ITERATIONS = 60


class Undistorter:
    """`undistort_points` of one camera, its matrix and coefficients checked and converted once
    (the positioner undistorts every frame's outline points). Where OpenCV's default 5 iterations
    do not converge within the image (tried once on a grid over it: `needs_check`), each frame's
    points are reprojected (cv2.projectPoints) and those off by more than `UNDISTORT_TOL_PX` are
    undistorted again with `UNDISTORT_MORE_ITERATIONS` iterations."""

    __slots__ = ("camera", "needs_check")

    def __init__(self, camera: CameraModel):
        self.camera = camera
        self.needs_check = False
        xs, ys = np.meshgrid(np.linspace(0, camera.width - 1, 17), np.linspace(0, camera.height - 1, 9))
        grid = np.column_stack([xs.ravel(), ys.ravel()])
        self.needs_check = bool(self._off_px(grid, self.first_pass(grid)).max(initial=0.0) > UNDISTORT_TOL_PX)

    def first_pass(self, pts: np.ndarray) -> np.ndarray:
        """(N, 2) float64 px -> cv2.undistortPoints' default (5 iterations)."""
        return cv2.undistortPoints(pts.reshape(-1, 1, 2), self.camera.K, self.camera.dist).reshape(-1, 2)

    def _off_px(self, pts: np.ndarray, und: np.ndarray) -> np.ndarray:
        """How far (px) each undistorted point reprojects from its pixel."""
        X = np.column_stack([und, np.ones(len(und))])
        back = cv2.projectPoints(X, np.zeros(3), np.zeros(3), self.camera.K, self.camera.dist)[0].reshape(-1, 2)
        d = back - pts
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def __call__(self, points_px: np.ndarray) -> np.ndarray:
        pts = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 2)
        if len(pts) == 0:
            return np.zeros((0, 2))
        out = self.first_pass(pts)
        if self.needs_check:
            bad = ~(self._off_px(pts, out) <= UNDISTORT_TOL_PX)
            if bad.any():
                eye = np.eye(3)
                out[bad] = cv2.undistortPoints(pts[bad].reshape(-1, 1, 2), self.camera.K, self.camera.dist, None, eye,
                                               eye, (cv2.TERM_CRITERIA_COUNT, UNDISTORT_MORE_ITERATIONS, 0)
                                               ).reshape(-1, 2)
        return out


def _polygon_sums(p: np.ndarray, perimeter: bool):
    """(sum of cross products, perimeter or 0.0, sum (x_i + x_j) cross_i, sum (y_i + y_j) cross_i)
    of a closed (K >= 3, 2) polygon: its area, perimeter and centroid from one compiled pass."""
    return _kr.polygon_sums(np.ascontiguousarray(p, np.float64), perimeter)


def polygon_area_perimeter(poly: np.ndarray) -> tuple[float, float]:
    """Area (shoelace, absolute) and perimeter of a closed (K, 2) polygon, in its own units."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    if len(p) < 3:
        return 0.0, 0.0
    sums = _polygon_sums(p, True)
    return 0.5 * abs(sums[0]), sums[1]


def polygon_centroid(poly: np.ndarray) -> np.ndarray | None:
    """Area centroid of a closed (K, 2) polygon, or None when it is degenerate."""
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    if len(p) < 3:
        return None
    return _centroid(_polygon_sums(p, False))


def _centroid(sums) -> np.ndarray | None:
    """The centroid of a polygon from its `_polygon_sums`, or None when its area is about 0."""
    a = 0.5 * sums[0]
    if abs(a) < 1e-12:
        return None
    return np.array([sums[2], sums[3]]) / (6 * a)


def steiner_area(area: float, perimeter: float, offset: float) -> float:
    """Area of a convex shape grown outward by `offset` (same units): A + P*offset + pi*offset^2."""
    return area + perimeter * offset + math.pi * offset * offset


def ray_unit(xy_norm: np.ndarray) -> np.ndarray:
    """Unit viewing ray(s) in the camera frame for (N, 2) or (2,) normalized image points."""
    xy = np.asarray(xy_norm, dtype=np.float64)
    v = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def distance_oblique(area_norm: float, area_m2: float, ray_cam: np.ndarray,
                     R_cw: np.ndarray = R_LOOKING_UP,
                     led_normal_world: np.ndarray = LED_NORMAL_WORLD) -> float:
    """Distance (m) from the normalized projected area `area_norm` of a planar LED of area
    `area_m2` seen along the unit camera-frame ray `ray_cam`, camera orientation `R_cw`
    (world-to-camera). Implements ``d = sqrt(A cos(theta) / (a cos(alpha)^3))`` (module doc)."""
    if area_norm <= 0 or area_m2 <= 0:
        return float("nan")
    cos_alpha = float(ray_cam[2])
    cos_theta = abs(float(np.dot(R_cw @ led_normal_world, ray_cam)))
    if cos_alpha <= 0 or cos_theta <= 1e-3:
        return float("nan")
    return math.sqrt(area_m2 * cos_theta / (area_norm * cos_alpha ** 3))


def contour_geometry(contour_px: np.ndarray, camera: CameraModel,
                     edge_offset_px: float = DEFAULT_EDGE_OFFSET_PX, undistort=None) -> dict | None:
    """Undistorted geometry of one blob envelope.

    Returns {"area_norm": bias-corrected normalized area, "centroid_norm": (2,) normalized
    centroid of the undistorted polygon, "area_px", "perimeter_px": of the distorted polygon},
    or None when the contour has fewer than 3 points or no area.
    `edge_offset_px`: outward offset of the true edge from the contour (module doc, item 3).
    `undistort`: the camera's `Undistorter` when the caller keeps one (else made here).
    """
    c = np.asarray(contour_px, dtype=np.float64).reshape(-1, 2)
    area_px, perim_px = polygon_area_perimeter(c)
    if area_px <= 0:
        return None
    und = (undistort or Undistorter(camera))(c)
    sums = _polygon_sums(und, False)   # polygon_area_perimeter's area and polygon_centroid in one pass
    area_n, cen = 0.5 * abs(sums[0]), _centroid(sums)
    if area_n <= 0 or cen is None:
        return None
    # The edge bias is a pixel-scale effect, so it is applied as a ratio measured in pixels.
    corr = steiner_area(area_px, perim_px, edge_offset_px) / area_px
    return {"area_norm": area_n * corr, "centroid_norm": cen, "area_px": area_px,
            "perimeter_px": perim_px}


def range_sigma_m(distance_m: float, area_px: float, perimeter_px: float,
                  edge_sigma_px: float = 0.1, model_rel_sigma: float = MODEL_REL_SIGMA) -> float:
    """Expected 1-sigma error of a range, metres.

    d ~ eta^-1/2, so sigma_d / d = sigma_eta / (2 eta); an edge located to within `edge_sigma_px`
    all around moves eta by about ``edge_sigma_px * perimeter``. `model_rel_sigma` covers what the
    model leaves out (small-patch approximation, residual calibration error).
    """
    if not (area_px > 0 and math.isfinite(distance_m)):
        return float("inf")
    rel = model_rel_sigma + edge_sigma_px * perimeter_px / (2.0 * area_px)
    return distance_m * rel


def led_outline_world(led, points_per_side: int = 8) -> np.ndarray:
    """(K, 3) world points on the outline of a ceiling LED (facing down, sides along world x/y),
    dense enough that the outline stays a good polygon after lens distortion."""
    if led.shape == "circle":
        r = led.size[0] / 2
        a = np.linspace(0, 2 * np.pi, 4 * points_per_side, endpoint=False)
        xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    else:
        w = led.size[0] / 2
        h = (led.size[1] if len(led.size) > 1 else led.size[0]) / 2
        t = np.linspace(-1, 1, points_per_side, endpoint=False)
        xy = np.concatenate([np.column_stack([t * w, -h + 0 * t]), np.column_stack([w + 0 * t, t * h]),
                             np.column_stack([-t * w, h + 0 * t]), np.column_stack([-w + 0 * t, -t * h])])
    return np.column_stack([led.x + xy[:, 0], led.y + xy[:, 1], np.full(len(xy), led.z)])


def project_world(points_world: np.ndarray, camera: CameraModel, R_cw: np.ndarray,
                  C: np.ndarray) -> np.ndarray:
    """The forward model: (K, 3) world points -> (K, 2) distorted pixels for a camera at C (3,)
    with world-to-camera rotation R_cw (frames in the module doc)."""
    rvec, _ = cv2.Rodrigues(np.asarray(R_cw, float))
    tvec = -np.asarray(R_cw, float) @ np.asarray(C, float)
    px, _ = cv2.projectPoints(np.asarray(points_world, float).reshape(-1, 1, 3), rvec, tvec,
                              camera.K, camera.dist)
    return px.reshape(-1, 2)


class Geometry:
    """One envelope's `contour_geometry` (a dict or None), computed on first use (`value`): a
    frame whose LEDs are all ranged from their outlines never needs it. `undistort`: the
    camera's `Undistorter` (None: made when needed)."""

    __slots__ = ("_args", "_value")

    def __init__(self, contour_px, camera: CameraModel, edge_offset_px: float, undistort=None):
        self._args = (contour_px, camera, edge_offset_px, undistort)
        self._value = self

    @property
    def value(self) -> dict | None:
        if self._value is self:
            self._value = contour_geometry(*self._args)
            self._args = None
        return self._value


def _with_range(obs, distance_m, estimator):
    """`dataclasses.replace(obs, distance_m=..., distance_estimator=...)` for a plain frozen
    dataclass record (no `__post_init__`, no slots): a copy of its field values with the two
    changed, without a keyword call of the generated `__init__` (a tenth of the cost; a frame
    annotates every ranged LED)."""
    cls = type(obs)
    plain = _PLAIN.get(cls)
    if plain is None:
        plain = _PLAIN[cls] = not hasattr(cls, "__post_init__") and hasattr(obs, "__dict__")
    if not plain:
        return dataclasses.replace(obs, distance_m=distance_m, distance_estimator=estimator)
    new = object.__new__(cls)
    fields = new.__dict__
    fields.update(obs.__dict__)
    fields["distance_m"] = distance_m
    fields["distance_estimator"] = estimator
    return new


# record class -> may `_with_range` copy its instances' __dict__ (no __post_init__, not slotted)
_PLAIN: dict[type, bool] = {}


class Ranger:
    """The ranging stage: which of a frame's LED observations can be ranged, and their ranges.

    Callable on its own (`range_leds`), and the one API both the local positioner
    (receiver.locate.indoor) and the lighting-server client (receiver.serve.client) use.
    `settings`: the locate stage's `PositionerSettings` (its `ranging` estimator, `edge_sigma_px`,
    `edge_offset_px`, `border_margin_px`). IDs the map does not know are
    counted in `unknown_ids`.
    """

    def __init__(self, camera: CameraModel, led_map, settings):
        if settings.ranging not in ESTIMATORS:
            raise ValueError(f"unknown ranging estimator {settings.ranging!r}")
        self.camera, self.led_map = camera, led_map
        self.estimator = settings.ranging
        self.edge_sigma_px = settings.edge_sigma_px
        self.edge_offset_px = settings.edge_offset_px
        self.border_margin_px = settings.border_margin_px
        self.unknown_ids: set[int] = set()
        self._known: dict = {}  # LED id -> the map's LED or None (`_lookup`)
        self._undistort = Undistorter(camera)

    def _touching_edge(self, obs_list) -> list[bool]:
        """For each observation: does its envelope come within `border_margin_px` of the image
        edge? (All envelopes' extremes in one compiled pass; no contour: False.) Contours that
        are not (K, 2) float64 arrays are converted first."""
        m = self.border_margin_px
        w1, h1 = self.camera.width - 1 - m, self.camera.height - 1 - m
        contours = [o.contour for o in obs_list]
        try:
            return _kr.cut_by_edge(contours, m, w1, h1)
        except (ValueError, TypeError, BufferError):
            return _kr.cut_by_edge([None if c is None else np.ascontiguousarray(np.asarray(c, np.float64).reshape(-1, 2))
                                    for c in contours], m, w1, h1)

    def _lookup(self, led_id: int):
        """The map's LED of this ID or None, looked up once per ID (the map does not change
        during a run)."""
        try:
            return self._known[led_id]
        except KeyError:
            led = self._known[led_id] = self.led_map.lookup(led_id)
            return led

    def usable(self, leds) -> list:
        """The frame's rangeable LEDs: (observation, map LED, `Geometry` of its envelope or None)
        for every decoded, uncut OOK or tone LED the map knows (unknown IDs are counted in
        `unknown_ids`). Blobs within `border_margin_px` of the image edge are left out (their
        area is cut). S2-PSK lights are left out: a street-light head or a taillight pair is seen
        as two emitter blobs, not one fixture of the map's size, from a camera looking along the
        road; they are ranged as pairs by the vehicle locator (receiver.locate.vehicle)."""
        cand = [o for o in leds if o.id is not None and not o.border and o.mode != "s2psk"]
        items = []
        if not cand:
            return items
        lookup, camera, offset, und = self._lookup, self.camera, self.edge_offset_px, self._undistort
        for obs, cut in zip(cand, self._touching_edge(cand)):
            if cut:
                continue
            led = lookup(obs.id)
            if led is None:
                self.unknown_ids.add(obs.id)
                continue
            if led.mode == "s2psk":
                continue
            contour = obs.contour
            items.append((obs, led, Geometry(contour, camera, offset, und)
                          if contour is not None and len(contour) >= 3 else None))
        return items

    def ranges(self, items, R_cw: np.ndarray | None, skip=()):
        """(d (N,) m, sigma_d (N,) m, estimator names) of `usable`'s items, NaN where the LED's
        size is unknown. `R_cw`: the camera orientation for the oblique estimator's
        foreshortening (None: looking straight up). `skip`: indices of items not to range (NaN,
        name ""), e.g. those ranged otherwise (their envelope geometry is then never computed)."""
        d = np.full(len(items), np.nan)
        sd = np.full(len(items), np.nan)
        names = [""] * len(items)
        for i, (obs, led, lazy) in enumerate(items):
            if i in skip:
                continue
            A = led.area_m2
            if not A:
                continue
            geo = lazy.value if lazy is not None else None
            if self.estimator == "oblique" and geo is not None:
                Rw = np.eye(3) if R_cw is None else R_cw
                d[i] = distance_oblique(geo["area_norm"], A, ray_unit(geo["centroid_norm"]), Rw)
                names[i] = "oblique-up" if R_cw is None else "oblique-pose"
                area_px, perim = geo["area_px"], geo["perimeter_px"]
            else:
                d[i] = distance_eq18(obs.area_px, A, self.camera.focal_px)
                names[i] = "eq18"
                area_px = obs.area_px
                perim = 4.0 * math.sqrt(max(area_px, 0.0))   # square-ish blob without a contour
            sd[i] = range_sigma_m(d[i], area_px, perim, self.edge_sigma_px)
        return d, sd, names

    def image_points(self, items) -> np.ndarray:
        """(N, 2) undistorted normalized image points of `usable`'s items."""
        if not items:
            return np.zeros((0, 2))
        return self._undistort(np.array([[o.cx, o.cy] for o, _, _ in items]))

    @staticmethod
    def annotate(leds, items, d: np.ndarray, names: list[str]) -> list:
        """`leds` with `distance_m` (rounded to 10 um) and `distance_estimator` set on every
        item with a finite range; the others unchanged."""
        dl = np.asarray(d, dtype=np.float64).tolist()
        return _kr.annotate(list(leds), list(items), dl, list(names), LedObservation, _with_range)

    def range_leds(self, leds, R_cw: np.ndarray | None = None) -> list:
        """Ranging without a positioner: `leds` with the ranges of the rangeable ones."""
        items = self.usable(leds)
        d, _, names = self.ranges(items, R_cw)
        return self.annotate(leds, items, d, names)
