"""Annotated video of what the receiver sees (`OverlayWriter`, for `occloc run --overlay FILE`).

Per frame, on a BGR copy of the gray frame (OpenCV drawing only): each LED's envelope, track
number, decoded ID and distance; the S2-PSK pairs (a line between the emitters and the ID); the
position (text); the vehicle picture (hv and fv text, each car coloured by its zone); and a small
top-view inset of the map (LED positions, the estimated camera or host-vehicle position). Text,
lines and the inset scale with the image (`scale_for`: a 33 MP photo gets text as readable as a
720p frame's).

Output by the path's extension (`FORMATS`): a still of the last frame (.png, .jpg/.jpeg) or a
video with the first codec of its list this OpenCV build can write (.avi: MJPG, FFV1; .mkv: FFV1,
MJPG; .mp4: H.264 (avc1), MPEG-4 part 2 (mp4v), both of which common players open). Another
extension, or no codec for it, is an InputError before any frame is processed.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from receiver.core.errors import InputError
from receiver.io.files import cv_path

INSET = (200, 150)  # top-view inset size at scale 1, px
GREEN, YELLOW, CYAN, WHITE, RED = (0, 255, 0), (0, 255, 255), (255, 255, 0), (255, 255, 255), (0, 0, 255)
ORANGE = (0, 165, 255)
ZONE_COLOURS = {"safe": GREEN, "min": ORANGE, "critical": RED}
STILLS = (".png", ".jpg", ".jpeg")
# Video extension -> FOURCCs tried in order.
FORMATS = {".avi": ("MJPG", "FFV1"), ".mkv": ("FFV1", "MJPG"), ".mp4": ("avc1", "mp4v")}
# Image height (px) at which text and lines are drawn at scale 1 (a 720p frame).
REFERENCE_HEIGHT_PX = 720


def scale_for(size) -> float:
    """Drawing scale of an image of `size` (w, h): its height over a 720p frame's, at least 1."""
    return max(1.0, float(min(size[0], size[1])) / REFERENCE_HEIGHT_PX)


def check_overlay_path(path: str) -> None:
    """InputError unless `path`'s extension is one the overlay writes (`STILLS`, `FORMATS`)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in STILLS and ext not in FORMATS:
        raise InputError(f"--overlay {path}: cannot write {ext or 'a file without extension'}; use "
                         f"{', '.join(STILLS + tuple(FORMATS))}")
    if ext in FORMATS:  # OpenCV's video writer opens it (staged beside it) by name
        cv_path(os.path.realpath(path), "--overlay video")


class OverlayWriter:
    """OverlayWriter(path, size=(w, h), fps, camera, led_map); .write(gray, frame_result); .close()."""

    def __init__(self, path: str, size, fps: float, camera=None, led_map=None):
        self.path, self.size = path, (int(size[0]), int(size[1]))
        self.fps = float(fps) if fps and fps > 0 else 30.0
        self.camera, self.led_map = camera, led_map
        check_overlay_path(path)
        ext = os.path.splitext(path)[1].lower()
        self.png = ext in STILLS   # a still of the last frame (PNG or JPEG)
        self._writer = None
        self._frames = 0
        self._last = None
        self._pts = None
        if led_map is not None and led_map.leds:
            self._pts = np.array([[l.x, l.y] for l in led_map.leds.values()], np.float64)
        if not self.png:
            level = cv2.utils.logging.getLogLevel()
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
            try:
                for fourcc in FORMATS[ext]:
                    w = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), self.fps, self.size, True)
                    if w.isOpened():
                        self._writer, self.fourcc = w, fourcc
                        break
            finally:
                cv2.utils.logging.setLogLevel(level)
            if self._writer is None:
                raise InputError(f"{path}: this OpenCV cannot write {' or '.join(FORMATS[ext])} in {ext}")

    def _map_xy(self, x, y, lo, scale, origin):
        return (int(origin[0] + (x - lo[0]) * scale), int(origin[1] + INSET[1] - 8 - (y - lo[1]) * scale))

    def _inset(self, img, position, k: float = 1.0) -> None:
        if self._pts is None:
            return
        h, w = img.shape[:2]
        iw, ih = min(int(INSET[0] * k), w // 3), min(int(INSET[1] * k), h // 3)
        ox, oy = w - iw - 8, 8
        roi = img[oy:oy + ih, ox:ox + iw]
        roi[:] = (roi * 0.35).astype(np.uint8)
        cv2.rectangle(img, (ox, oy), (ox + iw - 1, oy + ih - 1), WHITE, 1)
        pts = self._pts
        if position is not None:
            pts = np.vstack((pts, [[position["x"], position["y"]]]))
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        scale = min((iw - 16) / max(hi[0] - lo[0], 1e-6), (ih - 16) / max(hi[1] - lo[1], 1e-6))
        for x, y in self._pts:
            p = (int(ox + 8 + (x - lo[0]) * scale), int(oy + ih - 8 - (y - lo[1]) * scale))
            cv2.circle(img, p, max(2, int(2 * k)), YELLOW, -1)
        if position is not None:
            p = (int(ox + 8 + (position["x"] - lo[0]) * scale), int(oy + ih - 8 - (position["y"] - lo[1]) * scale))
            cv2.drawMarker(img, p, RED, cv2.MARKER_CROSS, int(10 * k), max(2, int(2 * k)))

    def annotate(self, gray: np.ndarray, res) -> np.ndarray:
        """The annotated BGR frame."""
        img = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR) if gray.ndim == 2 else gray.copy()
        k = scale_for((img.shape[1], img.shape[0]))
        th = max(1, int(round(k)))  # line thickness
        font = cv2.FONT_HERSHEY_SIMPLEX
        for led in getattr(res, "leds", []) or []:
            c = np.asarray(led.contour, np.float64).reshape(-1, 2)
            colour = GREEN if led.id is not None else YELLOW
            if c.size:
                cv2.polylines(img, [np.round(c).astype(np.int32)], True, colour, th, cv2.LINE_AA)
            label = f"#{led.track}" + (f" id {led.id}" if led.id is not None else "")
            if led.distance_m is not None:
                label += f" {led.distance_m:.2f} m"
            y0 = int(c[:, 1].min()) - 4 if c.size else int(led.cy)
            cv2.putText(img, label, (int(led.cx - 30 * k), max(y0, int(10 * k))), font, 0.4 * k, colour, th,
                        cv2.LINE_AA)
        for pr in getattr(res, "pairs", ()) or ():
            a = tuple(int(round(v)) for v in pr.a_px)
            b = tuple(int(round(v)) for v in pr.b_px)
            cv2.line(img, a, b, CYAN, th, cv2.LINE_AA)
            txt = f"{pr.kind or ''} {pr.led_id}" if pr.led_id is not None else "pair"
            cv2.putText(img, txt, ((a[0] + b[0]) // 2, (a[1] + b[1]) // 2 - int(6 * k)), font, 0.4 * k, CYAN, th,
                        cv2.LINE_AA)
        lines = [f"frame {res.frame}  t {res.t_s:.3f} s"]
        pos = getattr(res, "position", None)
        if pos:
            lines.append(f"pos x {pos['x']:.2f} y {pos['y']:.2f} z {pos.get('z', 0):.2f} m "
                         f"({pos.get('method', '')}, {pos.get('n_leds', '')} LEDs)")
        veh = getattr(res, "vehicle", None)
        if veh:
            hv = veh.get("hv")
            if hv:
                lines.append(f"hv x {hv.get('x', 0):.1f} y {hv.get('y', 0):.1f} m")
            for fv in veh.get("fv", []) or []:
                ttc = fv.get("ttc_s")
                lines.append((f"fv {fv.get('id')} {fv.get('distance_m', 0) or 0:.1f} m "
                              f"{fv.get('angle_deg', 0) or 0:+.1f} deg" + (f" TTC {ttc:.1f} s" if ttc is not None else "")
                              + (f" {fv['zone']}" if fv.get("zone") else ""), ZONE_COLOURS.get(fv.get("zone"), WHITE)))
        for i, t in enumerate(lines):
            text, colour = t if isinstance(t, tuple) else (t, WHITE)
            cv2.putText(img, text, (int(8 * k), int((18 + 16 * i) * k)), font, 0.45 * k, colour, th, cv2.LINE_AA)
        hv = (veh or {}).get("hv") if isinstance(veh, dict) else None
        self._inset(img, pos if pos else hv, k)
        return img

    def write(self, gray: np.ndarray, frame_result) -> None:
        img = self.annotate(gray, frame_result)
        if self.png:
            self._last = img
        else:
            if (img.shape[1], img.shape[0]) != self.size:
                img = cv2.resize(img, self.size, interpolation=cv2.INTER_AREA)
            self._writer.write(img)
            self._frames += 1

    def close(self) -> None:
        """Finish the file; InputError when it is incomplete (OpenCV's video writer does not
        report a failed write, e.g. a full disk: the file is read back and its frames counted)."""
        if self.png:
            if self._last is not None:
                # the still in the format its name asks for (PNG or JPEG), written straight into
                # the file the caller staged (receiver.cli.run: renamed into place when the run ends)
                ok, buf = cv2.imencode(os.path.splitext(self.path)[1].lower(), self._last)
                if not ok:
                    raise InputError(f"{self.path}: cannot encode the overlay image")
                with open(self.path, "wb") as f:
                    f.write(buf.tobytes())
        elif self._writer is not None:
            self._writer.release()
            self._writer = None
            if self._frames and self._count_frames() != self._frames:
                raise InputError("the video is incomplete (disk full?)")

    def _count_frames(self) -> int:
        cap = cv2.VideoCapture(self.path)
        try:
            return int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        finally:
            cap.release()
