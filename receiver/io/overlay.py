"""Annotated video of what the receiver sees (`OverlayWriter`, for `occloc run --overlay FILE`).

Per frame, on a BGR copy of the gray frame (OpenCV drawing only): each LED's envelope, track
number, decoded ID and distance; the S2-PSK pairs (a line between the emitters and the ID); the
position (text); the vehicle picture (hv and fv text, each car coloured by its zone); and a small
top-view inset of the map (LED positions, the estimated camera or host-vehicle position, the cars
ahead placed on the road in their zone's colour). Labels close together are moved apart. Text,
lines and the inset scale with the image (`scale_for`: a 33 MP photo gets text as readable as a
720p frame's).

`LiveWindow` shows the same picture live in a window (`occloc run --show`) where a display exists.

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
# A vehicle's inset shows the road map within this many metres of the host (x and y), at least a
# quarter of it around the host: the cars ahead (up to ~60 m) and the nearest street lights.
VEHICLE_VIEW_M = 80.0
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


class _Labels:
    """Labels of one frame, each moved up or down (by its own height, a few lines at most) off the
    ones already drawn: the labels of lights and cars close together do not pile on each other."""

    TRIES = 6

    def __init__(self):
        self.boxes: list[tuple[int, int, int, int]] = []

    def reserve(self, text: str, org, scale: float, th: int) -> None:
        """Keep the place of `text` drawn at `org` free of the labels put later."""
        (tw, tht), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, th)
        self.boxes.append((int(org[0]), int(org[1]) - tht, int(org[0]) + tw, int(org[1]) + base))

    def put(self, img, text: str, org, scale: float, colour, th: int) -> None:
        font = cv2.FONT_HERSHEY_SIMPLEX
        (tw, tht), base = cv2.getTextSize(text, font, scale, th)
        x, y = int(org[0]), int(org[1])
        step = tht + base + 2
        for k in range(2 * self.TRIES + 1):   # the place asked for, then one line up, one down, two up...
            yy = y + (-(k + 1) // 2 if k % 2 else k // 2) * step
            box = (x, yy - tht, x + tw, yy + base)
            if box[1] < 0 or box[3] > img.shape[0]:   # off the image
                continue
            if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in self.boxes):
                y = yy
                break
        self.boxes.append((x, y - tht, x + tw, y + base))
        cv2.putText(img, text, (x, y), font, scale, colour, th, cv2.LINE_AA)


def _inset_box(shape, k: float) -> tuple[int, int, int, int]:
    """(left, top, width, height) px of the inset in an image of `shape` at drawing scale `k`:
    the top right corner, at most a third of the image each way."""
    h, w = shape[:2]
    iw, ih = min(int(INSET[0] * k), w // 3), min(int(INSET[1] * k), h // 3)
    return w - iw - 8, 8, iw, ih


class Annotator:
    """What the receiver saw drawn on a frame (`annotate`): the picture of `OverlayWriter` and
    `LiveWindow`. `led_map`: the map of the inset (None: no inset)."""

    def __init__(self, led_map=None):
        self._pts = None
        if led_map is not None and led_map.leds:
            self._pts = np.array([[l.x, l.y] for l in led_map.leds.values()], np.float64)

    def _inset(self, img, position, k: float = 1.0, cars=(), vehicle: bool = False) -> None:
        """The top view: the map's lights (yellow), the camera or host (white cross) and the cars
        ahead placed on the road map (`cars`: (x, y, zone), a dot in the zone's colour); a
        `vehicle` view shows the host's surroundings only."""
        if self._pts is None:
            return
        ox, oy, iw, ih = _inset_box(img.shape, k)
        m = min(int(8 * k), iw // 6, ih // 6)   # margin inside the frame, px (the dots' room)
        roi = img[oy:oy + ih, ox:ox + iw]
        roi[:] = (roi * 0.35).astype(np.uint8)
        cv2.rectangle(img, (ox, oy), (ox + iw - 1, oy + ih - 1), WHITE, max(1, int(round(k / 2))))
        pts = self._pts
        extra = ([[position["x"], position["y"]]] if position is not None else []) + [[x, y] for x, y, _ in cars]
        if vehicle and position is not None:
            # the host's surroundings (a road map is hundreds of metres long): the host, the cars
            # ahead and the lights within VEHICLE_VIEW_M
            here = np.array([position["x"], position["y"]], np.float64)
            near = np.abs(pts - here).max(axis=1) <= VEHICLE_VIEW_M
            pts = np.vstack((pts[near], extra, here - VEHICLE_VIEW_M / 4, here + VEHICLE_VIEW_M / 4))
        elif extra:
            pts = np.vstack((pts, extra))
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        scale = min((iw - 2 * m) / max(hi[0] - lo[0], 1e-6), (ih - 2 * m) / max(hi[1] - lo[1], 1e-6))
        mid = (lo + hi) / 2   # drawn at the inset's centre

        def at(x, y):
            return int(ox + iw / 2 + (x - mid[0]) * scale), int(oy + ih / 2 - (y - mid[1]) * scale)
        for x, y in self._pts:
            if lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]:
                cv2.circle(img, at(x, y), max(2, int(2 * k)), YELLOW, -1)
        for x, y, zone in cars:
            cv2.circle(img, at(x, y), max(3, int(4 * k)), ZONE_COLOURS.get(zone, WHITE), -1)
        if position is not None:
            cv2.drawMarker(img, at(position["x"], position["y"]), WHITE if cars else RED, cv2.MARKER_CROSS,
                           int(10 * k), max(2, int(2 * k)))

    def annotate(self, gray: np.ndarray, res) -> np.ndarray:
        """The annotated BGR frame."""
        img = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR) if gray.ndim == 2 else gray.copy()
        k = scale_for((img.shape[1], img.shape[0]))
        th = max(1, int(round(k)))  # line thickness
        font = cv2.FONT_HERSHEY_SIMPLEX
        labels = _Labels()
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
        # the text block and the inset are kept free of the lights' labels
        for i, t in enumerate(lines):
            labels.reserve(t[0] if isinstance(t, tuple) else t, (int(8 * k), int((18 + 16 * i) * k)), 0.45 * k, th)
        if self._pts is not None:
            ox, oy, iw, ih = _inset_box(img.shape, k)
            labels.boxes.append((ox, oy, ox + iw, oy + ih))
        pairs = getattr(res, "pairs", ()) or ()
        ranges = {}   # S2-PSK ID -> its range (m), for the pair's label
        for led in getattr(res, "leds", []) or []:
            c = np.asarray(led.contour, np.float64).reshape(-1, 2)
            colour = GREEN if led.id is not None else YELLOW
            if c.size:
                cv2.polylines(img, [np.round(c).astype(np.int32)], True, colour, th, cv2.LINE_AA)
            if led.mode == "s2psk" and pairs:
                # an emitter of a pair: the pair's one label names its ID and range
                if led.id is not None and led.distance_m is not None:
                    ranges.setdefault(led.id, led.distance_m)
                continue
            label = f"#{led.track}" + (f" id {led.id}" if led.id is not None else "")
            if led.distance_m is not None:
                label += f" {led.distance_m:.2f} m"
            y0 = int(c[:, 1].min()) - 4 if c.size else int(led.cy)
            labels.put(img, label, (int(led.cx - 30 * k), max(y0, int(10 * k))), 0.4 * k, colour, th)
        for pr in pairs:
            a = tuple(int(round(v)) for v in pr.a_px)
            b = tuple(int(round(v)) for v in pr.b_px)
            cv2.line(img, a, b, CYAN, th, cv2.LINE_AA)
            txt = f"{pr.kind or ''} {pr.led_id}" if pr.led_id is not None else "pair"
            if pr.led_id in ranges:
                txt += f" {ranges[pr.led_id]:.1f} m"
            labels.put(img, txt, ((a[0] + b[0]) // 2, (a[1] + b[1]) // 2 - int(6 * k)), 0.4 * k, CYAN, th)
        for i, t in enumerate(lines):
            text, colour = t if isinstance(t, tuple) else (t, WHITE)
            cv2.putText(img, text, (int(8 * k), int((18 + 16 * i) * k)), font, 0.45 * k, colour, th, cv2.LINE_AA)
        hv = (veh or {}).get("hv") if isinstance(veh, dict) else None
        cars = [(fv["road_x"], fv["road_y"], fv.get("zone")) for fv in ((veh or {}).get("fv") or [])
                if isinstance(veh, dict) and fv.get("road_x") is not None and fv.get("road_y") is not None]
        self._inset(img, pos if pos else hv, k, cars, vehicle=bool(hv) and not pos)
        return img


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
        self._annotator = Annotator(led_map)
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

    def annotate(self, gray: np.ndarray, res) -> np.ndarray:
        """The annotated BGR frame (`Annotator.annotate`)."""
        return self._annotator.annotate(gray, res)

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


# The live window's picture is at most this size (px, w x h): a 33 MP photo is shown scaled down.
WINDOW_MAX = (1280, 800)


class LiveWindow:
    """A window showing each frame annotated (`occloc run SOURCE --show`), drawn with Tk (the
    standard library's; this OpenCV is built without a GUI). InputError when there is no display
    to open it on. Closing the window stops the showing, not the run."""

    def __init__(self, led_map=None, title: str = "occloc"):
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise InputError("--show needs a display (DISPLAY is not set): use --overlay FILE to write "
                             "the picture instead")
        try:
            import tkinter
            self._root = tkinter.Tk()
        except Exception as e:   # no tkinter, or Tk cannot reach the display
            raise InputError(f"--show cannot open a window ({str(e).splitlines()[0] if str(e) else type(e).__name__}): "
                             f"use --overlay FILE to write the picture instead") from None
        self._root.title(title)
        self._label = tkinter.Label(self._root)
        self._label.pack()
        self._photo = None
        self.open = True
        self._root.protocol("WM_DELETE_WINDOW", self.close)
        self._annotator = Annotator(led_map)

    def write(self, gray: np.ndarray, frame_result) -> None:
        """Show this frame annotated (nothing once the window is closed)."""
        if not self.open:
            return
        import base64
        import tkinter
        img = self._annotator.annotate(gray, frame_result)
        h, w = img.shape[:2]
        f = min(1.0, WINDOW_MAX[0] / w, WINDOW_MAX[1] / h)
        if f < 1.0:
            img = cv2.resize(img, (max(1, int(w * f)), max(1, int(h * f))), interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            return
        try:
            self._photo = tkinter.PhotoImage(data=base64.b64encode(buf.tobytes()))
            self._label.configure(image=self._photo)
            self._root.update()
        except tkinter.TclError:   # the window went away
            self.open = False

    def close(self) -> None:
        if self.open:
            self.open = False
            try:
                self._root.destroy()
            except Exception:
                pass
