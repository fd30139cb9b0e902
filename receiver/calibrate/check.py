"""Can this camera, with these settings, receive? (`check_frames`, `occloc check`).

Each test looks at a clip of frames and reports a `Finding` (ok or a problem, with what to change;
V4L2 controls as `v4l2-ctl -d DEV -c name=value`):

* stripes: stripe depth (`receiver.vision.profile.stripe_depth`) of every LED followed over the
  clip (blobs associated by nearest centroid); OOK and tone lights need deep stripes.
* exposure: estimated from the stripes (`receiver.calibrate.rows`, else the edge ramps of the
  LEDs' row profiles, `receiver.decode.exposure.ramp_exposure_rows`) or the camera file's
  `exposure_us`: OOK chips are read up to `MAX_EXPOSURE_CHIPS` chips of exposure (the exposure
  model; `exposure_verdict` names the exposure and chip rate that would work), a tone's stripes
  up to half of its half period.
* auto-exposure / gain drift: the trend of the blobs' median peak and of the frame mean over
  the clip (more than `DRIFT_FRAC` of the level).
* anti-flicker banding: mains-lit rooms put a periodic row pattern into the background (100 or
  120 Hz through the rolling shutter); the background's row means minus their median over the
  clip, its strongest sinusoid (`BAND_MIN_DN` and `BAND_MIN_FRAC` of the background).
* timestamps: non-increasing times, gaps longer than 1.5 frame intervals (dropped frames),
  identical consecutive frames (an encoder filling a drop), the source's own skip counters.
* focus: the blobs' left/right edge blur (`receiver.calibrate.rows.edge_blur_px`) above
  `MAX_BLUR_PX`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from receiver.calibrate.rows import edge_blur_px, measure_row_time
from receiver.decode.exposure import MAX_EXPOSURE_CHIPS, MODEL_FROM_CHIPS, exposure_verdict, ramp_exposure_rows
from receiver.decode.ook import rows_per_chip
from receiver.core.errors import InputError
from receiver.vision.detect import auto_level, detect
from receiver.vision.profile import row_profile, stripe_depth

MIN_STRIPE_DEPTH = 0.35
DRIFT_FRAC = 0.15
BAND_MIN_DN = 1.5
BAND_MIN_FRAC = 0.03
MAX_BLUR_PX = 2.5
EXPOSURE_CHIP_FRAC = 0.5
GAP_FACTOR = 1.5
ASSOC_PX = 40.0
MAX_RAMP_PROFILES = 60


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
    if led_map is None:
        return []
    rates = [float(l.rate_hz) for l in led_map.by_mode("ook") if l.rate_hz]
    rates += [2.0 * float(l.freq_hz) for l in led_map.by_mode("tone") if l.freq_hz]
    if led_map.addressing == "xy" and led_map.default_rate_hz:
        rates.append(float(led_map.default_rate_hz))
    return rates


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


def check_frames(frames, camera=None, led_map=None, *, fps: float = 0.0, max_frames: int = 90,
                 source_counts: dict | None = None) -> list[Finding]:
    """The findings (see the module docstring) for an iterable of `Frame`s."""
    times, idx, means, peaks, bgrows = [], [], [], [], []
    tracks: list[dict] = []
    blurs = []
    kept = []
    ook_profiles: list[np.ndarray] = []  # the LEDs' row profiles (well-covered rows), for edge ramps
    dup = 0
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
        blobs = [b for b in detect(g) if not b.border]
        pk = [b.peak for b in blobs if b.peak < 250]
        peaks.append(float(np.median(pk)) if pk else np.nan)
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
                t = {"cx": b.cx, "cy": b.cy, "depth": [], "n": 0, "peaks": []}
                tracks.append(t)
            else:
                t = best[1]
                t["cx"], t["cy"] = b.cx, b.cy
            t["n"] += 1
            if b.peak < 250:
                t["peaks"].append((float(f.t_s), float(b.peak)))
            if depth is not None:
                t["depth"].append(depth)
    if not times:
        raise InputError("no frames to check")
    out: list[Finding] = []
    rolling = camera is not None and camera.row_readout_us > 0
    rates = _chip_rates(led_map)
    striped = bool(rates) or led_map is None
    # stripes
    leds = [t for t in tracks if t["n"] >= max(2, len(times) // 4) and t["depth"]]
    depth = [{"cx": round(t["cx"], 1), "cy": round(t["cy"], 1), "depth": round(float(np.median(t["depth"])), 3)}
             for t in leds]
    if not leds:
        out.append(Finding("stripes", False, "no LED seen in most frames",
                           "point the camera at the lights; lower exposure/gain if the image is saturated"))
    elif striped:
        weak = [d for d in depth if d["depth"] < MIN_STRIPE_DEPTH]
        text = f"{len(depth)} LEDs, stripe depth median {np.median([d['depth'] for d in depth]):.2f}"
        if weak and len(weak) * 2 >= len(depth):
            out.append(Finding("stripes", False, text + f"; {len(weak)} weakly striped",
                               "shorten the exposure (v4l2-ctl -c auto_exposure=1 -c exposure_time_absolute=1) "
                               "and lower the gain; the LEDs must be OOK/tone modulated",
                               {"leds": depth}))
        else:
            out.append(Finding("stripes", True, text, value={"leds": depth}))
    # exposure
    if rolling and rates:
        est, how = None, ""
        ook = [float(l.rate_hz) for l in led_map.by_mode("ook") if l.rate_hz]
        if led_map.addressing == "xy" and led_map.default_rate_hz:
            ook.append(float(led_map.default_rate_hz))
        tone = [float(l.freq_hz) for l in led_map.by_mode("tone") if l.freq_hz]
        ramp = None
        if ook:
            # the edges' ramps (every stripe shape); past half a chip they are the measurement,
            # the stripe fit below assumes clean chip edges
            ramps = [e for e in (ramp_exposure_rows(p, rows_per_chip(max(ook), camera.row_readout_us))
                                 for p in ook_profiles) if e is not None]
            if len(ramps) >= 3:
                ramp = float(np.median(ramps)) * camera.row_readout_us
        if ramp is not None and ramp >= MODEL_FROM_CHIPS * 1e6 / max(ook):
            est, how = ramp, "edge ramps"
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
        exp = est if est is not None else (camera.exposure_us or None)
        if est is None and exp:
            how = "camera file"
        chip_us = 1e6 / max(rates)
        texts, fixes, bad = [], [], False
        if exp is not None and ook:
            # OOK: the exposure model reads chips up to MAX_EXPOSURE_CHIPS (receiver.decode.exposure)
            for r in sorted(set(ook)):
                ok_r, t = exposure_verdict(exp, r)
                texts.append(t)
                bad |= not ok_r
            fix_us = MAX_EXPOSURE_CHIPS * 1e6 / max(ook)
        else:
            fix_us = EXPOSURE_CHIP_FRAC * chip_us
        if exp is not None and tone:
            half_us = 1e6 / (2.0 * max(tone))
            tone_bad = exp > EXPOSURE_CHIP_FRAC * half_us
            texts.append(f"exposure ~{exp:.0f} us vs the {max(tone):g} Hz tone's half period {half_us:.0f} us"
                         + (": stripes wash out" if tone_bad else ""))
            if tone_bad:
                bad = True
                fix_us = min(fix_us, EXPOSURE_CHIP_FRAC * half_us)
        weak_all = out[0].name == "stripes" and not out[0].ok
        if exp is None and weak_all:
            bad = True
        text = ("; ".join(texts) if texts else "exposure unknown" if exp is None
                else f"exposure ~{exp:.0f} us vs shortest chip {chip_us:.0f} us") + (f" ({how})" if how else "")
        out.append(Finding("exposure", not bad, text,
                           "set a short manual exposure: v4l2-ctl -c auto_exposure=1 -c exposure_time_absolute=N "
                           f"(100 us units; N <= {max(1, int(fix_us / 100))}, i.e. <= {fix_us:.0f} us)" if bad else "",
                           {"exposure_us": exp, "chip_us": chip_us,
                            "exposure_chips": None if exp is None else round(exp / chip_us, 3)}))
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
    bad = any(abs(v) > DRIFT_FRAC for v in drift.values())
    out.append(Finding("gain_drift", not bad,
                       "brightness trend " + ", ".join(f"{k} {v:+.0%}" for k, v in drift.items()) if drift
                       else "brightness trend not measurable",
                       "fix exposure and gain: v4l2-ctl -c auto_exposure=1 -c gain=N "
                       "(and white_balance_automatic=0)" if bad else "", {"drift": drift}))
    # banding
    B = np.asarray(bgrows)
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
    out.append(Finding("banding", not bad, f"background row pattern {amp:.1f} DN on a {level:.0f} DN background",
                       "mains flicker: v4l2-ctl -c power_line_frequency=1 (50 Hz) or 2 (60 Hz); "
                       "or an exposure of whole flicker periods, or turn off the flickering lights" if bad else "",
                       {"band_dn": round(amp, 3), "background_dn": round(level, 2)}))
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
    out.append(Finding("timestamps", not bad,
                       f"{len(t)} frames, interval {nominal * 1000:.1f} ms; {gaps} gaps (~{lost} frames dropped), "
                       f"{back} non-increasing, {dup} repeated frames, {src_lost} lost by the source",
                       "frames are lost: lower the resolution or frame rate (v4l2-ctl --set-fmt-video / "
                       "--set-parm), disable auto exposure priority (v4l2-ctl -c exposure_dynamic_framerate=0), "
                       "use a raw format (GREY/YUYV) and a faster disk/USB port" if bad else "",
                       {"gaps": gaps, "dropped_est": lost, "non_increasing": back, "repeated": dup,
                        "source_lost": src_lost}))
    # focus
    if blurs:
        blur = float(np.median(blurs))
        bad = blur > MAX_BLUR_PX
        out.append(Finding("focus", not bad, f"LED edge blur sigma {blur:.2f} px",
                           "focus on the lights: v4l2-ctl -c focus_automatic_continuous=0 -c focus_absolute=N "
                           "(or focus_auto=0), or clean the lens" if bad else "", {"blur_px": round(blur, 3)}))
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
