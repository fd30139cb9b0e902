"""`occloc calibrate intrinsics|rows`: set up a real camera's camera.yaml (INTERFACES.md).

* `intrinsics SOURCE --board chess:COLSxROWS --square-mm S --out FILE [--camera EXISTING]`
  (or `--board charuco:COLSxROWS:DICT --marker-mm M`): board views from a video, image folder or
  camera; camera_matrix and distortion_coefficients measured, image size from the frames, and the
  keys calibration does not measure (pixel_size_um, focal_length_mm, row_readout_us,
  exposure_us, fps) kept from EXISTING.
* `rows SOURCE --camera FILE (--freq-hz F | --ook-rate HZ) [--out FILE2] [--map MAP]`: the row
  readout time (and an exposure estimate) from a tone or OOK LED of known rate; written as
  `row_readout_us` into FILE2, or into FILE (replaced atomically) without --out. FILE may have
  no row time yet (0, as `intrinsics` writes without --camera): the physical range 3-60 us is
  searched. With `--map MAP` and no rate, every tone light of the map in view is measured and
  the lights combined (median and spread; a warning when they disagree).

Progress goes to standard error, the result is one JSON line on standard output. Files are written
to a temporary file in the same folder and renamed into place; an input is never overwritten
(except FILE by `rows` without --out, which is the point, unless FILE is read-only: then --out
is needed).
"""

from __future__ import annotations

import dataclasses
import os
import sys

from receiver.cli.args import MAX_FRAMES, number_in, whole_in

HELP = "calibrate a camera: intrinsics from a chess/ChArUco board, row readout time from an LED"

# Fewest board views calibration uses (calibrate_views' min_views): Zhang's method needs three
# in general position for the five intrinsics, one more guards against a degenerate view.
MIN_VIEWS = 4


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="what", metavar="WHAT")
    sub.required = True
    a = sub.add_parser("intrinsics", help="camera matrix and distortion from board views",
                       description="camera matrix and distortion from views of a chessboard or ChArUco board")
    a.add_argument("source", metavar="SOURCE", help="video file, image or image folder, or /dev/videoN")
    a.add_argument("--board", required=True, metavar="SPEC",
                   help="chess:COLSxROWS (inner corners, as OpenCV counts them) or "
                        "charuco:COLSxROWS:DICT (squares, e.g. charuco:7x5:DICT_4X4_50)")
    a.add_argument("--square-mm", type=number_in(0.01, 10_000.0, "mm", low_open=True), required=True, metavar="S", help="square side, mm")
    a.add_argument("--marker-mm", type=number_in(0.01, 10_000.0, "mm", low_open=True), metavar="M", help="ChArUco marker side, mm")
    a.add_argument("--out", required=True, metavar="FILE", help="camera.yaml to write")
    a.add_argument("--camera", metavar="EXISTING",
                   help="camera.yaml whose unmeasured keys (pixel size, focal length, row time, exposure, fps) are kept")
    a.add_argument("--max-frames", type=whole_in(1, MAX_FRAMES), metavar="N", help="look at no more than N frames")
    a.add_argument("--max-views", type=whole_in(MIN_VIEWS, 10_000), default=40, metavar="N",
                   help=f"calibrate on at most N views (40; at least {MIN_VIEWS}: fewer leave the camera matrix unsolved)")
    a.add_argument("--max-blur-px", type=number_in(0.0, 1000.0, "px", low_open=True), default=4.0, metavar="PX",
                   help="reject chessboard views whose edges are wider than this (4 px)")
    a.add_argument("--size", metavar="WxH", help="frame size to request from a camera")
    a.add_argument("--force", action="store_true",
                   help="write a calibration that fails the checks (RMS above 1 px, absurd distortion), "
                        "with a warning, instead of refusing it")
    r = sub.add_parser("rows", help="row readout time (and exposure) from a tone or OOK LED",
                       description="rolling-shutter row readout time from the stripes of an LED of known rate")
    r.add_argument("source", metavar="SOURCE", help="recording folder, video file, images or /dev/videoN")
    r.add_argument("--camera", required=True, metavar="FILE", help="camera.yaml (its row_readout_us is the starting guess)")
    g = r.add_mutually_exclusive_group()
    g.add_argument("--freq-hz", type=number_in(1.0, 1e6, "Hz"), metavar="F", help="a tone LED blinking at F Hz")
    g.add_argument("--ook-rate", type=number_in(1.0, 1e7, "chips/s"), metavar="HZ", help="an OOK LED at HZ chips per second")
    r.add_argument("--out", metavar="FILE2", help="write the camera file here (default: update FILE)")
    r.add_argument("--map", metavar="MAP",
                   help="LED map: warn when the exposure is too long for its chip rates; without --freq-hz "
                        "and --ook-rate, every tone light of the map in view is measured and combined")
    r.add_argument("--max-frames", type=whole_in(1, MAX_FRAMES), default=300, metavar="N", help="frames to read (300)")
    r.add_argument("--size", metavar="WxH", help="frame size to request from a camera")


def _progress(msg: str) -> None:
    print(f"occloc calibrate: {msg}", file=sys.stderr)


def write_camera_atomic(output, cam) -> None:
    """The camera file of `cam` written through `output` (receiver.io.files.Output: a temporary
    file renamed into place, the existing file's mode kept)."""
    from receiver.io.camera import camera_yaml
    from receiver.io.files import claim_output
    if isinstance(output, str):
        output = claim_output(output, (), "--out")
    output.write_text(camera_yaml(cam))


def _open(spec: str, size):
    from receiver.core.errors import InputError
    from receiver.io.sources import open_source, parse_size
    if not spec.startswith("/dev/video") and not os.path.exists(spec):
        raise InputError(f"no such file or folder: {spec}")
    return open_source(spec, size=parse_size(size))


def _board_frames(src, existing):
    """The frames board views are looked for in. A folder's photos are every readable one, each
    turned to the camera's orientation as `occloc run` turns a photo (portrait = sensor turned
    clockwise): the camera's is EXISTING's (--camera), else landscape (sensors read rows along
    their long side), so a phone's portrait and landscape shots calibrate one camera. A photo
    of another size than the first (once turned) is skipped and said. Other sources as they come."""
    if src.kind != "images":
        yield from src
        return
    from receiver.io.imagefile import to_camera_orientation
    from receiver.core.records import Frame
    size, turned = None, []
    for f in src.photos():
        h, w = f.gray.shape[:2]
        ref = (existing.width, existing.height) if existing is not None else (max(w, h), min(w, h))
        gray, t = to_camera_orientation(f.gray, *ref)
        name = os.path.basename(src.files[f.index])
        if t:
            turned.append(name)
        got = (gray.shape[1], gray.shape[0])
        if size is None:
            size = got
        elif got != size:
            src.skipped += 1
            print(f"occloc: warning: {name}: {w}x{h}, not the {size[0]}x{size[1]} of the first photo "
                  f"(in the camera's orientation): skipped (calibrate photos of one size)", file=sys.stderr)
            continue
        yield Frame(f.index, f.t_s, gray)
    if turned:
        _progress(f"{len(turned)} photo(s) turned to the camera's {'portrait' if size[1] > size[0] else 'landscape'} "
                  f"orientation ({size[0]}x{size[1]}), as occloc run turns them (portrait = sensor turned "
                  f"clockwise): {', '.join(turned[:3])}{' ...' if len(turned) > 3 else ''}")


def run_intrinsics(args) -> dict:
    import numpy as np
    from receiver.calibrate.intrinsics import ViewCollector, calibrate_views, calibration_problems, parse_board
    from receiver.core.errors import InputError
    from receiver.io.camera import CameraModel, load_camera

    from receiver.io.files import claim_output

    board = parse_board(args.board, args.square_mm, args.marker_mm)
    output = claim_output(args.out, [args.source, args.camera], "--out")
    existing = load_camera(args.camera) if args.camera else None
    col = ViewCollector(board, max_blur_px=args.max_blur_px)
    src = _open(args.source, args.size)
    try:
        for frame in _board_frames(src, existing):
            if args.max_frames is not None and col.stats.seen >= args.max_frames:
                break
            what = col.add(frame.index, frame.gray)
            if what != "none" or col.stats.seen % 50 == 0:
                _progress(f"frame {frame.index}: {what} ({col.stats.accepted} views)")
    finally:
        src.close()
    if col.search_size is not None:
        _progress(f"views of {col.size[0]}x{col.size[1]} searched for the board at {col.search_size[0]}x"
                  f"{col.search_size[1]} (bounded work), corners refined at full resolution")
    res = calibrate_views(col, max_views=args.max_views, min_views=MIN_VIEWS)
    for i, e in zip(res.frames, res.per_view_px):
        _progress(f"view frame {i}: {e:.3f} px")
    for i, e in res.dropped_views:
        _progress(f"view frame {i} dropped: reprojection error {e:.3f} px, far above the other views'")
    _progress(f"RMS reprojection error {res.rms_px:.3f} px over {len(res.frames)} views")
    problems = calibration_problems(res)
    if problems and not getattr(args, "force", False):
        raise InputError("calibration refused: " + "; ".join(problems)
                         + " (sharper, more varied board views; --force writes it anyway)")
    for p in problems:
        print(f"occloc: warning: {p}", file=sys.stderr)
    w, h = res.size
    keep = {}
    if existing is not None:
        ex = existing if (existing.width, existing.height) == (w, h) else existing.scaled(w, h)
        keep = dict(pixel_size_um=ex.pixel_size_um, focal_length_mm=ex.focal_length_mm,
                    row_readout_us=ex.row_readout_us, exposure_us=ex.exposure_us, fps=ex.fps)
    cam = CameraModel(w, h, np.asarray(res.K, np.float64), np.asarray(res.dist, np.float64).ravel()[:5],
                      **keep)
    if cam.fps == 0 and getattr(src, "fps", 0):
        cam = dataclasses.replace(cam, fps=float(src.fps))
    write_camera_atomic(output, cam)
    if existing is None:
        print(f"occloc: note: {args.out}: row_readout_us and exposure_us are not measured from a board "
              f"(written as 0): measure the row time with `occloc calibrate rows SOURCE --camera {args.out} "
              f"--map MAP` (or --freq-hz F / --ook-rate HZ), or give --camera EXISTING to keep its values",
              file=sys.stderr)
    out = res.to_json()
    out["out"] = args.out
    out["problems"] = problems
    return out


def _sensor_frames(src, cam):
    """Photos turned to the camera's (sensor) orientation as `occloc run` turns them and brought
    to the camera's size (a photo saved smaller spans several sensor rows per image row: the
    stripes measured on it give the time of the camera file's rows only at its size); other
    sources as they come."""
    if src.kind != "images":
        yield from src
        return
    import cv2
    from receiver.cli.run import _fit_photo
    from receiver.core.records import Frame
    for f in src.photos():
        _, gray = _fit_photo(cam, f.gray)
        if gray.shape[:2] != (cam.height, cam.width):
            gray = cv2.resize(gray, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)
        yield Frame(f.index, f.t_s, gray)


def run_rows_from_map(args, cam, out_path, output) -> dict:
    """`calibrate rows --map MAP` without a rate: every tone light of the map in view."""
    from receiver.calibrate.rows import measure_row_time_tones
    from receiver.core.errors import InputError
    from receiver.io.ledmap import load_map

    m = load_map(args.map)
    freqs = [led.freq_hz for led in m.by_mode("tone") if led.freq_hz]
    if not freqs:
        raise InputError(f"{args.map} has no tone lights: give --freq-hz F or --ook-rate HZ")
    src = _open(args.source, args.size)
    try:
        res = measure_row_time_tones(_sensor_frames(src, cam), freqs, max_frames=args.max_frames)
    finally:
        src.close()
    for light in res.lights:
        _progress(f"light {light['freq_hz']:g} Hz at ({light['cx']:.0f}, {light['cy']:.0f}): {light['row_us']:.4f} us")
    _progress(f"row readout {res.t_row_us:.4f} us, spread {res.spread_us:.4f} us over {len(res.lights)} lights")
    if res.warning:
        print(f"occloc: warning: {res.warning}", file=sys.stderr)
    write_camera_atomic(output, dataclasses.replace(cam, row_readout_us=float(res.t_row_us)))
    d = res.to_json()
    d.update(previous_row_readout_us=cam.row_readout_us, out=out_path)
    return d


def _check_updatable(path: str) -> None:
    """InputError when the camera file `rows` would update in place is marked read-only (no write
    permission for anyone: a file the user protected, which a rename into place would replace
    even where the system lets it, e.g. as root)."""
    import stat
    from receiver.core.errors import InputError
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # load_camera names the problem
    if stat.S_ISREG(mode) and not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
        raise InputError(f"{path} is read-only: give --out FILE2 for the calibrated camera file")


def run_rows(args) -> dict:
    from receiver.calibrate.rows import exposure_warning, measure_row_time, smeared_grid_warning
    from receiver.core.errors import InputError
    from receiver.io.camera import load_camera

    from receiver.io.files import claim_output

    out_path = args.out or args.camera
    if not args.out:
        _check_updatable(args.camera)
    # Without --out the camera file is updated in place: that is the point of it.
    output = claim_output(out_path, [args.source, args.map, args.camera], "--out", update=not args.out)
    cam = load_camera(args.camera)
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    if args.freq_hz is None and args.ook_rate is None:
        if not args.map:
            raise InputError("calibrate rows needs the lights' rate: --freq-hz F, --ook-rate HZ, or --map MAP "
                             "(its tone lights)")
        return run_rows_from_map(args, cam, out_path, output)
    mode, rate = ("tone", args.freq_hz) if args.freq_hz is not None else ("ook", args.ook_rate)
    if not rate > 0:
        raise InputError("the LED's rate must be positive")
    src = _open(args.source, args.size)
    try:
        res = measure_row_time(_sensor_frames(src, cam), mode=mode, rate_hz=rate, prior_row_us=cam.row_readout_us,
                               max_frames=args.max_frames, progress=_progress)
    except InputError as e:
        # The camera's own exposure, when longer than a unit (a chip, half a tone period), smears
        # the edges this measurement needs: say so rather than only "no stripes".
        unit_us = 1e6 / (2 * rate if mode == "tone" else rate)
        if cam.exposure_us > unit_us and "stripe" in str(e):
            raise InputError(f"{e}; the camera file's exposure {cam.exposure_us:g} us is longer than one "
                             f"{'half period' if mode == 'tone' else 'chip'} ({unit_us:.0f} us), which smears "
                             f"the stripe edges the row time is measured from: record the LED with an exposure "
                             f"under {unit_us:.0f} us for the calibration") from None
        raise
    finally:
        src.close()
    if src.size is not None and src.size != (cam.width, cam.height):
        _progress(f"frames are {src.size[0]}x{src.size[1]}, the camera file {cam.width}x{cam.height}: "
                  f"row time measured in the frames' rows")
    ook, tones = ([rate], []) if mode == "ook" else ([], [rate])
    if args.map:
        from receiver.decode.policy import map_rates_hz
        from receiver.io.ledmap import load_map
        map_ook, map_tones = map_rates_hz(load_map(args.map))
        ook += map_ook
        tones += map_tones
    warn = exposure_warning(res.exposure_us, ook, tones)
    if warn:
        from receiver.calibrate.check import exposure_fix
        from receiver.calibrate.rows import exposure_limit_us
        print(f"occloc: warning: {warn}; {exposure_fix(src.kind, exposure_limit_us(ook, tones))}", file=sys.stderr)
    smeared = smeared_grid_warning(res)
    if smeared:
        print(f"occloc: warning: {smeared}", file=sys.stderr)
        warn = f"{warn}; {smeared}" if warn else smeared
    _progress(f"row readout {res.t_row_us:.4f} us +- {res.stderr_us:.4f} (standard error), "
              f"spread {res.spread_us:.4f} us over {res.blobs} blobs in {res.frames} frames; "
              f"exposure ~{res.exposure_us if res.exposure_us is None else round(res.exposure_us, 1)} us")
    new = dataclasses.replace(cam, row_readout_us=float(res.t_row_us))
    write_camera_atomic(output, new)
    d = res.to_json()
    d.update(previous_row_readout_us=cam.row_readout_us, out=out_path, warning=warn)
    return d


def main(args) -> int:
    from receiver.io.files import StdoutOutput, dumps
    res = run_intrinsics(args) if args.what == "intrinsics" else run_rows(args)
    out = StdoutOutput()
    out.write(dumps(res) + "\n")   # a statistic without a value (one blob: no spread) is null, not NaN
    out.flush()
    return 0
