"""`occloc run`: frames in, one JSON line per frame out (INTERFACES.md "Receiver command line").

SOURCE picks the frame source (receiver.io.sources); camera and map come from the recording folder
or --camera/--map. Frames whose size differs from the camera file: a 90-degree-rotated still
(portrait photo of a landscape sensor) is turned back so that image rows are sensor rows again
(assumed: portrait = sensor turned clockwise); another size with the same aspect ratio scales
the camera (`CameraModel.scaled`); anything else is an error.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import time

# Nothing heavy at module level: `occloc run --help` and the argument set-up (`add_arguments`)
# must not load OpenCV, numpy or the pipeline; `_main` imports what a run needs.
from receiver.cli.args import seconds_up_to
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
    p.add_argument("--fps", type=float, metavar="F", help="frame rate for timestamps of images and pipes")
    p.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames")
    p.add_argument("--odometry", metavar="FILE",
                   help='vehicle scenes: host speed log, JSON lines {"t": s, "speed_mps": v}')
    p.add_argument("--overlay", metavar="FILE",
                   help="write the frames annotated with what the receiver saw: a video (.avi), "
                        "or the last frame as a PNG (.png, e.g. for a photo)")
    p.add_argument("--settings-out", metavar="FILE",
                   help="write the exact settings this run used (every stage's, as JSON) to FILE")
    p.add_argument("--server", metavar="udp://HOST:PORT",
                   help="solve positions on a lighting server (occloc serve); ranging stays here")
    p.add_argument("--server-timeout", type=seconds_up_to(60.0), default=None, metavar="S",
                   help="longest wait for a server's reply to a frame (default 0.2 s); a frame "
                        "without one has no position and is counted in the summary")
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


def make_positioner(camera, led_map, server: str | None = None, server_timeout_s: float | None = None):
    """receiver.locate.indoor.Positioner when that module is available, else None; with `server`
    (udp://HOST:PORT) a receiver.serve.client.RemotePositioner that solves on that lighting server
    (waiting `server_timeout_s` for a reply, default the client's)."""
    if server is not None:
        from receiver.serve.client import RemotePositioner
        kw = {} if server_timeout_s is None else {"timeout_s": server_timeout_s}
        return RemotePositioner(camera, led_map, server, **kw)
    try:
        from receiver.locate.indoor import Positioner
    except ImportError:
        return None
    return Positioner(camera, led_map)


def make_vehicle_locator(camera, led_map):
    """receiver.locate.vehicle.VehicleLocator for maps with S2-PSK street lights or a taillight
    block (the vehicle scenes), else None."""
    if not (led_map.by_mode("s2psk") or led_map.taillight is not None):
        return None
    from receiver.locate.vehicle import VehicleLocator
    return VehicleLocator(camera, led_map)


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


def _open_overlay(path: str | None, cam, led_map):
    """(OverlayWriter on a temporary sibling of `path`, path) or None; renamed into place by
    `_close_overlay` (a crash never leaves a half video under the name asked for)."""
    if not path:
        return None
    from receiver.io.overlay import OverlayWriter
    folder, name = os.path.split(os.path.abspath(path))
    stem, ext = os.path.splitext(name)
    tmp = os.path.join(folder, f".{stem}.{os.getpid()}.tmp{ext or '.avi'}")
    return OverlayWriter(tmp, (cam.width, cam.height), cam.fps, cam, led_map), tmp, path


def _close_overlay(overlay, ok: bool) -> None:
    writer, tmp, path = overlay
    writer.close()
    if ok and os.path.exists(tmp):
        os.replace(tmp, path)
    elif os.path.exists(tmp):
        os.unlink(tmp)


def write_settings(path: str, rx) -> None:
    """The receiver's resolved settings and its locators', as one JSON object, written to a
    temporary file renamed into place."""
    from receiver.core.settings import settings_json
    from receiver.io.files import AtomicWriter, dumps

    loc = getattr(rx.positioner, "local", rx.positioner)  # a server client ranges locally
    obj = {"receiver": settings_json(rx.settings),
           "locate": settings_json(loc.settings) if getattr(loc, "settings", None) is not None else None,
           "vehicle": settings_json(rx.vehicle.s) if rx.vehicle is not None else None}
    out = AtomicWriter(path)
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
    from receiver.io.output import RunSummary, frame_line
    from receiver.pipeline import Receiver
    from receiver.io.camera import fit_camera
    from receiver.io.sources import default_source, find_recording_files, open_source, parse_size

    from receiver.io.files import AtomicWriter, refuse_overwrite

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
    if server is not None:
        from receiver.serve.client import parse_udp_url
        parse_udp_url(server)          # a bad URL is an error before any work
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
    refuse_overwrite(args.out, inputs, "--out")
    refuse_overwrite(getattr(args, "settings_out", None), inputs + [args.out], "--settings-out")
    refuse_overwrite(getattr(args, "overlay", None), inputs + [args.out, getattr(args, "settings_out", None)],
                     "--overlay")
    cam = load_camera(cam_path)
    led_map = load_map(map_path)
    if not cam.rolling_shutter and (led_map.by_mode("ook") or led_map.by_mode("tone") or led_map.addressing == "xy"):
        raise InputError(f"{cam_path}: row_readout_us 0 (global shutter), but the map has OOK or tone "
                         f"lights, which need a rolling shutter (give the sensor's row readout time)")
    if args.fps is not None:
        cam = dataclasses.replace(cam, fps=args.fps)
    size = parse_size(args.size)
    n_threads = getattr(args, "threads", DEFAULT_THREADS)
    src = open_source(spec, size=size, pix_fmt=args.pix_fmt, realtime=args.realtime, camera=cam,
                      threads=n_threads)
    try:
        if src.size is None:
            raise InputError(f"{spec}: frame size unknown")
        cam, rotate = fit_camera(cam, src.size)
        if rotate:
            print(f"occloc: {spec}: frames are {src.size[0]}x{src.size[1]}, the camera "
                  f"{cam.width}x{cam.height}: turning them back to sensor orientation", file=sys.stderr)
        # Without --server the two-argument call of older make_positioner replacements (tests).
        positioner = (make_positioner(cam, led_map, server=server,
                                      server_timeout_s=getattr(args, "server_timeout", None)) if server
                      else make_positioner(cam, led_map))
        vehicle = make_vehicle_locator(cam, led_map)
        speed = None
        if getattr(args, "odometry", None):
            from receiver.io.odometry import load_odometry
            speed = load_odometry(args.odometry)
        rx = Receiver(cam, led_map, positioner=positioner, vehicle=vehicle, speed=speed, still=src.is_still)
        for readable, note in rx.policy.exposure_notes():
            if not readable:  # known before the first frame: say so at once
                print(f"occloc: warning: {note}", file=sys.stderr)
        if getattr(args, "settings_out", None):
            write_settings(args.settings_out, rx)
        # A file is written to a temporary sibling and renamed into place at the end (also after
        # a stop signal); standard output streams line by line.
        out = AtomicWriter(args.out) if args.out else sys.stdout
        summary = RunSummary()
        total = getattr(getattr(src, "inner", src), "frame_count", None) or None
        if args.max_frames is not None and total:
            total = min(total, args.max_frames)
        progress = Progress(sys.stderr, total)
        frames = _rotated(src) if rotate else src
        overlay = _open_overlay(getattr(args, "overlay", None), cam, led_map)
        ok = False
        try:
            for frame in _frames_until_stopped(frames, stop):
                if args.max_frames is not None and summary.frames >= args.max_frames:
                    break
                res = rx.process(frame)
                if overlay is not None:
                    overlay[0].write(frame.gray, res)
                out.write(frame_line(res, profile=args.profile) + "\n")
                if out is sys.stdout and args.realtime:
                    out.flush()
                summary.add(res)
                progress.update(summary.frames, len(summary.ids))
            ok = True
        finally:
            progress.done()
            if hasattr(positioner, "close"):
                positioner.close()
            if overlay is not None:
                _close_overlay(overlay, ok)
            if out is not sys.stdout:
                out.commit() if ok else out.discard()
            else:
                out.flush()
        if cam.exposure_us <= 0:  # learned during the run (before the summary: it stays the last line)
            for readable, note in rx.policy.exposure_notes():
                print(f"occloc: {'' if readable else 'warning: '}{note}", file=sys.stderr)
        hv_reason = vehicle.run_reason() if vehicle is not None else None
        fv_reason = getattr(vehicle, "fv_reason", None) if vehicle is not None else None
        print("occloc: " + summary.text(skipped=src.skipped, dropped=src.dropped, truncated=src.truncated,
                                        hv_reason=hv_reason)
              + (f"; forward vehicles not ranged ({fv_reason})" if fv_reason else "")
              + (f"; {speed.note()}" if speed is not None and speed.note() else "") + f"; threads: {n_threads}"
              + _server_text(positioner), file=sys.stderr)
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
    return 0
