"""`occloc run`: frames in, one JSON line per frame out (INTERFACES.md "Receiver command line").

SOURCE picks the frame source (receiver.io.sources); camera and map come from the recording folder
or --camera/--map. Frames whose size differs from the camera file: a 90-degree-rotated still
(portrait photo of a landscape sensor) is turned back so that image rows are sensor rows again
(assumed: portrait = sensor turned clockwise); another size with the same aspect ratio scales
the camera (`CameraModel.scaled`); anything else is an error.

Photos (an image, or a folder of images) are independent observations: each is fitted to the
camera on its own (orientation and size), located by a receiver of its own (no tracking or
Kalman filter across photos), and its line names it (`"file"`). A photo sequence to be tracked
is a video. A frame without a position says why in `"no_fix"` (`no_fix_reason`), and the summary
counts the reasons.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import time

# Nothing heavy at module level: `occloc run --help` and the argument set-up (`add_arguments`)
# must not load OpenCV, numpy or the pipeline; `_main` imports what a run needs.
from receiver.cli.args import MAX_FRAMES, MAX_PIXELS, number_in, seconds_up_to, whole_in
from receiver.core.budget import DEFAULT_THREADS, limit_blas_threads, threads

HELP = "receive LEDs from a recording, video, photos, raw pipe or camera: JSON lines per frame"
# Without a tty, a progress line every this many frames.
PROGRESS_EVERY_FRAMES = 100
# Seconds between redraws of the tty progress line.
PROGRESS_REDRAW_S = 0.2
# Upper bound of --threads (a typo like 1000 would start that many OpenCV workers).
MAX_THREADS = 256


def add_arguments(p) -> None:
    p.add_argument("source", nargs="?", metavar="SOURCE",
                   help="recording folder, video file, image or image folder, '-' (raw frames on stdin) "
                        "or /dev/videoN (default: the bundled recordings/indoor-walk)")
    p.add_argument("--camera", metavar="FILE", help="camera.yaml (default: the recording's)")
    p.add_argument("--map", metavar="FILE", help="LED map.json (default: the recording's)")
    p.add_argument("--out", metavar="FILE", help="write JSON lines here instead of standard output")
    p.add_argument("--realtime", action="store_true",
                   help="always process the newest frame; frames that arrive meanwhile are dropped and counted")
    p.add_argument("--size", metavar="WxH", help="frame size of raw frames on stdin (or to request from a camera)")
    p.add_argument("--pix-fmt", choices=("gray", "bgr24"), default=None, help="raw frame format on stdin (gray)")
    p.add_argument("--profile", action="store_true", help="add per-stage milliseconds (stage_ms) to each line")
    p.add_argument("--fps", type=number_in(*FPS_RANGE, "frames/s"), metavar="F", help="frame rate for timestamps of images and pipes")
    p.add_argument("--max-frames", type=whole_in(0, MAX_FRAMES), metavar="N", help="stop after N frames")
    p.add_argument("--max-pixels", type=whole_in(1, MAX_PIXELS), default=None, metavar="N",
                   help="largest photo or raw frame, width x height, checked before decoding "
                        "(default 200,000,000: the largest phone sensors)")
    p.add_argument("--odometry", metavar="FILE",
                   help='vehicle scenes: host speed log, JSON lines {"t": s, "speed_mps": v}')
    p.add_argument("--overlay", metavar="FILE",
                   help="write the frames annotated with what the receiver saw: a video (.mp4 H.264, "
                        ".avi MJPG, .mkv FFV1), or the last frame as an image (.png, .jpg: e.g. a photo)")
    p.add_argument("--show", action="store_true",
                   help="show the frames annotated live in a window (where a display exists)")
    p.add_argument("--settings-out", metavar="FILE",
                   help="write the exact settings this run used (every stage's, as JSON) to FILE")
    p.add_argument("--settings", metavar="FILE",
                   help="run with the settings of FILE (what --settings-out writes; a stage or field "
                        "left out keeps its default)")
    p.add_argument("--server", metavar="udp://HOST:PORT",
                   help="solve positions on a lighting server (occloc serve), which gets the frame's "
                        "decoded LEDs and outlines and gives the local run's positions")
    p.add_argument("--server-timeout", type=seconds_up_to(60.0), default=None, metavar="S",
                   help="longest wait for a server's reply to a frame (default 0.2 s); a frame "
                        "without one has no position and is counted in the summary")
    p.add_argument("--key-file", metavar="FILE",
                   help="this device's name and key (one 'DEVICE HEXKEY' line) for a server with "
                        "device keys: every datagram is signed")
    p.add_argument("--threads", type=_threads, default=DEFAULT_THREADS, metavar="N",
                   help=f"threads for OpenCV, video decoding and numpy's BLAS (default {DEFAULT_THREADS}: "
                        f"the frame budget is stated for one core)")


def _threads(text: str) -> int:
    import argparse
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= MAX_THREADS:
        raise argparse.ArgumentTypeError(f"must be a whole number 1..{MAX_THREADS}, not {text!r}")
    return n


def _rotated(source):
    import cv2
    from receiver.core.records import Frame
    for f in source:
        yield Frame(f.index, f.t_s, cv2.rotate(f.gray, cv2.ROTATE_90_COUNTERCLOCKWISE))


def _fit_photo(cam, gray, exposure_us: float | None = None):
    """(camera fitted to one photo, the photo in sensor orientation): a photo whose long side is
    not the camera's is turned back first, then the camera is scaled to its size
    (`fit_camera`: InputError when the aspect ratio is not the camera's). `exposure_us`: the
    photo's own shutter time (its EXIF), which replaces the camera file's."""
    import dataclasses
    from receiver.io.camera import fit_camera
    from receiver.io.imagefile import to_camera_orientation
    gray, _ = to_camera_orientation(gray, cam.width, cam.height)
    fitted, _ = fit_camera(cam, (gray.shape[1], gray.shape[0]))
    if exposure_us is not None:
        fitted = dataclasses.replace(fitted, exposure_us=float(exposure_us))
    return fitted, gray


def _photo_exposure_notes(rx, name: str, exposure_us: float) -> list[str]:
    """The exposure verdicts (receiver.decode.exposure.exposure_verdict) of one photo's EXIF
    shutter time against the map's OOK chip rates, for those it is too long for."""
    from receiver.decode.exposure import exposure_verdict
    out = []
    for rate in rx.policy.plan.ook_rates:
        ok, text = exposure_verdict(exposure_us, rate)
        if not ok:
            out.append(f"{name}: {text} (the photo's EXIF)")
    return out


# `no_fix` values of frames without a position that the positioner itself does not explain
# (see receiver.locate.indoor.Positioner.last_reason for the others).
NO_LED = "no LED seen"
NO_ID = "no decoded ID"
NO_REPLY = "no server position"


def no_fix_reason(res, positioner) -> str | None:
    """Why a frame has no position, in a few words (None when it has one, or when the map has no
    light to position by: vehicle scenes). The positioner's own reason (`last_reason`: too few
    LEDs, handedness undecided, solver rejected ...) when it gives one, else what the frame shows."""
    if res.position is not None or positioner is None:
        return None
    reason = getattr(positioner, "last_reason", None)
    if reason:
        return reason
    indoor = [o for o in res.leds if o.mode != "s2psk"]
    if not indoor:
        return NO_LED
    if all(o.id is None for o in indoor):
        return NO_ID
    return NO_REPLY if hasattr(positioner, "timeouts") else "no position"


# What `--out` may be called: the run writes JSON Lines, nothing else (no extension: e.g. /dev/null).
OUT_EXTENSIONS = (".jsonl", ".ndjson", ".json", ".txt", ".log", "")
# Formats `occloc export` converts a run to, by the extension a user might give --out.
EXPORT_HINT = {".csv": "csv", ".tum": "tum", ".geojson": "geojson"}


def _check_out_extension(path: str | None) -> None:
    from receiver.core.errors import InputError
    if path is None:
        return
    ext = os.path.splitext(path)[1].lower()
    if ext in OUT_EXTENSIONS:
        return
    fmt = EXPORT_HINT.get(ext)
    hint = (f": write run.jsonl, then `occloc export run.jsonl --format {fmt} --out {os.path.basename(path)}`"
            if fmt else "")
    raise InputError(f"--out {path}: occloc run writes JSON Lines (.jsonl), not {ext}{hint}")


def _handedness_hint(summary, led_map, told: dict | None = None) -> str:
    """The summary's advice when frames had no position because the map's handedness could not
    be told from them ('' otherwise). `told`: handedness -> the first photo (or frame) that told
    it (each photo has a receiver of its own, so one photo's answer does not reach another)."""
    if not summary.no_fix.get("handedness undecided") or led_map.handedness is not None:
        return ""
    if told and len(told) == 1:
        (hand, where), = told.items()
        return (f'; the map does not say its handedness; {where} tells it is {hand}-handed: add '
                f'"handedness": "{hand}" to the map')
    return ('; the map does not say its handedness and no photo/frame could tell it (both fits poor): '
            'add "handedness": "left" or "right" to the map')


def _told_handedness(positioner) -> str | None:
    """The handedness a receiver's positioner detected from its frames (None: not detected)."""
    pose = getattr(positioner, "pose", None)
    if getattr(pose, "handedness_source", None) == "detected":
        return pose.handedness
    return None


def _indoor_lights(led_map) -> bool:
    """Does the map have lights a position can be solved from (not only S2-PSK / taillights)?"""
    return any(led.mode != "s2psk" for led in led_map.leds.values())


def make_positioner(camera, led_map, server: str | None = None, server_timeout_s: float | None = None,
                    settings=None, key_file: str | None = None):
    """receiver.locate.indoor.Positioner when that module is available, else None; with `server`
    (udp://HOST:PORT) a receiver.serve.client.RemotePositioner that solves on that lighting server
    (waiting `server_timeout_s` for a reply, default the client's). `settings`: PositionerSettings
    (None: the defaults)."""
    if server is not None:
        from receiver.serve.client import RemotePositioner
        kw = {} if server_timeout_s is None else {"timeout_s": server_timeout_s}
        if key_file is not None:
            from receiver.serve.auth import load_device_key
            kw["device"], kw["key"] = load_device_key(key_file)
        return RemotePositioner(camera, led_map, server, report=lambda line: print(line, file=sys.stderr, flush=True),
                                **kw)
    try:
        from receiver.locate.indoor import Positioner
    except ImportError:
        return None
    return Positioner(camera, led_map, settings=settings)


def make_vehicle_locator(camera, led_map, settings=None):
    """receiver.locate.vehicle.VehicleLocator for maps with S2-PSK street lights or a taillight
    block (the vehicle scenes), else None. `settings`: VehicleSettings (None: the defaults)."""
    if not (led_map.by_mode("s2psk") or led_map.taillight is not None):
        return None
    from receiver.locate.vehicle import VehicleLocator
    return VehicleLocator(camera, led_map) if settings is None else VehicleLocator(camera, led_map, settings)


def read_settings(path: str) -> dict:
    """{'receiver': ReceiverSettings or None, 'locate': PositionerSettings or None, 'vehicle':
    VehicleSettings or None} of a file `write_settings` wrote (a stage it leaves out: None)."""
    from receiver.core.errors import InputError
    from receiver.core.settings import settings_from_json
    from receiver.io.files import load_json
    from receiver.locate.settings import PositionerSettings, VehicleSettings
    from receiver.pipeline import ReceiverSettings

    obj = load_json(path, "settings")
    if not isinstance(obj, dict):
        raise InputError(f"{path}: expected the JSON object --settings-out writes")
    classes = {"receiver": ReceiverSettings, "locate": PositionerSettings, "vehicle": VehicleSettings}
    unknown = sorted(set(obj) - set(classes))
    if unknown:
        raise InputError(f"{path}: unknown stage {unknown[0]!r} (expected receiver, locate, vehicle)")
    return {k: settings_from_json(cls, obj[k], f"{path}: {k}") if obj.get(k) is not None else None
            for k, cls in classes.items()}


def _server_text(positioner) -> str:
    """The summary's note on a lighting server's missing replies ('' when there were none)."""
    timeouts, errors = getattr(positioner, "timeouts", 0), getattr(positioner, "errors", 0)
    text = f"; server timeouts: {timeouts}" if timeouts else ""
    if errors:
        text += f"; server errors: {errors} (last: {positioner.last_error})"
    return text


class Progress:
    """One updating line on a tty, or a line every `every` frames otherwise."""

    def __init__(self, stream, total: int | None = None, every: int = PROGRESS_EVERY_FRAMES,
                 clock=time.monotonic):
        self.stream, self.total, self.every, self.clock = stream, total, every, clock
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self._last = -1e9
        self._drawn = False

    def update(self, n: int, ids: int) -> None:
        of = f"/{self.total}" if self.total else ""
        if self.tty:
            now = self.clock()
            if now - self._last >= PROGRESS_REDRAW_S:
                self.stream.write(f"\rframe {n}{of}, {ids} IDs decoded")
                self.stream.flush()
                self._last, self._drawn = now, True
        elif n % self.every == 0:
            self.stream.write(f"frame {n}{of}, {ids} IDs decoded\n")

    def done(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")


# Signals that stop a run cleanly: the frame loop ends, whole lines are flushed, the summary is
# printed and the exit status is 128 + the signal's number.
STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))
FPS_RANGE = (0.1, 10_000.0)


class StopRun(BaseException):
    """Raised by the stop-signal handler while the frame loop waits for a frame."""


class SignalStop:
    """Turns SIGINT/SIGTERM/SIGHUP into a clean stop of the frame loop. While the loop waits
    for a frame (`waiting`), the handler raises StopRun so that a blocked read ends; while a
    frame is processed or its line written, it only sets `signum` and the loop stops after
    the line (a line is never cut)."""

    def __init__(self):
        self.signum: int | None = None
        self.waiting = False
        self._old = {}

    def _handler(self, signum, frame):
        self.signum = signum
        if self.waiting:
            raise StopRun()

    def __enter__(self):
        import threading
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                try:
                    if sig != signal.SIGTERM and signal.getsignal(sig) is signal.SIG_IGN:
                        continue  # nohup / a background job: an ignored SIGINT/SIGHUP stays ignored
                    self._old[sig] = signal.signal(sig, self._handler)
                except (OSError, ValueError):
                    pass
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


def _frames_until_stopped(frames, stop: SignalStop):
    it = iter(frames)
    while stop.signum is None:
        stop.waiting = True
        try:
            if stop.signum is not None:
                return
            frame = next(it)
        except (StopIteration, StopRun):
            return
        finally:
            stop.waiting = False
        yield frame


def _open_overlay(output, cam, led_map):
    """(OverlayWriter on a staging file of `output` (receiver.io.files.Output), tmp, output) or
    None; moved into place by `_close_overlay` (a crash never leaves a half video under the name
    asked for)."""
    if output is None:
        return None
    from receiver.io.overlay import OverlayWriter
    ext = os.path.splitext(output.path)[1] or ".avi"
    tmp = output.staging_path(ext)
    try:
        return OverlayWriter(tmp, (cam.width, cam.height), cam.fps, cam, led_map), tmp, output
    except BaseException:
        output.discard_staged(tmp)
        raise


def _close_overlay(overlay, ok: bool) -> None:
    writer, tmp, output = overlay
    try:
        writer.close()
    except BaseException as e:
        output.discard_staged(tmp)
        if isinstance(e, OSError):
            raise output.error(e) from None
        if type(e).__name__ == "InputError":
            raise type(e)(f"cannot write {output.flag} {output.path}: {e}") from None
        raise
    if ok:
        output.commit_staged(tmp)
    else:
        output.discard_staged(tmp)


def write_settings(path, rx) -> None:
    """The receiver's resolved settings and its locators', as one JSON object, written to
    `path` (a receiver.io.files.Output, or a file name) through a temporary file renamed into
    place."""
    from receiver.core.settings import settings_json
    from receiver.io.files import AtomicWriter, dumps

    loc = getattr(rx.positioner, "local", rx.positioner)  # a server client ranges locally
    obj = {"receiver": settings_json(rx.settings),
           "locate": settings_json(loc.settings) if getattr(loc, "settings", None) is not None else None,
           "vehicle": settings_json(rx.vehicle.s) if rx.vehicle is not None else None}
    out = path.open() if hasattr(path, "open") else AtomicWriter(path)
    try:
        out.write(dumps(obj, indent=1, sort_keys=True) + "\n")
        out.commit()
    except BaseException:
        out.discard()
        raise


def main(args) -> int:
    # Stop signals are caught from the start: one that comes before the first frame ends the
    # run with an empty output and the summary, like one that comes later.
    n = getattr(args, "threads", DEFAULT_THREADS)
    limit_blas_threads(n)  # before numpy's first import (no effect when run in-process after it)
    with SignalStop() as stop, threads(n):
        return _main(args, stop)


def _main(args, stop: "SignalStop") -> int:
    import dataclasses
    from receiver.io.camera import load_camera
    from receiver.io.ledmap import load_map
    from receiver.core.errors import InputError
    import numpy as np
    from receiver.core.records import Frame
    from receiver.io.output import RunSummary, frame_line, with_fields
    from receiver.pipeline import Receiver
    from receiver.io.camera import fit_camera
    from receiver.io.sources import default_source, find_recording_files, open_source, parse_size

    from receiver.io.files import StdoutOutput, claim_output

    if args.source == "":  # e.g. `occloc run "$REC"` with REC unset: not the bundled recording
        raise InputError("empty source name: give a recording folder, video, photo, photo folder or -")
    spec = args.source or default_source()
    if args.max_frames is not None and args.max_frames < 0:
        raise InputError("--max-frames must not be negative")
    if args.fps is not None and not (math.isfinite(args.fps) and FPS_RANGE[0] <= args.fps <= FPS_RANGE[1]):
        raise InputError(f"--fps must be within {FPS_RANGE[0]:g}..{FPS_RANGE[1]:g}, not {args.fps:g}")
    if args.out is None and sys.stdout is None:
        raise InputError("standard output is closed: give --out FILE")
    if spec == "-" and sys.stdin is None:
        raise InputError("standard input is closed: nothing to read frames from")
    server = getattr(args, "server", None)
    if server is None and getattr(args, "server_timeout", None) is not None:
        raise InputError("--server-timeout needs --server udp://HOST:PORT")
    if server is None and getattr(args, "key_file", None) is not None:
        raise InputError("--key-file needs --server udp://HOST:PORT")
    if server is not None:
        from receiver.serve.client import parse_udp_url
        parse_udp_url(server)          # a bad URL is an error before any work
        if getattr(args, "key_file", None) is not None:
            from receiver.serve.auth import load_device_key
            load_device_key(args.key_file)
    if spec != "-" and not spec.startswith("/dev/video") and not os.path.exists(spec):
        raise InputError(f"no such file or folder: {spec}")
    rec = find_recording_files(spec) if spec != "-" and os.path.isdir(spec) else {}
    cam_path = args.camera or rec.get("camera")
    map_path = args.map or rec.get("map")
    if cam_path is None:
        raise InputError(f"{spec}: no camera file (give --camera FILE)")
    if map_path is None:
        raise InputError(f"{spec}: no LED map (give --map FILE)")
    inputs = [spec, cam_path, map_path, getattr(args, "odometry", None), rec.get("video"), rec.get("truth")]
    inputs.append(getattr(args, "settings", None))
    # What each output is (an input, a folder, another output) before what it is called: `--overlay
    # map.json` is refused as the map, not as a wrong extension.
    out_file = claim_output(args.out, inputs, "--out")
    settings_file = claim_output(getattr(args, "settings_out", None), inputs, "--settings-out",
                                 others=[("--out", args.out)])
    overlay_file = claim_output(getattr(args, "overlay", None), inputs, "--overlay",
                                others=[("--out", args.out), ("--settings-out", getattr(args, "settings_out", None))])
    _check_out_extension(args.out)
    if getattr(args, "overlay", None):
        from receiver.io.overlay import check_overlay_path
        check_overlay_path(args.overlay)
    given = (read_settings(args.settings) if getattr(args, "settings", None)
             else {"receiver": None, "locate": None, "vehicle": None})
    cam = load_camera(cam_path)
    led_map = load_map(map_path)
    window = None
    if getattr(args, "show", False):   # a display to show on, before any work
        from receiver.io.overlay import LiveWindow
        window = LiveWindow(led_map, f"occloc run {spec}")
    if not cam.rolling_shutter and (led_map.by_mode("ook") or led_map.by_mode("tone") or led_map.addressing == "xy"):
        raise InputError(f"{cam_path}: row_readout_us 0 (global shutter), but the map has OOK or tone "
                         f"lights, which need a rolling shutter (give the sensor's row readout time)")
    if args.fps is not None:
        cam = dataclasses.replace(cam, fps=args.fps)
    size = parse_size(args.size)
    n_threads = getattr(args, "threads", DEFAULT_THREADS)
    src = open_source(spec, size=size, pix_fmt=args.pix_fmt, realtime=args.realtime, camera=cam,
                      threads=n_threads, max_pixels=getattr(args, "max_pixels", None))
    images = getattr(src, "inner", src)
    photos = images.kind == "images"   # independent photos: --realtime has nothing to drop
    first = None   # the first readable photo
    try:
        if photos and src.size is None:
            first = next(images.photos(), None)
            if first is None:
                raise InputError(f"{spec}: no readable image")
            images.size = (first.gray.shape[1], first.gray.shape[0])
        if src.size is None:
            raise InputError(f"{spec}: frame size unknown")
        cam0 = cam
        exif_us = {}   # photo index -> its EXIF shutter time (us), where it records one
        first_index = None
        if photos:
            from receiver.io.imagefile import exif_exposure_us

            def photo_exposure(index):
                if index not in exif_us:
                    exif_us[index] = exif_exposure_us(images.files[index])
                return exif_us[index]
            first_index = first.index if first is not None else 0
            cam, _ = _fit_photo(cam0, np.zeros(src.size[::-1], np.uint8), photo_exposure(first_index))
            rotate = False
        else:
            cam, rotate = fit_camera(cam, src.size)
        if rotate:
            print(f"occloc: {spec}: frames are {src.size[0]}x{src.size[1]}, the camera "
                  f"{cam.width}x{cam.height}: turning them back to sensor orientation", file=sys.stderr)
        speed = None
        if getattr(args, "odometry", None):
            from receiver.io.odometry import load_odometry
            speed = load_odometry(args.odometry)
        timeout = getattr(args, "server_timeout", None)

        def build(c):
            # Without --server or --settings the two-argument call of older make_positioner
            # replacements (tests).
            if server:
                pos = make_positioner(c, led_map, server=server, server_timeout_s=timeout,
                                      key_file=getattr(args, "key_file", None))
            elif given["locate"] is not None:
                pos = make_positioner(c, led_map, settings=given["locate"])
            else:
                pos = make_positioner(c, led_map)
            veh = (make_vehicle_locator(c, led_map, settings=given["vehicle"]) if given["vehicle"] is not None
                   else make_vehicle_locator(c, led_map))
            return Receiver(c, led_map, positioner=pos, vehicle=veh, speed=speed, still=src.is_still,
                            settings=given["receiver"])

        rx = build(cam)
        positioner, vehicle = rx.positioner, rx.vehicle
        if given["receiver"] is not None:
            # The decoders a light and a pair get, built once before the first frame: decoder
            # settings that do not fit the map's lights (an S2-PSK history shorter than one of its
            # packets) are a one-line error before any work, not a traceback at the first light.
            try:
                rx.policy.new_light()
                rx.policy.new_pair_decoders()
            except ValueError as e:
                raise InputError(f"{args.settings}: {e}") from None
        if not (photos and exif_us.get(first_index)):   # a photo's EXIF is judged photo by photo
            for readable, note in rx.policy.exposure_notes():
                if not readable:  # known before the first frame: say so at once
                    print(f"occloc: warning: {note}", file=sys.stderr)
        if settings_file is not None:
            write_settings(settings_file, rx)
        explain = positioner is not None and _indoor_lights(led_map)
        # A file is written to a temporary sibling and renamed into place at the end (also after
        # a stop signal); standard output streams line by line.
        out = out_file.open() if out_file is not None else StdoutOutput()
        summary = RunSummary()
        told: dict[str, str] = {}   # handedness -> the photo/frame that told it
        notes = None   # the note evidence of the earlier photos' receivers (DecodePolicy.absorb_notes)
        total = len(images.files) if photos else getattr(images, "frame_count", None) or None
        if args.max_frames is not None and total:
            total = min(total, args.max_frames)
        progress = Progress(sys.stderr, total)
        frames = images.photos() if photos else _rotated(src) if rotate else src
        overlay = _open_overlay(overlay_file, cam, led_map)
        ok = False
        try:
            for frame in _frames_until_stopped(frames, stop):
                if args.max_frames is not None and summary.frames >= args.max_frames:
                    break
                fields = {}
                if photos:
                    name = os.path.basename(images.files[frame.index])
                    try:
                        pcam, gray = _fit_photo(cam0, frame.gray, photo_exposure(frame.index))
                    except InputError as e:
                        if len(images.files) == 1:
                            raise InputError(f"{name}: {e}") from None
                        images.skipped += 1
                        print(f"occloc: warning: {name}: {e}: skipped", file=sys.stderr)
                        continue
                    # Every photo gets a fresh receiver (nothing carries over from another photo);
                    # the one built for the settings serves the first photo of its size.
                    if rx.frames or (pcam.width, pcam.height, pcam.exposure_us) != (
                            rx.camera.width, rx.camera.height, rx.camera.exposure_us):
                        if hasattr(positioner, "close"):
                            positioner.close()
                        notes = rx.policy.absorb_notes(notes)  # the notes speak for every photo
                        rx = build(pcam)
                        positioner, vehicle = rx.positioner, rx.vehicle
                    if exif_us.get(frame.index):
                        for note in _photo_exposure_notes(rx, name, exif_us[frame.index]):
                            print(f"occloc: warning: {note}", file=sys.stderr)
                    frame = Frame(frame.index, frame.t_s, gray)
                    fields["file"] = name
                res = rx.process(frame)
                if overlay is not None:
                    overlay[0].write(frame.gray, res)
                if window is not None:
                    window.write(frame.gray, res)
                reason = no_fix_reason(res, positioner) if explain else None
                if reason is not None:
                    fields["no_fix"] = reason
                out.write(with_fields(frame_line(res, profile=args.profile), fields) + "\n")
                if out_file is None and args.realtime:
                    out.flush()
                summary.add(res, no_fix=reason)
                hand = _told_handedness(positioner)
                if hand is not None and hand not in told:
                    told[hand] = fields.get("file") or f"frame {frame.index}"
                progress.update(summary.frames, len(summary.ids))
            ok = True
        finally:
            progress.done()
            if hasattr(positioner, "close"):
                positioner.close()
            if window is not None:
                window.close()
            if overlay is not None:
                _close_overlay(overlay, ok)
            out.commit() if ok else out.discard()
        notes = rx.policy.absorb_notes(notes)
        if cam.exposure_us <= 0:  # learned during the run (before the summary: it stays the last line)
            for readable, note in notes.exposure_notes():
                print(f"occloc: {'' if readable else 'warning: '}{note}", file=sys.stderr)
        for note in notes.chip_notes():  # lights too short in the image for their chips
            print(f"occloc: warning: {note}", file=sys.stderr)
        hv_reason = vehicle.run_reason() if vehicle is not None else None
        fv_reason = getattr(vehicle, "fv_reason", None) if vehicle is not None else None
        print("occloc: " + summary.text(skipped=src.skipped, dropped=src.dropped, truncated=src.truncated,
                                        hv_reason=hv_reason)
              + (f"; forward vehicles not ranged ({fv_reason})" if fv_reason else "")
              + (f"; {speed.note()}" if speed is not None and speed.note() else "") + f"; threads: {n_threads}"
              + _server_text(positioner) + _handedness_hint(summary, led_map, told), file=sys.stderr)
        if stop.signum is not None:
            name = signal.Signals(stop.signum).name
            print(f"occloc: stopped by {name} after {summary.frames} frames", file=sys.stderr)
            return 128 + stop.signum
    except OSError as e:
        if isinstance(e, BrokenPipeError):
            raise
        raise InputError(f"{getattr(e, 'filename', None) or spec}: {e.strerror or e}") from None
    finally:
        src.close()
        if window is not None:
            window.close()
    return 0
