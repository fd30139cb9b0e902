"""Can this camera, with these settings, receive? (`check_frames`, `occloc check`).

Each test looks at a clip of frames and reports a `Finding` (ok or a problem, its measured value
and limit, and what to change, worded for the source: `v4l2-ctl -c name=value` for a V4L2
camera, the camera app's settings for photos, both for a video file: `fix_for`, `exposure_fix`).
Photos (`source_kind` "images") are independent stills: a light seen once counts, and the tests
that need a clip (drift, banding, timestamps) say they do not apply.

* stripes: stripe depth (`receiver.vision.profile.stripe_depth`) of every LED followed over the
  clip (blobs associated by nearest centroid); OOK and tone lights need deep stripes.
* exposure: the photos' own EXIF shutter time where they have one, else estimated from the
  stripes (`receiver.calibrate.rows`, else the edge ramps of the LEDs' row profiles,
  `receiver.decode.exposure.ramp_exposure_rows`, which saturate near two chips: past a chip or
  so the chip sequence fit `receiver.calibrate.rows.long_exposure_chips`) or the camera file's
  `exposure_us`. OOK chips
  are read up to `MAX_EXPOSURE_CHIPS` chips of exposure (the exposure model; `exposure_verdict`
  names the exposure and chip rate that would work), a tone's stripes keep their depth up to
  its half period (`receiver.calibrate.rows.exposure_limit_us`). A stripe fit below one row
  resolved no edge ramp: the camera file's exposure is judged instead.
* chips: the striped LEDs' median image height against each OOK chip rate: an image showing
  fewer chips than a packet (54) holds no whole packet, and its IDs need several frames of each
  light (`receiver.decode.pieces.chips_verdict` gives how many, and which rate or image height
  would read the packets from the frames' own chips); pieces too short to be aligned by their
  chips are placed by the frame times among the map's IDs only (a problem with "xy" addressing).
* auto-exposure / gain drift: the trend of the blobs' median peak and of the frame mean over
  the clip (more than `DRIFT_FRAC` of the level); the background's only while the camera is
  still (the lights' median frame-to-frame step, summed, under `MOVING_PX`) or nothing else
  measures it: a moving camera sees another background as it goes.
* anti-flicker banding: mains-lit rooms put a periodic row pattern into the background (100 or
  120 Hz through the rolling shutter); the background's row means minus their median over the
  clip, its strongest sinusoid (`BAND_MIN_DN` and `BAND_MIN_FRAC` of the background).
* timestamps: non-increasing times, gaps longer than 1.5 frame intervals (dropped frames),
  identical consecutive frames (an encoder filling a drop), the source's own skip counters.
* focus: the blobs' left/right edge blur (`receiver.calibrate.rows.edge_blur_px`) above
  `MAX_BLUR_PX`, unless the stripes keep a median depth of `FOCUS_STRIPE_DEPTH`: a lens blur that
  wide would flatten them, so the wide edge is the fixture's own soft rim (reported, not failed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from receiver.calibrate.rows import (LONG_FROM_CHIPS, edge_blur_px, exposure_limit_us, long_exposure_chips,
                                     measure_row_time)
from receiver.decode.exposure import MODEL_FROM_CHIPS, exposure_verdict, ramp_exposure_rows
from receiver.core.protocol import OOK_PACKET_LEN
from receiver.decode.ook import rows_per_chip
from receiver.decode.pieces import chips_verdict
from receiver.decode.settings import OOK_TUNING, OokSettings
from receiver.decode.policy import map_rates_hz
from receiver.core.errors import InputError
from receiver.vision.detect import auto_level, detect
from receiver.vision.profile import row_profile, stripe_depth

MIN_STRIPE_DEPTH = 0.35
DRIFT_FRAC = 0.15
BAND_MIN_DN = 1.5
BAND_MIN_FRAC = 0.03
MAX_BLUR_PX = 2.5
# A wide LED edge (above MAX_BLUR_PX) with stripes this deep (median) is not a focus problem: a lens
# blur of that width would have flattened the stripes (a rendered 4 px defocus leaves 0.41); the
# edge is the fixture's own soft rim (the Luxapose phone photos: 8-13 px edges, depth 0.99).
FOCUS_STRIPE_DEPTH = 0.8
GAP_FACTOR = 1.5
# A picture whose lights travel this far (px: their median step from frame to frame, summed over
# the clip) comes from a moving camera (gain_drift).
MOVING_PX = 40.0
ASSOC_PX = 40.0
MAX_RAMP_PROFILES = 60
# Exposures past a chip or so are told by a chip sequence fit over the first this many of them
# (its cost grows with each profile).
SEQUENCE_FIT_PROFILES = 12
# The lights' image heights (the chips a frame) are measured on this many frames.
HEIGHT_FRAMES = 30


@dataclass
class Finding:
    name: str
    ok: bool
    text: str
    fix: str = ""
    value: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"check": self.name, "ok": self.ok, "text": self.text, "fix": self.fix, **self.value}


def _chip_rates(led_map) -> list[float]:
    """Unit rates of the map's striped lights: OOK chip rates and twice the tone frequencies."""
    ook, tone = map_rates_hz(led_map)
    return ook + [2.0 * f for f in tone]


# What to change, by finding and source kind ("v4l2" camera, "images" = photos, else a video file).
FIXES = {
    "no_leds": {"v4l2": "point the camera at the lights; lower exposure/gain if the image is saturated",
                "images": "photograph the lights (they must fill some of the frame); use a lower ISO "
                          "and a shorter shutter time if they are white blobs",
                "video": "record with the lights in view; lower exposure/gain if the image is saturated"},
    "stripes": {"v4l2": "shorten the exposure (v4l2-ctl -c auto_exposure=1 -c exposure_time_absolute=1) "
                        "and lower the gain; the LEDs must be OOK/tone modulated",
                "images": "use the camera app's manual (pro) mode: the shortest shutter time (1/4000 s or "
                          "shorter) and a low ISO; the LEDs must be OOK/tone modulated",
                "video": "record with a short manual exposure and low gain (a V4L2 webcam: v4l2-ctl -c "
                         "auto_exposure=1 -c exposure_time_absolute=1); the LEDs must be OOK/tone modulated"},
    "gain_drift": {"v4l2": "fix exposure and gain: v4l2-ctl -c auto_exposure=1 -c gain=N "
                           "(and white_balance_automatic=0)",
                   "video": "record with exposure, gain and white balance fixed (a V4L2 webcam: v4l2-ctl -c "
                            "auto_exposure=1 -c gain=N -c white_balance_automatic=0)"},
    "banding": {"v4l2": "mains flicker: v4l2-ctl -c power_line_frequency=1 (50 Hz) or 2 (60 Hz); "
                        "or an exposure of whole flicker periods, or turn off the flickering lights",
                "video": "mains flicker: set the camera's anti-flicker to the mains frequency (a V4L2 webcam: "
                         "v4l2-ctl -c power_line_frequency=1 or 2), or turn off the flickering lights"},
    "timestamps": {"v4l2": "frames are lost: lower the resolution or frame rate (v4l2-ctl --set-fmt-video / "
                           "--set-parm), disable auto exposure priority (v4l2-ctl -c exposure_dynamic_framerate=0), "
                           "use a raw format (GREY/YUYV) and a faster disk/USB port",
                   "video": "frames are lost: record at a lower resolution or frame rate, with a fixed frame "
                            "rate (no auto-exposure priority), to a faster disk"},
    "focus": {"v4l2": "focus on the lights: v4l2-ctl -c focus_automatic_continuous=0 -c focus_absolute=N "
                      "(or focus_auto=0), or clean the lens",
              "images": "tap the lights to focus on them (or set manual focus to their distance), hold the "
                        "phone still, clean the lens",
              "video": "focus on the lights (fixed focus at their distance), or clean the lens"},
}


def fix_for(name: str, source_kind: str) -> str:
    """The advice of finding `name` worded for the source (`FIXES`)."""
    kind = source_kind if source_kind in ("v4l2", "images") else "video"
    options = FIXES[name]
    return options.get(kind) or options["video"]


def exposure_fix(source_kind: str, limit_us: float) -> str:
    """The advice for an exposure above `limit_us`, worded for the source (`fix_for`)."""
    shutter = f"1/{math.ceil(1e6 / limit_us)} s" if limit_us > 0 else "the shortest"
    if source_kind == "images":
        return (f"use the camera app's manual (pro) mode: a shutter time of {shutter} or shorter "
                f"(<= {limit_us:.0f} us) and a low ISO")
    v4l2 = (f"v4l2-ctl -c auto_exposure=1 -c exposure_time_absolute=N (100 us units; "
            f"N <= {max(1, int(limit_us / 100))}, i.e. <= {limit_us:.0f} us)")
    if source_kind == "v4l2":
        return "set a short manual exposure: " + v4l2
    return f"record with a manual exposure of <= {limit_us:.0f} us ({shutter}; a V4L2 webcam: {v4l2})"


def _background_rows(gray: np.ndarray) -> np.ndarray:
    """Mean of every row over the background pixels (lights and their glow masked), nan when a
    row is mostly light."""
    g = gray[:, ::4]
    level, _bg = auto_level(g)
    mask = (g > min(level, 250)).astype(np.uint8)
    mask = cv2.dilate(mask, np.ones((15, 5), np.uint8))
    good = mask == 0
    n = good.sum(axis=1)
    s = (g * good).sum(axis=1, dtype=np.float64)
    out = np.full(g.shape[0], np.nan)
    ok = n >= 0.2 * g.shape[1]
    out[ok] = s[ok] / n[ok]
    return out


def _receiver_detect(camera, led_map, still: bool):
    """The detection settings `occloc run` uses on these frames (photos: flat regions and blobs
    much smaller than the biggest light dropped), or None (the defaults) without camera and map:
    the check judges the blobs the receiver would decode."""
    if camera is None or led_map is None or not still:
        return None
    return _run_detect(camera, led_map, still)


def _run_detect(camera, led_map, still: bool):
    """The detection settings of `occloc run` for this camera and map (a striped light is one
    blob, its dark stripes bridged)."""
    from receiver.decode.policy import ModePlan
    from receiver.pipeline import Receiver, ReceiverSettings
    return Receiver._resolve(ReceiverSettings(), camera, ModePlan.from_map(led_map), True).detect


def check_frames(frames, camera=None, led_map=None, *, fps: float = 0.0, max_frames: int = 90,
                 source_counts: dict | None = None, source_kind: str = "video",
                 stated_exposure_us: float | None = None) -> list[Finding]:
    """The findings (see the module docstring) for an iterable of `Frame`s. `source_kind`: the
    frame source's kind ("v4l2", "images", "video", "recording", "stdin"): photos are judged
    as stills, and the advice is worded for the source (`fix_for`). `stated_exposure_us`: the
    exposure the photos record themselves (EXIF; the longest of them), judged instead of an
    estimate."""
    still = source_kind == "images"
    detect_settings = _receiver_detect(camera, led_map, still)
    # the lights as `occloc run` sees them (one blob each), for their image heights
    run_detect = _run_detect(camera, led_map, still) if camera is not None and led_map is not None else None
    times, idx, means, peaks, bgrows = [], [], [], [], []
    tracks: list[dict] = []
    blurs = []
    kept = []
    ook_profiles: list[np.ndarray] = []  # the LEDs' row profiles (well-covered rows), for edge ramps
    heights: list[int] = []  # the striped LEDs' image heights (rows), for the chips a frame
    dup = 0
    moved_px = 0.0   # the picture's path: the lights' median step, frame to frame, summed
    prev = None
    for f in frames:
        if len(times) >= max_frames:
            break
        g = f.gray
        if prev is not None and g.shape == prev.shape and np.array_equal(g, prev):
            dup += 1
        prev = g
        times.append(float(f.t_s))
        idx.append(int(f.index))
        means.append(float(g.mean()))
        bgrows.append(_background_rows(g))
        kept.append(f)
        blobs = [b for b in detect(g, settings=detect_settings) if not b.border]
        if run_detect is not None and len(kept) <= HEIGHT_FRAMES:
            heights.extend(b.y1 - b.y0 for b in detect(g, settings=run_detect) if not b.border and b.y1 - b.y0 >= 6)
        pk = [b.peak for b in blobs if b.peak < 250]
        peaks.append(float(np.median(pk)) if pk else np.nan)
        steps = []   # this frame's lights' steps from the frame before (px)
        for b in blobs:
            depth = None
            if b.y1 - b.y0 >= 6:
                prof, w, _ = row_profile(g, b)
                depth = stripe_depth(prof, w, background=b.background)
                if len(ook_profiles) < MAX_RAMP_PROFILES and b.peak < 250:
                    keep = w >= 0.5 * w.max()
                    if keep.sum() >= 24:
                        ook_profiles.append(np.asarray(prof, np.float64)[keep.nonzero()[0][0]:keep.nonzero()[0][-1] + 1])
            bl = edge_blur_px(g, b)
            if bl is not None:
                blurs.append(bl)
            best = None
            for t in tracks:
                d = math.hypot(t["cx"] - b.cx, t["cy"] - b.cy)
                if d < ASSOC_PX and (best is None or d < best[0]):
                    best = (d, t)
            if best is None:
                t = {"cx": b.cx, "cy": b.cy, "depth": [], "n": 0, "peaks": [], "seen": -1}
                tracks.append(t)
            else:
                t = best[1]
                if t["seen"] == len(times) - 2:   # seen in the frame before: its step
                    steps.append((b.cx - t["cx"], b.cy - t["cy"]))
                t["cx"], t["cy"] = b.cx, b.cy
            t["n"] += 1
            t["seen"] = len(times) - 1
            if b.peak < 250:
                t["peaks"].append((float(f.t_s), float(b.peak)))
            if depth is not None:
                t["depth"].append(depth)
        if steps:
            moved_px += float(np.hypot(*np.median(np.asarray(steps), axis=0)))
    if not times:
        raise InputError("no frames to check")
    out: list[Finding] = []
    rolling = camera is not None and camera.row_readout_us > 0
    rates = _chip_rates(led_map)
    striped = bool(rates) or led_map is None
    # stripes
    # a light of a photo is seen once; in a clip it must be in a quarter of the frames (and two)
    min_seen = 1 if still else max(2, len(times) // 4)
    leds = [t for t in tracks if t["n"] >= min_seen and t["depth"]]
    depth = [{"cx": round(t["cx"], 1), "cy": round(t["cy"], 1), "depth": round(float(np.median(t["depth"])), 3)}
             for t in leds]
    deep = False   # the stripes are deep enough to clear a wide edge of being a focus problem
    if not leds:
        seen = "in the photo" if still else f"in at least {min_seen} of {len(times)} frames"
        out.append(Finding("stripes", False, f"no LED seen {seen}", fix_for("no_leds", source_kind)))
    elif striped:
        weak = [d for d in depth if d["depth"] < MIN_STRIPE_DEPTH]
        text = (f"{len(depth)} LEDs, stripe depth median {np.median([d['depth'] for d in depth]):.2f} "
                f"(each needs >= {MIN_STRIPE_DEPTH:g})")
        if weak and len(weak) * 2 >= len(depth):
            out.append(Finding("stripes", False, text + f"; {len(weak)} weakly striped",
                               fix_for("stripes", source_kind), {"leds": depth, "min_depth": MIN_STRIPE_DEPTH}))
        else:
            deep = float(np.median([d["depth"] for d in depth])) >= FOCUS_STRIPE_DEPTH
            out.append(Finding("stripes", True, text + (f"; {len(weak)} weakly striped" if weak else ""),
                               value={"leds": depth, "min_depth": MIN_STRIPE_DEPTH}))
    # exposure
    if rolling and rates:
        est, how = None, ""
        ook, tone = map_rates_hz(led_map)
        ramp = None
        if stated_exposure_us:
            # the photos' own record of their shutter time: exact, nothing to estimate
            est, how = float(stated_exposure_us), "the photos' EXIF"
        elif ook:
            # the edges' ramps (every stripe shape); past half a chip they are the measurement,
            # the stripe fit below assumes clean chip edges
            ramps = [e for e in (ramp_exposure_rows(p, rows_per_chip(max(ook), camera.row_readout_us))
                                 for p in ook_profiles) if e is not None]
            if len(ramps) >= 3:
                ramp = float(np.median(ramps)) * camera.row_readout_us
        if stated_exposure_us:
            pass
        elif ramp is not None and ramp >= MODEL_FROM_CHIPS * 1e6 / max(ook):
            est, how = ramp, "edge ramps"
            # the ramps saturate near two chips (every row's window then holds edges at both
            # ends): past a chip or so, the chip sequence fit tells a longer exposure
            per_chip = rows_per_chip(max(ook), camera.row_readout_us)
            e_long = long_exposure_chips(ook_profiles[:SEQUENCE_FIT_PROFILES], per_chip,
                                         (float(np.median(blurs)) if blurs else 0.0) / per_chip)
            if e_long is not None and e_long >= LONG_FROM_CHIPS:
                # a lower bound: a Manchester pair averages to half ON, so an exposure two chips
                # longer fits as well
                est, how = e_long * 1e6 / max(ook), "chip sequence fit: at least this long"
        else:
            try:
                mode, rate = ("ook", max(ook)) if ook else ("tone", max(tone))
                est = measure_row_time(kept, mode=mode, rate_hz=rate,
                                       prior_row_us=camera.row_readout_us).exposure_us
                how = "stripe fit"
            except (InputError, ValueError):
                est = None
            if est is None and ramp is not None:
                est, how = ramp, "edge ramps"
        row_us = camera.row_readout_us
        # A stripe fit below one row has not resolved the exposure (edge ramps sharper than a
        # row): the camera file's value is judged when it has one, else "under one row".
        under_row = est is not None and est < row_us and not stated_exposure_us
        if under_row:
            est = None if camera.exposure_us > 0 else row_us
            under_row = est is not None
        exp = est if est is not None else (camera.exposure_us or None)
        if est is None and exp:
            how = "camera file" if how != "stripe fit" else "camera file; the stripe fit resolves no ramp"
        said = (f"exposure under one row ({row_us:.0f} us)" if under_row
                else None if exp is None else f"exposure ~{exp:.0f} us")
        chip_us = 1e6 / max(rates)
        texts, bad = [], False
        fix_us = exposure_limit_us(ook, tone)
        if exp is not None and ook:
            # OOK: the exposure model reads chips up to MAX_EXPOSURE_CHIPS (receiver.decode.exposure)
            for r in sorted(set(ook)):
                ok_r, t = exposure_verdict(exp, r)
                texts.append(t + (f" (limit {exposure_limit_us([r]):.0f} us)" if ok_r else ""))
                bad |= not ok_r
        if exp is not None and tone:
            limit_us = exposure_limit_us((), [max(tone)])
            tone_bad = exp > limit_us
            texts.append(f"{said} (limit {limit_us:.0f} us: the {max(tone):g} Hz tone's half period)"
                         + (": stripes wash out" if tone_bad else ""))
            bad |= tone_bad
        weak_all = out[0].name == "stripes" and not out[0].ok
        if exp is None and weak_all:
            bad = True
        text = ("; ".join(texts) if texts else f"exposure unknown (limit {fix_us:.0f} us)") + (f" ({how})" if how else "")
        out.append(Finding("exposure", not bad, text, exposure_fix(source_kind, fix_us) if bad else "",
                           {"exposure_us": exp, "chip_us": chip_us, "limit_us": round(fix_us, 2),
                            "exposure_chips": None if exp is None else round(exp / chip_us, 3)}))
    # chips a frame: fewer than a packet are pieced together over frames (receiver.decode.pieces)
    if rolling and heights and led_map is not None:
        rows = float(np.median(heights))
        for r in sorted(set(map_rates_hz(led_map)[0])):
            chips = rows * r * camera.row_readout_us * 1e-6
            if chips < OOK_PACKET_LEN:
                ok_c, text = chips_verdict(chips, r, max_chips=OokSettings.pieces_max_chips,
                                           min_frames=OOK_TUNING.pieces_min_frames,
                                           mapped=led_map.addressing != "xy")
                out.append(Finding("chips", ok_c, f"{text} ({rows:.0f} rows, {camera.row_readout_us:g} us a row)",
                                   "" if ok_c else "use the map's IDs (addressing \"map\"), faster chips or "
                                                   "lights larger in the image",
                                   {"chips_a_frame": round(chips, 2), "rate_hz": r, "rows": rows}))
    # drift
    t = np.asarray(times)
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    drift = {}
    # the same LED's peak over time (a moving camera changes the frame, not one LED's peak)
    rel = []
    for tr in tracks:
        if len(tr["peaks"]) >= 5:
            tt, pp = np.asarray(tr["peaks"]).T
            if tt[-1] > tt[0] and pp.mean() > 5:
                rel.append(np.polyfit(tt, pp, 1)[0] * (tt[-1] - tt[0]) / pp.mean())
    if rel:
        drift["blob_peak"] = float(np.median(rel))
    bgl = np.array([np.nanmedian(r) if np.isfinite(r).any() else np.nan for r in bgrows])
    ok = np.isfinite(bgl)
    if ok.sum() >= 5 and span > 0 and np.nanmean(bgl) > 5:
        drift["background"] = float(np.polyfit(t[ok], bgl[ok], 1)[0] * span / np.nanmean(bgl[ok]))
    # A camera that moves (a light travels across the picture) sees another background as it
    # goes: the background's trend is then the scene's, and only the lights' own peaks judge.
    scene_bg = moved_px >= MOVING_PX and "blob_peak" in drift
    judged = {k: v for k, v in drift.items() if not (k == "background" and scene_bg)}
    bad = any(abs(v) > DRIFT_FRAC for v in judged.values())
    trends = [f"{k} {v:+.0%}" + ("" if k in judged else f" (not judged: the camera moves, the lights travel {moved_px:.0f} px)")
              for k, v in drift.items()]
    if still:
        out.append(Finding("gain_drift", True, "not applicable to independent photos"))
    else:
        out.append(Finding("gain_drift", not bad,
                           "brightness trend " + ", ".join(trends) + f" (limit +-{DRIFT_FRAC:.0%} over the clip)"
                           if drift else "brightness trend not measurable",
                           fix_for("gain_drift", source_kind) if bad else "",
                           {"drift": drift, "limit_frac": DRIFT_FRAC, "moved_px": round(moved_px, 1)}))
    # banding: across the frames of the most common size (photos of a folder may differ in size)
    heights = [r.size for r in bgrows]
    common = max(set(heights), key=heights.count) if heights else 0
    B = np.asarray([r for r in bgrows if r.size == common])
    amps = []
    level = float(np.nanmedian(B)) if np.isfinite(B).any() else 0.0
    if len(B) >= 3:
        med = np.nanmedian(B, axis=0)
        for row in B:
            r = row - med
            ok = np.isfinite(r)
            if ok.sum() < 40:
                continue
            x = np.interp(np.arange(r.size), np.flatnonzero(ok), r[ok])
            x = x - np.polyval(np.polyfit(np.arange(x.size), x, 1), np.arange(x.size))
            X = np.fft.rfft(x * np.hanning(x.size))
            k_lo = 1
            k_hi = x.size // 20  # periods of at least 20 rows
            if k_hi > k_lo:
                amps.append(float(np.abs(X[k_lo:k_hi + 1]).max() * 4.0 / x.size))
    amp = float(np.median(amps)) if amps else 0.0
    bad = amp > BAND_MIN_DN and amp > BAND_MIN_FRAC * max(level, 1.0)
    limit = max(BAND_MIN_DN, BAND_MIN_FRAC * max(level, 1.0))
    if still:
        out.append(Finding("banding", True, "not applicable to independent photos"))
    elif len(B) < 3:
        out.append(Finding("banding", True, f"not measurable from {len(B)} frame(s) (needs 3)"))
    else:
        out.append(Finding("banding", not bad, f"background row pattern {amp:.1f} DN on a {level:.0f} DN "
                                               f"background (limit {limit:.1f} DN)",
                           fix_for("banding", source_kind) if bad else "",
                           {"band_dn": round(amp, 3), "background_dn": round(level, 2), "limit_dn": round(limit, 3)}))
    # timestamps
    dt = np.diff(t)
    rate = fps or (camera.fps if camera is not None and camera.fps else 0.0)
    nominal = 1.0 / rate if rate > 0 else (float(np.median(dt)) if dt.size else 0.0)
    back = int((dt <= 0).sum()) if dt.size else 0
    gaps = int((dt > GAP_FACTOR * nominal).sum()) if dt.size and nominal > 0 else 0
    lost = int(np.round(dt[dt > GAP_FACTOR * nominal] / nominal - 1).sum()) if gaps else 0
    index_gaps = int((np.diff(idx) > 1).sum()) if len(idx) > 1 else 0
    counts = dict(source_counts or {})
    src_lost = int(counts.get("dropped", 0)) + int(counts.get("skipped", 0))
    bad = back > 0 or gaps > 0 or dup > 0 or src_lost > 0 or index_gaps > 0
    if still:
        out.append(Finding("timestamps", True, f"{len(t)} photo(s): not applicable to independent photos"))
    else:
        out.append(Finding("timestamps", not bad,
                           f"{len(t)} frames, interval {nominal * 1000:.1f} ms; {gaps} gaps longer than "
                           f"{GAP_FACTOR:g} intervals (~{lost} frames dropped), {back} non-increasing, {dup} repeated "
                           f"frames, {src_lost} lost by the source (limit: none of these)",
                           fix_for("timestamps", source_kind) if bad else "",
                           {"gaps": gaps, "dropped_est": lost, "non_increasing": back, "repeated": dup,
                            "source_lost": src_lost}))
    # focus
    if blurs:
        blur = float(np.median(blurs))
        wide = blur > MAX_BLUR_PX
        bad = wide and not deep
        text = f"LED edge blur sigma {blur:.2f} px (limit {MAX_BLUR_PX:g} px)"
        if wide and deep:
            text += (f"; the stripes keep their depth (median >= {FOCUS_STRIPE_DEPTH:g}), so the edge is the "
                     f"fixture's, not the focus")
        out.append(Finding("focus", not bad, text, fix_for("focus", source_kind) if bad else "",
                           {"blur_px": round(blur, 3), "limit_px": MAX_BLUR_PX}))
    else:
        out.append(Finding("focus", True, "LED edge blur not measurable (LEDs too small or saturated)"))
    return out


def render_text(findings: list[Finding]) -> str:
    lines = []
    for f in findings:
        lines.append(f"{'ok  ' if f.ok else 'FAIL'} {f.name:11s} {f.text}")
        if not f.ok and f.fix:
            lines.append(f"     {'':11s} -> {f.fix}")
    bad = [f.name for f in findings if not f.ok]
    lines.append("verdict: " + ("this camera and these settings can work" if not bad
                                else "problems found: " + ", ".join(bad)))
    return "\n".join(lines)
