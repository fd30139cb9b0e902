"""Camera intrinsics from views of a chessboard or a ChArUco board (`calibrate_views`).

Board specs (`parse_board`): `chess:COLSxROWS` counts *inner corners* as OpenCV's
findChessboardCorners does; `charuco:COLSxROWS:DICT` counts *squares* (cv2.aruco.CharucoBoard)
with an ArUco dictionary name such as DICT_4X4_50.

Views are filtered before calibrating:
* blurred: chessboards by `cv2.estimateChessboardSharpness` (mean edge width in px above
  `max_blur_px`), ChArUco boards by the variance of the Laplacian inside the board's corner hull
  (below `min_laplacian_var`);
* duplicates: a view whose corners lie within `min_move_frac` of the image diagonal (mean
  distance of the common corners) of an accepted view adds nothing (a still board in a video);
* too few corners (ChArUco: fewer than 6 detected).
Chessboard corners come from OpenCV's sector-based finder (`cv2.findChessboardCornersSB`, with
its accuracy flag: sub-pixel corners from the board's own sectors, more accurate than
`findChessboardCorners` + `cornerSubPix`), the classic finder only where it finds nothing. A
view over `MAX_SEARCH_PIXELS` is searched downscaled and its corners refined on the full image.
Then `cv2.calibrateCameraExtended` on the accepted views (at most `max_views`, spread evenly),
which gives the RMS reprojection error and the per-view errors; views whose error exceeds
`VIEW_ERROR_FACTOR` x the median (and `MIN_VIEW_ERROR_PX`) are dropped and the camera calibrated
again (a mis-ordered or mis-detected board pulls every parameter).

`calibration_problems` judges the result: RMS above `MAX_RMS_PX`, or a radial distortion that
scales the image corner's radius by less than `MIN_RADIAL_SCALE` or more than `MAX_RADIAL_SCALE`
(no ordinary lens does: a ChArUco fit with k3 = 48925 does), or fewer views than parameters.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import cv2
import numpy as np

from receiver.core.errors import InputError


# A view whose reprojection error exceeds this many times the median of the views (and
# MIN_VIEW_ERROR_PX) is dropped before the final calibration.
VIEW_ERROR_FACTOR = 3.0
MIN_VIEW_ERROR_PX = 0.5
# A calibration with an RMS reprojection error above this (px) is refused (sharp corners of a
# flat board fit to ~0.1-0.5 px).
MAX_RMS_PX = 1.0
# The radial distortion factor 1 + k1 r^2 + k2 r^4 + k3 r^6 anywhere out to the image corner must
# stay within these (a wide-angle webcam reaches ~0.7; a factor out of range is an overfit).
MIN_RADIAL_SCALE, MAX_RADIAL_SCALE = 0.5, 1.5
# Largest image OpenCV's chessboard search looks at (pixels): its cost grows with the image
# (findChessboardCornersSB: about 0.25 GB and 3 s per megapixel; a 33 MP phone photo took 7 GB
# and three minutes). A larger view is searched downscaled to this size and its corners are
# refined on the full image (cv2.cornerSubPix), which keeps their full-resolution accuracy.
MAX_SEARCH_PIXELS = 2_100_000
# Half-size of the full-resolution refinement window, as a fraction of the corner spacing
# (well inside a square, so a window never reaches the next corner), and its bounds (px).
REFINE_WINDOW_FRAC, REFINE_WINDOW_PX = 0.2, (3, 30)
# Longest side over shortest side of a camera's frame: sensors are 1:1 to 16:9, panoramic film
# formats under 3:1. A longer strip is not a camera's view, and OpenCV's chessboard search costs
# grow without bound with it (a 100x100000 image runs past ten minutes).
MAX_FRAME_ASPECT = 4.0


@dataclass(frozen=True)
class Board:
    kind: str  # "chess" | "charuco"
    cols: int
    rows: int
    square_m: float
    marker_m: float | None = None
    dictionary: str | None = None

    def object_points(self) -> np.ndarray:
        """(N, 3) float32 inner-corner positions of a chessboard (metres, z = 0), row-major as
        findChessboardCorners orders them."""
        g = np.mgrid[0:self.cols, 0:self.rows].T.reshape(-1, 2).astype(np.float32)
        return np.hstack((g * self.square_m, np.zeros((g.shape[0], 1), np.float32)))

    def charuco(self):
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, d)


def parse_board(spec: str, square_mm: float, marker_mm: float | None = None) -> Board:
    """Board from 'chess:9x6' or 'charuco:7x5:DICT_4X4_50' and the square (and marker) size."""
    if square_mm is None or not square_mm > 0:
        raise InputError("--square-mm must be positive")
    m = re.fullmatch(r"(chess|charuco):(\d+)[xX](\d+)(?::(\w+))?", spec or "")
    if not m:
        raise InputError(f"--board must be chess:COLSxROWS or charuco:COLSxROWS:DICT, not {spec!r}")
    kind, cols, rows, dname = m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)
    if cols < 2 or rows < 2:
        raise InputError("--board needs at least 2x2 corners/squares")
    if kind == "chess":
        if dname:
            raise InputError("a chess board takes no dictionary")
        return Board("chess", cols, rows, square_mm / 1000.0)
    if not dname or not dname.startswith("DICT_") or not hasattr(cv2.aruco, dname):
        raise InputError(f"unknown ArUco dictionary {dname!r} (e.g. DICT_4X4_50)")
    if marker_mm is None or not 0 < marker_mm < square_mm:
        raise InputError("a charuco board needs --marker-mm, smaller than --square-mm")
    return Board("charuco", cols, rows, square_mm / 1000.0, marker_mm / 1000.0, dname)


@dataclass
class ViewStats:
    seen: int = 0
    found: int = 0
    blurred: int = 0
    duplicate: int = 0
    accepted: int = 0


@dataclass
class CalibrationResult:
    K: np.ndarray
    dist: np.ndarray
    rms_px: float
    per_view_px: list[float]
    frames: list[int]
    size: tuple[int, int]
    stats: ViewStats = field(default_factory=ViewStats)
    dropped_views: list[tuple[int, float]] = field(default_factory=list)  # (frame, error px) dropped

    def to_json(self) -> dict:
        return {"rms_px": round(self.rms_px, 4), "views": len(self.frames),
                "dropped_views": [{"frame": i, "error_px": round(e, 4)} for i, e in self.dropped_views],
                "fx": round(float(self.K[0, 0]), 3), "fy": round(float(self.K[1, 1]), 3),
                "cx": round(float(self.K[0, 2]), 3), "cy": round(float(self.K[1, 2]), 3),
                "dist": [round(float(v), 6) for v in self.dist.ravel()[:5]],
                "per_view_px": [round(float(v), 4) for v in self.per_view_px],
                "frames_used": self.frames, "frames_seen": self.stats.seen,
                "found": self.stats.found, "rejected_blurred": self.stats.blurred,
                "rejected_duplicate": self.stats.duplicate,
                "image_width": self.size[0], "image_height": self.size[1]}


class ViewCollector:
    """Detects the board in frames and keeps the sharp, distinct views."""

    def __init__(self, board: Board, *, max_blur_px: float = 4.0, min_laplacian_var: float = 20.0,
                 min_move_frac: float = 0.02, max_search_px: int = MAX_SEARCH_PIXELS):
        self.board = board
        self.max_search_px = max_search_px
        self.search_size: tuple[int, int] | None = None  # the downscaled search size, when views are large
        self._search = None   # (search image, x and y scale) of the last view, when downscaled
        self.max_blur_px = max_blur_px
        self.min_laplacian_var = min_laplacian_var
        self.min_move_frac = min_move_frac
        self.views: list[tuple[int, np.ndarray, np.ndarray, np.ndarray | None]] = []
        self.stats = ViewStats()
        self.size: tuple[int, int] | None = None
        if board.kind == "charuco":
            self._cb = board.charuco()
            self._det = cv2.aruco.CharucoDetector(self._cb)

    def add(self, index: int, gray: np.ndarray) -> str:
        """Look at one frame: 'accepted', 'none', 'blurred' or 'duplicate'."""
        h, w = gray.shape[:2]
        if max(w, h) > MAX_FRAME_ASPECT * min(w, h):
            raise InputError(f"frame {index} is {w}x{h}: not a camera's frame (sides over "
                             f"{MAX_FRAME_ASPECT:g}:1), nothing to calibrate")
        if self.size is None:
            self.size = (w, h)
        elif self.size != (w, h):
            raise InputError(f"frame {index} is {w}x{h}, earlier frames {self.size[0]}x{self.size[1]}")
        self.stats.seen += 1
        found = self._detect(gray)
        if found is None:
            return "none"
        self.stats.found += 1
        img_pts, obj_pts, ids = found
        if self._blurred(gray, img_pts):
            self.stats.blurred += 1
            return "blurred"
        if self._duplicate(img_pts, ids, math.hypot(w, h)):
            self.stats.duplicate += 1
            return "duplicate"
        self.views.append((index, img_pts, obj_pts, ids))
        self.stats.accepted += 1
        return "accepted"

    def _detect(self, gray):
        b = self.board
        if b.kind == "chess":
            h, w = gray.shape[:2]
            small = gray
            self._search = None
            if w * h > self.max_search_px:
                f = math.sqrt(self.max_search_px / (w * h))
                self.search_size = (max(1, int(w * f)), max(1, int(h * f)))
                small = cv2.resize(gray, self.search_size, interpolation=cv2.INTER_AREA)
            ok, corners = cv2.findChessboardCornersSB(
                small, (b.cols, b.rows), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
            if not ok:
                flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
                ok, corners = cv2.findChessboardCorners(small, (b.cols, b.rows), flags=flags)
                if not ok:
                    return None
                if small is gray:
                    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit)
            if small is not gray:
                # pixel centres of the search image back to the full image's, then refined there
                sx, sy = w / small.shape[1], h / small.shape[0]
                pts = corners.reshape(-1, 2).astype(np.float64)
                pts = np.column_stack(((pts[:, 0] + 0.5) * sx - 0.5, (pts[:, 1] + 0.5) * sy - 0.5))
                corners = cv2.cornerSubPix(gray, pts.astype(np.float32).reshape(-1, 1, 2),
                                           _refine_window(pts, b.cols), (-1, -1), crit)
                self._search = (small, sx, sy)
            return corners.reshape(-1, 2).astype(np.float32), b.object_points(), None
        cc, cids, _mc, _mids = self._det.detectBoard(gray)
        if cids is None or len(cids) < 6:
            return None
        obj, img = self._cb.matchImagePoints(cc, cids)
        if obj is None or len(obj) < 6:
            return None
        return img.reshape(-1, 2).astype(np.float32), obj.reshape(-1, 3).astype(np.float32), cids.ravel()

    def _blurred(self, gray, pts) -> bool:
        b = self.board
        if b.kind == "chess":
            if self._search is not None:
                # judged where it was searched: `max_blur_px` is an edge width at the search's
                # scale (a sharp 33 MP photo's edges span more pixels than a webcam's)
                gray, sx, sy = self._search
                pts = np.column_stack(((pts[:, 0] + 0.5) / sx - 0.5, (pts[:, 1] + 0.5) / sy - 0.5))
            sharp = cv2.estimateChessboardSharpness(gray, (b.cols, b.rows),
                                                    pts.astype(np.float32).reshape(-1, 1, 2))
            return float(sharp[0][0]) > self.max_blur_px
        hull = cv2.convexHull(pts.astype(np.float32)).astype(np.int32)
        mask = np.zeros(gray.shape[:2], np.uint8)
        cv2.fillConvexPoly(mask, hull, 1)
        lap = cv2.Laplacian(gray, cv2.CV_32F)
        var = float(lap[mask > 0].var()) if mask.any() else 0.0
        return var < self.min_laplacian_var

    def _duplicate(self, pts, ids, diag) -> bool:
        lim = self.min_move_frac * diag
        for _i, p, _o, vids in self.views:
            if ids is None:
                if p.shape == pts.shape and float(np.linalg.norm(p - pts, axis=1).mean()) < lim:
                    return True
            else:
                common, a, c = np.intersect1d(vids, ids, return_indices=True)
                if common.size >= 0.8 * max(len(ids), 1) and \
                        float(np.linalg.norm(p[a] - pts[c], axis=1).mean()) < lim:
                    return True
        return False


def _refine_window(pts: np.ndarray, cols: int) -> tuple[int, int]:
    """cornerSubPix's half-window for corners `pts` (row-major, `cols` a row): a fraction of the
    smallest spacing of neighbouring corners (`REFINE_WINDOW_FRAC`, within `REFINE_WINDOW_PX`)."""
    grid = pts.reshape(-1, cols, 2)
    steps = [np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel(),
             np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel()]
    spacing = float(np.min(np.concatenate([s for s in steps if s.size]))) if any(s.size for s in steps) else 0.0
    half = int(np.clip(round(REFINE_WINDOW_FRAC * spacing), *REFINE_WINDOW_PX))
    return half, half


def calibrate_views(col: ViewCollector, *, max_views: int = 40, K0: np.ndarray | None = None,
                    min_views: int = 4) -> CalibrationResult:
    """cv2.calibrateCameraExtended over the collector's views (k1 k2 p1 p2 k3)."""
    if not col.views:
        raise InputError(f"no usable board view in {col.stats.seen} frames "
                         f"(found {col.stats.found}, blurred {col.stats.blurred}, "
                         f"duplicates {col.stats.duplicate})")
    if len(col.views) < min_views:
        raise InputError(f"only {len(col.views)} usable board views (need {min_views}): "
                         f"move the board to more positions and angles")
    views = col.views
    if len(views) > max_views:
        keep = np.linspace(0, len(views) - 1, max_views).round().astype(int)
        views = [views[i] for i in keep]
    rms, K, dist, per_view = _calibrate(views, col.size, K0)
    dropped = []
    med = float(np.median(per_view))
    limit = max(VIEW_ERROR_FACTOR * med, MIN_VIEW_ERROR_PX)
    bad = [k for k, e in enumerate(per_view) if e > limit]
    if bad and len(views) - len(bad) >= min_views:
        dropped = [(int(views[k][0]), float(per_view[k])) for k in bad]
        views = [v for k, v in enumerate(views) if k not in bad]
        rms, K, dist, per_view = _calibrate(views, col.size, K0)
    return CalibrationResult(K, dist.ravel()[:5] if dist.size >= 5 else np.pad(dist.ravel(), (0, 5 - dist.size)),
                             float(rms), per_view, [int(v[0]) for v in views], col.size, col.stats, dropped)


def _calibrate(views, size, K0):
    """(rms px, K, dist, per-view errors px) of cv2.calibrateCameraExtended over `views`."""
    obj = [v[2] for v in views]
    img = [v[1].reshape(-1, 1, 2) for v in views]
    flags = 0
    K = None
    if K0 is not None:
        K, flags = np.array(K0, np.float64), cv2.CALIB_USE_INTRINSIC_GUESS
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, _r, _t, _si, _se, per_view = cv2.calibrateCameraExtended(
        obj, img, size, K, None, flags=flags, criteria=crit)
    return float(rms), K, dist, [float(v) for v in np.asarray(per_view).ravel()]


def calibration_problems(res: CalibrationResult) -> list[str]:
    """Why this calibration should not be trusted, with its numbers ([] when it is sound)."""
    out = []
    if not math.isfinite(res.rms_px) or res.rms_px > MAX_RMS_PX:
        out.append(f"RMS reprojection error {res.rms_px:.3f} px is above {MAX_RMS_PX:g} px")
    k1, k2, _p1, _p2, k3 = (float(v) for v in np.asarray(res.dist, float).ravel()[:5])
    w, h = res.size
    fx, fy, cx, cy = res.K[0, 0], res.K[1, 1], res.K[0, 2], res.K[1, 2]
    r_max = max(math.hypot((x - cx) / fx, (y - cy) / fy) for x in (0, w) for y in (0, h))
    r2 = np.linspace(0.0, r_max, 200) ** 2
    scale = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    lo, hi = float(scale.min()), float(scale.max())
    if not (lo >= MIN_RADIAL_SCALE and hi <= MAX_RADIAL_SCALE):
        out.append(f"distortion k1 {k1:.4g}, k2 {k2:.4g}, k3 {k3:.4g} scales radii by {lo:.3g}..{hi:.3g} "
                   f"out to the image corner (a lens stays within {MIN_RADIAL_SCALE:g}..{MAX_RADIAL_SCALE:g})")
    if not (fx > 0 and fy > 0 and 0 <= cx <= w and 0 <= cy <= h):
        out.append(f"camera matrix fx {fx:.1f}, fy {fy:.1f}, cx {cx:.1f}, cy {cy:.1f} is not a camera's "
                   f"for a {w}x{h} image")
    return out
