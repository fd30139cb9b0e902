"""Rolling-shutter row time and exposure from the stripes of an LED of known rate.

A rolling shutter starts row r of a frame at t0 + r * t_row, so an LED switching on a known time
grid (a tone LED's 50 % square wave at `freq_hz`, or an OOK LED's chip boundaries at
`rate_hz`) puts its edges on a grid of rows: one *unit* (half a tone period, one OOK chip) spans
`U = 1 / (rate * t_row)` rows, with rate = 2 f for a tone, the chip rate for OOK.

Method (`measure_row_time`):

1. LED blobs per frame (`receiver.vision.detect`, dark stripes up to about 1.5 units bridged), each
   blob's row profile (mean gray per row inside its envelope, `receiver.vision.profile`), its
   thin top and bottom rows trimmed.
2. Mid-level crossings of each profile with hysteresis (`crossings`), linearly interpolated to a
   fraction of a row: every stripe edge, rising or falling.
3. A coarse unit from the gaps between consecutive crossings (`coarse_unit`: the longest unit
   whose comb fits the gaps, so one-chip gaps of Manchester are not mistaken for two-chip ones),
   searched within [0.5, 2] of the camera file's nominal row time when it has one, else over the
   physical range of row times (`ROW_US_RANGE`, 3-60 us).
4. Each crossing gets an integer unit index (consecutive gaps rounded to whole units: robust to
   a 10 % wrong coarse unit and to missed edges), then one least-squares fit over every blob of
   every frame: position = a_blob + U * n + delta * direction (delta: the rising/falling offset of
   an off-centre threshold or a duty error), with outliers dropped and the indices re-rounded.
5. Uncertainty: the standard error of U from the fit, and the spread of per-blob estimates
   (standard deviation and its standard error over blobs); the larger standard error is reported.

Exposure (`fit_exposure`): a row integrates the LED over [t_r, t_r + t_exp], so each edge is a
ramp of E = t_exp / t_row rows. On the fitted grid and the chips read off the profile, the model
profile lo + (hi - lo) * blur(box_E(waveform)) is fitted for E (and a small shift), blob by blob;
the median E times t_row is the exposure. blur: a Gaussian of the sigma measured on the blobs'
left and right edges (`edge_blur_px`), as the synthetic camera and a demosaicing/compressing
camera blur the stripes like any edge (a pure lens blur would not: inside the LED the image is
uniform and the stripes are in time; then the exposure comes out short by about the blur).
Past a chip or so of exposure (OOK) the chips cannot be read off the profile any more: then the
exposure is the one under which the maximum-likelihood chip sequence (the decoder's own
`receiver.decode.exposure.mlse_chips`) fits the profiles best (`long_exposure_chips`), and a
warning says the row time may be wrong (`smeared_grid_warning`).

Image rows are sensor rows (frames in sensor orientation, as `receiver.io.sources` delivers them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from receiver.core.errors import InputError
from receiver.decode.ook import trim_rows
from receiver.vision.detect import detect
from receiver.vision.profile import row_profile

# Rows dropped at each end of a trimmed profile (the blob's outline, blurred by the lens).
END_ROWS = 2
# Hysteresis of the crossing detector, as a fraction of the profile's p10-p90 swing.
HYSTERESIS = 0.2
# Smallest p10-p90 swing (gray) of a profile worth reading.
MIN_SWING = 10.0
# The coarse unit is searched within this factor of the nominal one (camera file).
PRIOR_RANGE = (0.5, 2.0)
# Units shorter than this many rows are not resolved (the stripes blur into each other).
MIN_UNIT_ROWS = 1.2
# Without a nominal row time, row times in this range are searched (us): phone sensors read a row
# in about 5-25 us, webcams 10-60 us, fast global-shutter-like CMOS modes a few us.
ROW_US_RANGE = (3.0, 60.0)
# Residuals beyond this many robust sigmas (and at least OUTLIER_MIN_ROWS) are dropped.
OUTLIER_SIGMA, OUTLIER_MIN_ROWS = 4.0, 0.25
# Largest gap between consecutive edges, in units, kept in a blob (OOK: runs up to 4 chips
# around SYNC; a missed edge doubles a gap).
MAX_GAP_UNITS = 9


@dataclass
class Segment:
    """Crossings of one blob in one frame: positions (rows, profile index), directions (+1 rising,
    -1 falling), the profile, and the frame index."""

    frame: int
    pos: np.ndarray
    dirs: np.ndarray
    profile: np.ndarray
    n: np.ndarray | None = None
    blur_px: float | None = None


@dataclass
class RowTimeResult:
    t_row_us: float
    stderr_us: float
    spread_us: float
    unit_rows: float
    frames: int
    blobs: int
    edges: int
    exposure_us: float | None
    exposure_spread_us: float | None
    mode: str
    rate_hz: float
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        d = {"row_readout_us": round(self.t_row_us, 5), "stderr_us": round(self.stderr_us, 5),
             "spread_us": round(self.spread_us, 5), "unit_rows": round(self.unit_rows, 5),
             "frames": self.frames, "blobs": self.blobs, "edges": self.edges,
             "exposure_us": None if self.exposure_us is None else round(self.exposure_us, 2),
             "exposure_spread_us": None if self.exposure_spread_us is None
             else round(self.exposure_spread_us, 2),
             "mode": self.mode, "rate_hz": self.rate_hz}
        d.update(self.extra)
        return d


def crossings(x: np.ndarray, *, hysteresis: float = HYSTERESIS, min_swing: float = MIN_SWING):
    """(positions, directions) of the mid-level crossings of a profile x (R,): positions in
    fractional rows (linear interpolation), directions +1 rising / -1 falling. A crossing counts
    only when the profile moves from below mid - h to above mid + h (or back), h = hysteresis *
    swing; noise near the middle makes no edges."""
    x = np.asarray(x, np.float64)
    if x.size < 4:
        return np.zeros(0), np.zeros(0, np.int64)
    lo, hi = np.percentile(x, (10, 90))
    swing = hi - lo
    if swing < min_swing:
        return np.zeros(0), np.zeros(0, np.int64)
    mid, h = 0.5 * (lo + hi), hysteresis * swing
    state = np.where(x > mid + h, 1, np.where(x < mid - h, -1, 0))
    idx = np.flatnonzero(state)
    if idx.size < 2:
        return np.zeros(0), np.zeros(0, np.int64)
    s = state[idx]
    ch = np.flatnonzero(s[1:] != s[:-1])
    pos, dirs = [], []
    for c in ch.tolist():
        a, b = int(idx[c]), int(idx[c + 1])
        d = int(s[c + 1])
        seg = x[a:b + 1] - mid
        # the last sign change of (x - mid) between the two decided samples
        above = seg > 0
        k = np.flatnonzero(above[1:] != above[:-1])
        if k.size == 0:
            continue
        k = int(k[-1])
        y0, y1 = seg[k], seg[k + 1]
        pos.append(a + k + y0 / (y0 - y1))
        dirs.append(d)
    return np.asarray(pos, np.float64), np.asarray(dirs, np.int64)


def blob_profiles(gray: np.ndarray, stripe_gap_px: int, *, min_rows: int = 8):
    """Trimmed row profiles (float64 arrays) of the LED blobs of one frame, blobs touching the
    border left out."""
    out = []
    for b in detect(gray, stripe_gap_px=max(int(stripe_gap_px), 1)):
        if b.border or b.y1 - b.y0 < min_rows:
            continue
        prof, w, _ = row_profile(gray, b)
        a, e = trim_rows(w, prof.size, 0.5)
        a, e = a + END_ROWS, e - END_ROWS
        if e - a >= min_rows:
            out.append((np.asarray(prof[a:e], np.float64), b))
    return out


def _step_width(prof: np.ndarray, pad: int, span: int) -> float | None:
    """Mean 10-90 % width (px) of the two edges of one column profile of a lit blob, None when
    the profile does not show a clean step on each side."""
    n = prof.size
    bg = float(np.median(np.concatenate((prof[:2], prof[-2:]))))
    core = prof[pad + span // 4: n - pad - span // 4]
    if core.size < 2:
        return None
    top = float(np.median(core))
    if top - bg < 20 or top >= 250:
        return None
    y = (prof - bg) / (top - bg)
    widths = []
    c = n // 2
    for side in (y[:c], y[c:][::-1]):
        i10 = np.flatnonzero(side >= 0.1)
        i90 = np.flatnonzero(side >= 0.9)
        if i10.size == 0 or i90.size == 0 or i10[0] == 0:
            return None

        def at(level, i):
            a, b = side[i - 1], side[i]
            return i - 1 + (level - a) / (b - a) if b != a else float(i)
        widths.append(at(0.9, int(i90[0])) - at(0.1, int(i10[0])))
    return float(np.mean(widths))


def edge_blur_px(gray: np.ndarray, blob, *, pad: int = 6, max_rows: int = 24) -> float | None:
    """Gaussian blur sigma (px) of a blob's left and right edges: the 10-90 % width of a row's
    column profile is 2.563 sigma for a blurred step (less the pixel's own 1/12 px^2 variance).
    Measured row by row (the median over up to `max_rows` lit rows): an LED seen rotated has
    slanted edges, which a profile averaged over rows would smear into false blur. None when the
    blob is too small or too dim to tell."""
    h, w = gray.shape[:2]
    x0, x1 = blob.x0 - pad, blob.x1 + pad
    if x0 < 0 or x1 > w or blob.x1 - blob.x0 < 8:
        return None
    band = gray[blob.y0:blob.y1, x0:x1].astype(np.float32)
    rows = band[:, pad:-pad].mean(axis=1)
    lo, hi = float(rows.min()), float(rows.max())
    lit = np.flatnonzero(rows >= lo + 0.8 * (hi - lo))
    if lit.size < 2 or hi - blob.background < 20:
        return None
    lit = lit[np.linspace(0, lit.size - 1, min(lit.size, max_rows)).round().astype(int)]
    widths = [wd for wd in (_step_width(band[r], pad, blob.x1 - blob.x0) for r in lit) if wd is not None]
    if not widths:
        return None
    var = (float(np.median(widths)) / 2.563) ** 2 - 1.0 / 12.0
    return float(math.sqrt(max(var, 0.0)))


def coarse_unit(gaps: np.ndarray, lo: float, hi: float, *, keep: float = 0.8) -> float | None:
    """The longest unit u in [lo, hi] rows whose comb sum(cos(2 pi g / u)) over the gaps is at
    least `keep` of the best one (the fundamental of edges that fall on a grid of u)."""
    g = np.asarray(gaps, np.float64)
    g = g[(g > 0.5 * lo)]
    if g.size == 0 or not hi > lo:
        return None
    if g.size > 4000:
        g = g[np.linspace(0, g.size - 1, 4000).astype(int)]
    u = np.exp(np.arange(math.log(lo), math.log(hi), 0.002))
    score = np.empty(u.size)
    for i in range(0, u.size, 256):
        score[i:i + 256] = np.cos(2 * np.pi * g[None, :] / u[i:i + 256, None]).mean(axis=1)
    best = score.max()
    if best < 0.3:
        return None
    # local maxima at or above keep * best: the longest one
    ok = np.flatnonzero(score >= keep * best)
    # walk to the local maximum of the longest qualifying run
    j = int(ok[-1])
    while j > 0 and score[j - 1] > score[j]:
        j -= 1
    return float(u[j])


def _index(seg: Segment, unit: float) -> np.ndarray:
    gaps = np.diff(seg.pos)
    return np.concatenate(([0], np.cumsum(np.rint(gaps / unit)))).astype(np.int64)


def _two_kinds(segs: list[Segment]) -> bool:
    """Both rising->falling and falling->rising gaps are seen often enough to tell the unit from
    the rising/falling offset (a tone LED cut by its blob's ends shows only one kind)."""
    rf = fr = 0
    for s in segs:
        d = s.dirs
        rf += int(((d[:-1] > 0) & (d[1:] < 0)).sum())
        fr += int(((d[:-1] < 0) & (d[1:] > 0)).sum())
    return min(rf, fr) >= max(3, 0.1 * (rf + fr))


def fit_grid(segs: list[Segment], unit0: float, iterations: int = 4):
    """Joint least-squares fit of the unit U (rows) and the rising/falling offset delta over all
    segments (each with its own intercept). Returns (U, delta, stderr_U, residual sigma, kept
    segments with their indices `n` and a keep mask in `extra`)."""
    unit, delta = unit0, 0.0
    with_delta = _two_kinds(segs)
    min_edges = 3 if with_delta else 2
    masks = [np.ones(s.pos.size, bool) for s in segs]
    se = sigma = float("nan")
    for it in range(iterations):
        rows_n, rows_s, rows_y = [], [], []
        used = []
        for s, m in zip(segs, masks):
            # indices from gaps of kept edges, corrected for the offset between edge kinds
            p = s.pos - delta * s.dirs
            n = np.concatenate(([0], np.cumsum(np.rint(np.diff(p) / unit)))).astype(np.int64)
            s.n = n
            if m.sum() < min_edges:
                continue
            nn, ss, yy = n[m].astype(np.float64), s.dirs[m].astype(np.float64), s.pos[m]
            rows_n.append(nn - nn.mean())
            rows_s.append(ss - ss.mean())
            rows_y.append(yy - yy.mean())
            used.append(s)
        if not rows_n:
            return None
        A = np.stack((np.concatenate(rows_n), np.concatenate(rows_s)), axis=1)
        y = np.concatenate(rows_y)
        if not with_delta:
            A = A[:, :1]
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        unit = float(coef[0])
        delta = float(coef[1]) if coef.size > 1 else 0.0
        r = y - A @ coef
        dof = max(y.size - A.shape[1] - len(rows_n), 1)
        sigma = float(math.sqrt((r @ r) / dof))
        cov = sigma ** 2 * np.linalg.inv(A.T @ A)
        se = float(math.sqrt(cov[0, 0]))
        # outliers: residuals per segment (recomputed with the new unit)
        robust = 1.4826 * float(np.median(np.abs(r))) if r.size else 0.0
        lim = max(OUTLIER_SIGMA * robust, OUTLIER_MIN_ROWS)
        for s, m in zip(segs, masks):
            if m.sum() < min_edges:
                continue
            p = s.pos - delta * s.dirs
            n = np.concatenate(([0], np.cumsum(np.rint(np.diff(p) / unit)))).astype(np.float64)
            res = p - unit * n
            res = res - np.median(res[m])
            m[:] = np.abs(res) <= lim
    kept = [s for s, m in zip(segs, masks) if m.sum() >= min_edges]
    for s, m in zip(segs, masks):
        s.mask = m
    return unit, delta, se, sigma, kept


def _segment_unit(s: Segment, delta: float) -> tuple[float, float] | None:
    """(unit, weight) of one segment alone, delta fixed: slope of position vs index."""
    m = s.mask
    if m.sum() < 2:
        return None
    n = s.n[m].astype(np.float64)
    if n.max() - n.min() < 1:
        return None
    y = s.pos[m] - delta * s.dirs[m]
    nc = n - n.mean()
    u = float(nc @ (y - y.mean()) / (nc @ nc))
    return u, float(nc @ nc)


def _box_model(rows: np.ndarray, bounds: np.ndarray, chips: np.ndarray, E: float) -> np.ndarray:
    """Mean of the waveform (chips[k] on [bounds[k], bounds[k+1])) over [r - E/2, r + E/2]."""
    cum = np.concatenate(([0.0], np.cumsum(chips * np.diff(bounds))))

    def W(u):
        u = np.clip(u, bounds[0], bounds[-1])
        k = np.clip(np.searchsorted(bounds, u, side="right") - 1, 0, chips.size - 1)
        return cum[k] + chips[k] * (u - bounds[k])
    if E < 1e-3:
        k = np.clip(np.searchsorted(bounds, rows, side="right") - 1, 0, chips.size - 1)
        return chips[k].astype(np.float64)
    return (W(rows + E / 2) - W(rows - E / 2)) / E


def fit_exposure(seg: Segment, unit: float, delta: float, blur_px: float = 0.0) -> float | None:
    """Exposure ramp length E (rows) of one segment, see the module docstring; None when the
    segment is too short or its stripes too shallow to tell. `blur_px`: the image's Gaussian
    blur (sigma, px), applied to the model along the rows."""
    from scipy.ndimage import gaussian_filter1d
    m = seg.mask
    if m.sum() < 2:
        return None
    x = seg.profile
    n = seg.n[m].astype(np.float64)
    p = seg.pos[m] - delta * seg.dirs[m]
    a = float(np.mean(p - unit * n))
    k0 = int(math.floor((0 - a) / unit)) - 1
    k1 = int(math.ceil((x.size - a) / unit)) + 1
    bounds = a + unit * np.arange(k0, k1 + 1)
    lo, hi = np.percentile(x, (10, 90))
    mid = 0.5 * (lo + hi)
    centres = 0.5 * (bounds[:-1] + bounds[1:])
    ci = np.clip(np.rint(centres).astype(int), 0, x.size - 1)
    chips = (x[ci] > mid).astype(np.float64)
    rows = np.arange(x.size, dtype=np.float64)
    xc = x - x.mean()
    xx = float(xc @ xc)

    def sse(shift, E):
        mod = _box_model(rows, bounds + shift, chips, E)
        if blur_px > 0.05:
            mod = gaussian_filter1d(mod, blur_px, mode="nearest")
        mc = mod - mod.mean()
        mm = float(mc @ mc)
        g = float(mc @ xc) / mm if mm > 0 else 0.0  # gain of the closed-form linear fit
        return xx - g * g * mm if g > 0 else float("inf")

    best = None
    step = 1.6 * unit / 32
    for shift in np.linspace(-0.4, 0.4, 5):
        for E in np.arange(33) * step:
            v = sse(shift, E)
            if best is None or v < best[0]:
                best = (v, E, shift)
    if best is not None and math.isfinite(best[0]):
        _, E0, s0 = best
        for shift in s0 + np.linspace(-0.1, 0.1, 3):
            for E in np.clip(E0 + np.linspace(-step, step, 11), 0.0, None):
                v = sse(shift, E)
                if v < best[0]:
                    best = (v, E, shift)
    return None if best is None or not math.isfinite(best[0]) else float(best[1])


# Exposures (chips) the chip sequence fit tries (`long_exposure_chips`). Longer ones are not
# tried: past 2.5 chips the fit's residual shrinks with the model's narrowing range of levels
# rather than with the fit (on another renderer's 20 us and 87 us recordings 4 chips "fitted"
# best), and an exposure two chips longer fits about as well anyway: the top one means "at least".
SEQUENCE_FIT_CHIPS = tuple(np.arange(0.25, 2.51, 0.25))
# A tried exposure fits when its residual is within this factor of the best one; the shortest
# that fits is taken (a Manchester pair averages to half ON, so an exposure two chips longer
# fits about as well: the result is a lower bound).
SEQUENCE_FIT_TIE = 1.1
# From this exposure (chips) the sequence fit's value is reported; below it the residuals of
# the short exposures hardly differ and the stripe fit measures them better.
LONG_FROM_CHIPS = 1.5
# Chips over which the sequence fit normalises a profile's ON and OFF levels (at long
# exposures only the sync's runs reach them).
SEQUENCE_NORM_CHIPS = 16.0


def long_exposure_chips(profiles, unit_rows: float, blur_chips: float) -> float | None:
    """Exposure (chips) of OOK row profiles by maximum-likelihood chip sequence estimation
    (`receiver.decode.exposure.mlse_chips`, as the decoder reads long exposures) at each of
    `SEQUENCE_FIT_CHIPS`: the shortest exposure whose median residual over the profiles is
    within `SEQUENCE_FIT_TIE` of the best. None without a profile long enough."""
    from receiver.decode.exposure import linearise, mlse_chips
    profiles = [np.asarray(x, np.float64) for x in profiles]
    resid = []
    for e in SEQUENCE_FIT_CHIPS:
        r = []
        for x in profiles:
            z = linearise(x, unit_rows, e, blur_chips, SEQUENCE_NORM_CHIPS)
            m = mlse_chips(z, np.ones(z.size), unit_rows, e, blur_chips)
            if m is not None:
                r.append(m[3])
        if not r:
            return None
        resid.append(float(np.median(r)))
    best = min(resid)
    return float(next(e for e, v in zip(SEQUENCE_FIT_CHIPS, resid) if v <= SEQUENCE_FIT_TIE * best))


def unit_range(unit_rate_hz: float) -> tuple[float, float]:
    """(shortest, longest) unit in rows over `ROW_US_RANGE` for a light of `unit_rate_hz` units/s."""
    return 1e6 / (unit_rate_hz * ROW_US_RANGE[1]), 1e6 / (unit_rate_hz * ROW_US_RANGE[0])


def measure_row_time(frames, *, mode: str, rate_hz: float, prior_row_us: float = 0.0,
                     max_frames: int | None = None, progress=None) -> RowTimeResult:
    """Row readout time from an iterable of `Frame`s of an LED at a known rate.

    mode: 'tone' (rate_hz = the tone frequency) or 'ook' (rate_hz = the chip rate);
    prior_row_us: the camera file's nominal row time (0 = unknown; then row times of
    `ROW_US_RANGE` are searched). Raises InputError when no striped LED gives a fit."""
    if mode not in ("tone", "ook"):
        raise ValueError(mode)
    if not rate_hz > 0:
        raise InputError("the LED's rate must be positive")
    unit_rate = 2.0 * rate_hz if mode == "tone" else rate_hz
    if prior_row_us > 0:
        u_prior = 1e6 / (unit_rate * prior_row_us)
        u_lo, u_hi = u_prior * PRIOR_RANGE[0], u_prior * PRIOR_RANGE[1]
    else:
        # No nominal row time (e.g. a camera file fresh from `calibrate intrinsics`): the units
        # of the physical range of row times, ROW_US_RANGE.
        u_lo, u_hi = unit_range(unit_rate)
    u_lo = max(u_lo, MIN_UNIT_ROWS)
    gap_px = int(math.ceil(1.5 * u_hi)) + 1
    segs: list[Segment] = []
    nframes = 0
    for f in frames:
        if max_frames is not None and nframes >= max_frames:
            break
        nframes += 1
        for prof, b in blob_profiles(f.gray, gap_px):
            pos, dirs = crossings(prof)
            if pos.size >= 2:
                segs.append(Segment(f.index, pos, dirs, prof, blur_px=edge_blur_px(f.gray, b)))
        if progress is not None and nframes % 25 == 0:
            progress(f"frame {nframes}: {len(segs)} striped blobs")
    if nframes == 0:
        raise InputError("no frames")
    # Segments whose gaps are all within the searched unit range or (OOK) a few units.
    gaps = [np.diff(s.pos) for s in segs]
    if mode == "tone":
        # a tone's edges are evenly spaced: keep regular blobs with gaps in range
        segs = [s for s, g in zip(segs, gaps)
                if g.size and g.max() <= 1.3 * g.min() and u_lo <= np.median(g) <= u_hi]
        allg = np.concatenate([np.diff(s.pos) for s in segs]) if segs else np.zeros(0)
        unit0 = float(np.median(allg)) if allg.size else None
    else:
        allg = np.concatenate([g for g in gaps if g.size]) if segs else np.zeros(0)
        unit0 = coarse_unit(allg[(allg >= 0.7 * u_lo) & (allg <= MAX_GAP_UNITS * u_hi)], u_lo, u_hi)
        if unit0 is not None:
            keep = []
            for s, g in zip(segs, gaps):
                q = g / unit0
                if g.size and np.mean(np.abs(q - np.rint(q)) < 0.25) >= 0.8 and q.max() <= MAX_GAP_UNITS \
                        and np.rint(q).min() >= 1:
                    keep.append(s)
            segs = keep
    if unit0 is None or not segs:
        raise InputError(f"no {mode.upper()} stripes found at {rate_hz:g} Hz in {nframes} frames "
                         f"(is the LED in view, striped, and the rate right?)")
    fit = fit_grid(segs, unit0)
    if fit is None:
        raise InputError(f"too few stripe edges to fit ({len(segs)} blobs)")
    unit, delta, se_u, sigma, kept = fit
    per = [v for v in (_segment_unit(s, delta) for s in kept) if v is not None]
    t_row = 1e6 / (unit_rate * unit)
    if len(per) >= 2:
        us = np.array([v[0] for v in per])
        t_each = 1e6 / (unit_rate * us)
        spread = float(np.std(t_each, ddof=1))
        se_spread = spread / math.sqrt(len(per))
    else:
        spread, se_spread = float("nan"), 0.0
    se_t = t_row * se_u / unit
    stderr = max(se_t, se_spread) if math.isfinite(se_spread) else se_t
    # exposure: the longest segments (most edges)
    longest = sorted(kept, key=lambda s: -int(s.mask.sum()))[:12]
    blurs = [s.blur_px for s in kept if s.blur_px is not None]
    blur = float(np.median(blurs)) if blurs else 0.0
    Es = [e for e in (fit_exposure(s, unit, delta, blur) for s in longest) if e is not None]
    how = "stripe fit"
    exp_us = float(np.median(Es)) * t_row if Es else None
    exp_spread = float(np.std(Es)) * t_row if len(Es) >= 2 else None
    if mode == "ook":
        # the stripe fit reads the chips off the profile: past a chip or so of exposure they are
        # smeared together and only a fit of the whole chip sequence tells the exposure
        e_long = long_exposure_chips([s.profile for s in longest], unit, blur / unit)
        if e_long is not None and e_long >= LONG_FROM_CHIPS:
            exp_us, exp_spread, how = e_long * unit * t_row, None, "chip sequence fit"
    frames_used = len({s.frame for s in kept})
    return RowTimeResult(t_row, stderr, spread if math.isfinite(spread) else 0.0, unit, frames_used,
                         len(kept), int(sum(int(s.mask.sum()) for s in kept)), exp_us, exp_spread,
                         mode, float(rate_hz),
                         extra={"delta_rows": round(delta, 4), "edge_sigma_rows": round(sigma, 4),
                                "frames_read": nframes,
                                "blur_px": round(blur, 3), "exposure_from": how if exp_us is not None else None})


# A tone's stripes keep their full depth up to an exposure of this many half periods: a row
# integrating a 50 % square wave over its half period still swings from fully on to fully off (a
# triangle); beyond, the depth falls as 2 - 2 E / period, to nothing at one period.
TONE_EXPOSURE_HALF_PERIODS = 1.0


def exposure_limit_us(ook_rates_hz=(), tone_freqs_hz=()) -> float | None:
    """The longest exposure (us) at which every light is still read: OOK chips up to
    `MAX_EXPOSURE_CHIPS` chips (the exposure model, receiver.decode.exposure), a tone up to
    `TONE_EXPOSURE_HALF_PERIODS` of its half period; None without a rate."""
    from receiver.decode.exposure import MAX_EXPOSURE_CHIPS
    limits = [MAX_EXPOSURE_CHIPS * 1e6 / r for r in ook_rates_hz if r and r > 0]
    limits += [TONE_EXPOSURE_HALF_PERIODS * 1e6 / (2.0 * f) for f in tone_freqs_hz if f and f > 0]
    return min(limits) if limits else None


def exposure_warning(exposure_us: float | None, ook_rates_hz=(), tone_freqs_hz=()) -> str | None:
    """A warning when the exposure is longer than the lights allow (`exposure_limit_us`)."""
    limit = exposure_limit_us(ook_rates_hz, tone_freqs_hz)
    if exposure_us is None or limit is None or exposure_us <= limit:
        return None
    return (f"exposure ~{exposure_us:.0f} us is longer than the lights allow (limit {limit:.0f} us: "
            f"OOK chips are read up to a few chips of exposure, a tone's stripes up to its half period)")


def smeared_grid_warning(res: "RowTimeResult") -> str | None:
    """A warning when the exposure measured with an OOK row time spans `MAX_EXPOSURE_CHIPS` chips
    or more of the measured light: its stripe edges then smear into each other and no longer
    sit on the chip grid (so the row time may be wrong); None otherwise."""
    from receiver.decode.exposure import MAX_EXPOSURE_CHIPS
    if res.mode != "ook" or res.exposure_us is None:
        return None
    chip_us = 1e6 / res.rate_hz
    chips = res.exposure_us / chip_us
    if chips < MAX_EXPOSURE_CHIPS:
        return None
    return (f"the exposure (at least ~{res.exposure_us:.0f} us) spans {chips:.1f} of the {res.rate_hz / 1e3:g} kHz "
            f"chips ({chip_us:.0f} us) the row time is measured on: their stripe edges smear into each other, so "
            f"the row time {res.t_row_us:.2f} us may be wrong (and the exposure is a lower bound: one two "
            f"chips longer fits the stripes as well); "
            f"record the LED with an exposure under one chip ({chip_us:.0f} us) for the calibration, or "
            f"measure on a light of a lower chip rate")


# Several tone lights of a map in one view (`measure_row_time_tones`): their row times must agree
# within this fraction of the combined one, else a warning names them.
MAX_LIGHT_DISAGREE = 0.03
# Smallest spectral SNR (`stripe_frequency_hz` quality) of a blob's stripe frequency that is used.
MIN_TONE_QUALITY = 25.0
# Row-time grid of the search (log-spaced over ROW_US_RANGE).
ROW_GRID_STEPS = 4000


@dataclass
class LightsRowTime:
    """Row time combined from several tone lights: `t_row_us` (median of the lights' own),
    `spread_us` (their standard deviation), `lights` [{cx, cy, freq_hz, row_us}], `warning`."""

    t_row_us: float
    spread_us: float
    lights: list
    frames: int
    warning: str | None = None

    def to_json(self) -> dict:
        return {"row_readout_us": round(self.t_row_us, 5), "spread_us": round(self.spread_us, 5),
                "lights": self.lights, "frames": self.frames, "mode": "tone", "warning": self.warning}


def measure_row_time_tones(frames, freqs_hz, *, max_frames: int | None = None) -> LightsRowTime:
    """Row readout time from every striped light of a map's tone frequencies (`freqs_hz`) in
    view, without a nominal row time. Each blob's stripe frequency is measured in cycles per row
    k (`receiver.decode.tone.stripe_frequency_hz`); the row time T makes every k = f T for one of
    the map's f: the T in `ROW_US_RANGE` whose assignment fits best (least sum of |log(k / (f T))|),
    then each light's own T = k / f, combined by the median with their spread. Lights that
    disagree by more than `MAX_LIGHT_DISAGREE` are a warning."""
    from receiver.decode.tone import stripe_frequency_hz
    from receiver.vision.tone_profile import tone_profile

    f = np.array(sorted({float(v) for v in freqs_hz if v and v > 0}))
    if f.size == 0:
        raise InputError("the map has no tone frequencies")
    u_hi = 1e6 / (2.0 * f.min() * ROW_US_RANGE[0])
    gap_px = int(min(math.ceil(1.5 * u_hi), 64)) + 1
    ks, where, nframes = [], [], 0
    for fr in frames:
        if max_frames is not None and nframes >= max_frames:
            break
        nframes += 1
        for b in detect(fr.gray, stripe_gap_px=gap_px):
            if b.border:
                continue
            prof, w, _ = tone_profile(fr.gray, b)
            if prof.size < 8:
                continue
            # "Hz at 1 us rows" = cycles per row x 1e6
            k, q = stripe_frequency_hz(prof, 1.0, w, fmin_hz=0.8 * f.min() * ROW_US_RANGE[0])
            if math.isfinite(k) and q >= MIN_TONE_QUALITY:
                ks.append(k * 1e-6)
                where.append((round(float(b.cx), 1), round(float(b.cy), 1), fr.index))
    if nframes == 0:
        raise InputError("no frames")
    if not ks:
        raise InputError(f"no striped light found in {nframes} frames (are the map's tone lights in view?)")
    k = np.array(ks)
    T = np.geomspace(ROW_US_RANGE[0] * 1e-6, ROW_US_RANGE[1] * 1e-6, ROW_GRID_STEPS)
    resid = np.abs(np.log(k[None, :, None] / (f[None, None, :] * T[:, None, None])))   # (T, blob, f)
    cost = resid.min(axis=2).sum(axis=1)
    best = int(np.argmin(cost))
    assign = f[resid[best].argmin(axis=1)]
    each = k / assign
    t_row = float(np.median(each))
    spread = float(np.std(each, ddof=1)) if each.size >= 2 else 0.0
    lights = [{"cx": cx, "cy": cy, "frame": i, "freq_hz": float(fk), "row_us": round(float(t) * 1e6, 4)}
              for (cx, cy, i), fk, t in zip(where, assign, each)]
    warn = None
    off = np.abs(each / t_row - 1.0)
    if each.size < 2:
        warn = "one light only: no cross-check of the row time (photograph several of the map's lights)"
    elif off.max() > MAX_LIGHT_DISAGREE:
        bad = ", ".join(f"{l['freq_hz']:g} Hz at ({l['cx']:.0f}, {l['cy']:.0f}): {l['row_us']:.2f} us"
                        for l, o in zip(lights, off) if o > MAX_LIGHT_DISAGREE)
        warn = (f"the lights disagree by up to {100 * off.max():.1f} % (limit {100 * MAX_LIGHT_DISAGREE:g} %) "
                f"about the row time {t_row * 1e6:.3f} us: {bad} (a light of another frequency, or a "
                f"non-LED blob?)")
    return LightsRowTime(t_row * 1e6, spread * 1e6, lights, nframes, warn)
