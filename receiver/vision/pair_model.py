"""The S2-PSK pair as a record, its baseline model and its update from the blobs it explains in
a frame (receiver.vision.pairing: the per-frame flow).

One baseline model for every pair: the baseline is measured whenever both emitters' own blobs
are seen in one frame (for a pair of two tracks, any two blobs it explains at its two ends,
whatever their areas: `both_ends`; for a far head, a merged blob's width), blended into the
prediction, and grows at the measured rate per frame in between (a light's separation goes as
1 / range). A pair of two tracks starts from its founding blobs' separation; a far head's
(jumper) pair, founded on the mean of two jumps, scales that by the emitters' size until its
first measurement.

Per frame, each emitter's intensity is the mean gray inside its envelope at its current
position (also when dark, so no frame is lost); `EmitterLevels` learns its on/off levels from
recent frames, and `pair_xor` (receiver.decode.s2psk) turns the two intensities into the soft
XOR of one sample.

`g` below: the gates a function reads, by the names of `PairTuning` / `PairSettings` (a
receiver.vision.pairing.Pairer holds them).
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from receiver.core.records import Blob
from receiver.vision.track import Track


@functools.cache
def _quantile_index(n: int, q: float) -> tuple[int, int, float]:
    """(lo, hi, t): np.percentile's (method "linear") neighbours in a sorted list of `n` values
    and its weight of the upper one, for the `q` percentile (the same for every list of n)."""
    pos = (n - 1) * (q / 100.0)  # numpy's virtual index
    lo = min(max(int(math.floor(pos)), 0), n - 1)
    return lo, min(lo + 1, n - 1), pos - lo



@dataclass(frozen=True)
class PairTuning:
    """The pairing's internal constants (what a user sets is `PairSettings`). Sizes in emitter
    diameters (sqrt of a blob's area) or px as named; frames at the camera's rate."""

    min_frames: int = 4  # frames of intensity history before the on/off check (two clock beats)
    match_frac: float = 0.75  # a blob explains an emitter within this fraction of the baseline ...
    match_size: float = 1.5  # ... and within this many emitter diameters (blur, centroid noise)
    merged_ratio: float = 1.5  # a blob of 1.5-3 emitters' area at the midpoint: both lit as one
    max_merged: float = 3.0  # (two halves and the blurred gap)
    max_cut: float = 3.0  # one emitter's blob may be cut to 1/3 by a clock edge in the readout
    miss_growth_px: float = 1.0  # the gate grows this many px per frame while a pair coasts
    velocity_gain: float = 0.3  # smoothing of a pair's px/frame velocity
    jump_max_baseline: float = 4.0  # a far head's jumping track: jumps of at most 4 diameters ...
    jump_agree: float = 0.5  # ... two in a row agreeing within half a diameter ...
    jump_agree_y_px: float = 4.0  # ... after forgiving this much vertical shake (px)
    shake_min_pairs: int = 3  # pairs explaining a blob before their median pitch is trusted
    shake_sigma_px: float = 1.5  # `motion.pair_dx`: each blob's Gaussian (centroid noise + blur)
    shake_step_px: float = 0.25  # its grid step
    shake_zero_rel: float = 0.15  # dx 0 when that scores within 15 % of the best (no yaw: no noise)
    flux_margin_px: float = 10.0  # a far head's flux box: one baseline plus this either side ...
    flux_margin_y_px: float = 2.0  # ... and this above and below its envelopes (yaw moves it more)
    flux_floor: float = 2.0  # gray above the background a far head's flux counts from (sensor noise adds nothing)
    flux_min: float = 4.0  # fluxes above this count as lit (gray x px)
    flux_recent: int = 12  # the both-lit flux from the last this many lit fluxes (heads approach)
    jumper_levels_min_area_px: float = 16.0  # a near head's jumper pair inherits its track's levels
    head_follow: float = 0.2  # a far head's backlog follows its blobs by this much per frame
    head_gap_frames: int = 4  # ... until this many frames in a row without a blob
    jumper_unseen_frames: int = 12  # an emitter without its own blob this long: not reported (hidden, or a far head's pair a baseline aside)
    width_tol: float = 0.25  # a short (far) blob's width within 25 % (+1 px) of one emitter's / a merged
    width_min_px: float = 2.0  # merged one's (at least 2 px wider)
    width_max_rows: int = 3  # blobs of at most 3 rows are judged by width (a far half is 1-2 rows)
    baseline_gain: float = 0.5  # a new baseline measurement is blended in by this much
    baseline_max_ratio: float = 1.5  # measurements off by more than this factor are another light's
    growth_gain: float = 0.2  # smoothing of the baseline's growth per frame (an approaching light)
    growth_span_frames: int = 8  # growth is extrapolated over at most this many frames
    max_growth: float = 0.08  # and at most 8 % a frame (a head at 10 m at 70 km/h)
    report_coast_frames: int = 3  # emitters reported while the pair explained a blob this recently (both-dark run)
    anchor_coast_frames: int = 5  # a far head's pair that coasted this long is not reported until re-placed
    lone_sigmas: float = 2.0  # a decoded two-track pair's lone smaller blob moves it within this many sigmas
    shift_sigma_px: float = 1.5  # 1-sigma error (px per axis) of a frame's measured shift (`motion.pair_dx`'s blob noise)
    reanchor_sep_tol: float = 0.1  # a pair of two tracks that explains no blob is re-placed on two seen blobs
    # whose offset is its baseline within this fraction (+ match_min_px), within the camera-shift search
    # radius (`PairSettings.shake_radius_px`) per frame it coasted


TUNING = PairTuning()


class EmitterLevels:
    """Running on/off levels of one emitter from its last `history` intensities (gray):
    on = the `q_on` percentile, off = the `q_off` percentile (numpy's linear interpolation,
    computed on a sorted copy kept up to date per value: no array is built per frame)."""

    def __init__(self, *, history: int = 48, q_on: float = 90.0, q_off: float = 10.0):
        self.values: deque = deque(maxlen=history)
        self.q_on, self.q_off = q_on, q_off
        self._sorted: list[float] = []
        self._levels: tuple[float, float] | None = None  # (on, off) until the next add

    def add(self, value: float) -> None:
        v = float(value)
        if len(self.values) == self.values.maxlen:
            del self._sorted[bisect.bisect_left(self._sorted, self.values[0])]
        self.values.append(v)
        bisect.insort(self._sorted, v)
        self._levels = None

    def on_off(self) -> tuple[float, float]:
        """(on, off), computed once per added value."""
        if self._levels is None:
            self._levels = ((self._quantile(self.q_on), self._quantile(self.q_off)) if self.values
                            else (0.0, 0.0))
        return self._levels

    def _quantile(self, q: float) -> float:
        """np.percentile(values, q) (method "linear"), with numpy's own lerp arithmetic."""
        v = self._sorted
        lo, hi, t = _quantile_index(len(v), q)
        a, b = v[lo], v[hi]
        d = b - a
        return b - d * (1.0 - t) if t >= 0.5 else a + d * t


    @property
    def on(self) -> float:
        return self.on_off()[0]

    @property
    def off(self) -> float:
        return self.on_off()[1]

    def blinks(self, min_swing: float) -> bool:
        """Both levels seen, apart by at least `min_swing` gray values."""
        return len(self.values) >= 2 and self.on - self.off >= min_swing


def moved(blob: Blob, cx: float, cy: float) -> Blob:
    """`blob` translated (by whole pixels, so its envelope mask keeps its shape) to (cx, cy)."""
    dx, dy = float(round(cx - blob.cx)), float(round(cy - blob.cy))
    if dx == 0.0 and dy == 0.0:
        return blob
    # built as `frozen_record` builds records (the constructor's per-field setattr: ~2x the cost);
    # the offset as an array (numpy converts a tuple operand at twice the cost of the addition)
    out = object.__new__(Blob)
    ix, iy = int(dx), int(dy)
    out.__dict__.update(cx=blob.cx + dx, cy=blob.cy + dy, area_px=blob.area_px, hull=blob.hull + np.array((dx, dy)),
                        x0=blob.x0 + ix, y0=blob.y0 + iy, x1=blob.x1 + ix, y1=blob.y1 + iy, border=blob.border,
                        peak=blob.peak, level=blob.level, background=blob.background)
    return out


# what becomes of a pair in a frame (`follow_update`)
LIVE, ENDED, WRONG = "live", "ended", "wrong"

# A pair's baseline counts as measured while both emitters' own blobs were seen within this
# many frames, the latest in this frame (receiver.core.records.PairObservation.both_visible).
BOTH_SEEN_FRAMES = 3


@dataclass
class Pair:
    """Two emitters paired as one S2-PSK transmitter (`a` is the left one in the image).

    `a`, `b`: the pair's own emitter records (Track objects outside the tracker, with the
    founding tracks' ids): `blob` is the emitter's envelope at its current position (px).
    `tracks`: the tracker's tracks whose blob this pair explained in the latest frame."""

    a: Track
    b: Track
    levels_a: EmitterLevels = field(default_factory=EmitterLevels)
    levels_b: EmitterLevels = field(default_factory=EmitterLevels)
    led_id: int | None = None  # its decoded S2-PSK ID (receiver.decode.policy), None until then
    kind: str | None = None
    fresh: bool = True  # formed this frame: its levels already hold this frame's intensities
    tracks: list = field(default_factory=list)
    nearby: list = field(default_factory=list)  # tracks near its emitters, also coasting ones
    vx: float = 0.0  # px per frame, both emitters
    vy: float = 0.0
    frames: int = 0  # frames since the pair formed
    misses: int = 0  # consecutive frames without a blob it explains
    mx: float = 0.0  # midpoint, px
    my: float = 0.0
    # a decoded street light's one-emitter area (px^2) from the latest blob it explained, half
    # of a merged one; 0 = none
    size: float = 0.0
    # Both emitters' own blobs were seen apart, each within the last BOTH_SEEN_FRAMES frames
    # (S2-PSK lights one emitter at a time for half the symbols and far heads merge when both
    # are lit, so the two are rarely seen apart in one frame): the baseline is then measured.
    both_seen: bool = False
    seen_a: int = -10**9  # `frames` count when A's / B's own blob was last seen
    seen_b: int = -10**9
    # A's / B's own blob as observed when last seen (unmoved: the measured centroid, distorted px)
    # and its `frames` count; the vehicle locator ranges taillight pairs from these
    # (receiver.core.records.PairObservation.a_seen).
    obs_a: tuple | None = None  # (blob, frames)
    obs_b: tuple | None = None
    uid: int = field(default_factory=itertools.count().__next__)  # unique for the process's life
    base0: tuple | None = None  # b - a at formation, px
    area0: float = 1.0  # one emitter's area at formation, px
    # The baseline b - a as last measured in one frame (px):
    # from A's and B's own blobs seen together, or from a merged blob's width less one
    # emitter's; None until then (`base0` scaled by the emitters' size is used). `base_frames`:
    # the `frames` count of that measurement; `growth`: the baseline's relative growth per frame
    # (an approaching light's grows as 1 / distance), smoothed over the measurements.
    base: tuple | None = None
    base_frames: int = 0
    growth: float = 0.0
    # A jumper pair's place is sure (`TUNING.anchor_coast_frames`): False after a coast of
    # that many frames, True again once a blob both lit (at the midpoint) or both emitters' own
    # blobs in one frame place it; a single half's blob cannot tell which half it is.
    anchored: bool = True
    # A decoded jumper pair that explained no blob in this frame while a blob no pair explains
    # lies beside one of its emitters: its place is in doubt
    beside: bool = False
    ids: tuple[int, int] = (-1, -1)  # the LED ids of emitters A and B in the output (`Pairer.emitters`)
    # the frames before the pair formed, oldest first: (t_s, a, b, a_on, b_on, a_off, b_off),
    # the emitters' intensities and levels as receiver.decode.s2psk.pair_xor takes them
    backlog: list = field(default_factory=list)
    # its head's last fluxes (`Pairer.sample_flux`): 48 frames hold about 24 with a half lit, twice
    # the default `flux_recent` that the flux decoder reads
    flux: deque = field(default_factory=lambda: deque(maxlen=48))

    # the key when the founding tracks' ids are a live pair's key already: its emitters' LED ids
    alias: tuple[int, int] | None = None
    # False from a frame in which it explained another pair's emitter (`pair_match.anothers`: two
    # cars' taillights close together) until its emitters' samples from then on decode an ID
    # again (receiver.pipeline): its samples may be another light's since, so the ID it holds
    # is not reported (`reported_id`) meanwhile.
    confirmed: bool = True
    # tracks found to be another light's (`pair_match.other_lamps`: a nearer light's bloomed
    # lamp beside its emitters): a light does not turn into this pair's emitter later, so their
    # blobs are only nearby for it (`pair_match.explain`'s `exclude`) and never re-place it
    others: set = field(default_factory=set)

    @property
    def reported_id(self) -> int | None:
        """The ID to report: `led_id` while its own emitters confirm it, else None."""
        return self.led_id if self.confirmed else None

    @property
    def founding(self) -> tuple[int, int]:
        """The founding tracks' ids (one track twice for a pair founded on a jumping track)."""
        return self.a.track_id, self.b.track_id

    @property
    def key(self) -> tuple[int, int]:
        """Unique among live pairs: the founding tracks' ids (or `alias`)."""
        return self.alias if self.alias is not None else self.founding


def _emitter(t: Track) -> Track:
    """The pair's own copy of a founding track (the tracker keeps moving the original)."""
    return Track(t.track_id, t.blob, t.first_frame, t.last_frame, vx=t.vx, vy=t.vy)


def pair_score(a: Track, b: Track, *, row_band: float = 1.0, max_area_ratio: float = 2.5,
               min_baseline: float = 1.2, max_baseline: float = 25.0) -> float | None:
    """Geometric pairing cost (lower is better) of two tracks, None when implausible."""
    da, db = math.sqrt(max(a.blob.area_px, 1.0)), math.sqrt(max(b.blob.area_px, 1.0))
    diam = 0.5 * (da + db)
    dy = abs(a.cy - b.cy)
    dx = abs(a.cx - b.cx)
    ratio = max(a.blob.area_px, 1.0) / max(b.blob.area_px, 1.0)
    if dy > row_band * diam or not (1 / max_area_ratio <= ratio <= max_area_ratio):
        return None
    if not (min_baseline * diam <= dx <= max_baseline * diam):
        return None
    return dy / diam + abs(math.log(ratio)) + 0.01 * dx / diam


def predict(p: Pair, growth_span_frames: int) -> tuple[float, float, float, float, float]:
    """(mx, my, hx, hy, single): pair `p`'s predicted midpoint and half baseline (px) and
    one emitter's area (px^2). Rigid pair: the baseline as last measured, grown since at its
    measured rate (the baseline model above), so a blob can never pull one emitter onto the other."""
    single = max(0.5 * (p.a.blob.area_px + p.b.blob.area_px), p.size, 1.0)
    if p.base is not None:
        # measured: grown since at the measured rate (blob area is no measure of size: a far
        # half covers one or two rows, a saturated emitter blooms)
        scale = (1.0 + p.growth) ** min(p.frames - p.base_frames, growth_span_frames)
        return p.mx + p.vx, p.my + p.vy, 0.5 * scale * p.base[0], 0.5 * scale * p.base[1], single
    scale = math.sqrt(single / p.area0)  # a far head's jumper pair until its first measurement
    return p.mx + p.vx, p.my + p.vy, 0.5 * scale * p.base0[0], 0.5 * scale * p.base0[1], single


def both_ends(p: Pair, pred: tuple, explaining: list, merged) -> tuple | None:
    """(A's blob, B's blob): of a pair `p` of two tracks (a head whose halves are separate
    blobs), two of the blobs it explains in this frame at its prediction `pred` (mx, my, hx,
    hy, single), one on each side of its midpoint, whatever their areas (each the nearest to
    its end), or None. A far half covers one or two rows, so its blob's area halves or doubles
    from frame to frame, and a blob cut by a clock edge during the rolling readout loses rows,
    not columns: neither is a whole emitter's envelope, but each sits on its emitter's column,
    so two of them in one frame measure the baseline's horizontal part. (A far head's jumper
    pair, whose halves merge, is measured by its merged blob's width.)"""
    mx, my, hx, hy, _ = pred
    best_a = best_b = None
    for t in explaining:
        if t.blob is merged:
            continue
        da = math.hypot(t.cx - mx + hx, t.cy - my + hy)
        db = math.hypot(t.cx - mx - hx, t.cy - my - hy)
        if da <= db:
            if best_a is None or da < best_a[0]:
                best_a = (da, t.blob)
        elif best_b is None or db < best_b[0]:
            best_b = (db, t.blob)
    if best_a is None or best_b is None:
        return None
    return best_a[1], best_b[1]


def measure_baseline(g, p: Pair, hx: float, hy: float, obs_a, obs_b, merged, whole: bool = True) -> None:
    """Re-measure a jumper pair's (one jumping track's: a far head) baseline from this frame's
    blobs, free of the camera's shake (both ends in one frame): A's and B's own blobs, or a
    merged blob's width less one emitter's envelope width (horizontal part; the vertical one is
    kept).
    `hx`, `hy`: the predicted half baseline, px. `whole` False: A's and B's blobs are
    `both_ends` (not whole envelopes): only the horizontal part is measured. The baseline was
    otherwise only scaled by the emitters' area from formation, and a far head's area is no
    measure of its size (one or two rows): on vehicle-road it fell 20-40 % short, merged blobs then read as one emitter
    of twice its size and the pair lost its head at 45-60 m."""
    meas = None
    if obs_a is not None and obs_b is not None:
        meas = (obs_b.cx - obs_a.cx, obs_b.cy - obs_a.cy if whole else 2.0 * hy)
    elif merged is not None:
        w1 = max(p.a.blob.x1 - p.a.blob.x0, p.b.blob.x1 - p.b.blob.x0)
        d = (merged.x1 - merged.x0) - w1
        if d >= g.width_min_px:
            meas = (math.copysign(d, hx if hx else 1.0), 2.0 * hy)
    if meas is None:
        return
    pred = (2.0 * hx, 2.0 * hy)
    r = max(math.hypot(*meas), 1e-6) / max(math.hypot(*pred), 1e-6)
    if not (1.0 / g.baseline_max_ratio <= r <= g.baseline_max_ratio):
        return  # another light's blob, or a merged blob of another shape
    if p.base is not None:
        n = p.frames - p.base_frames
        if 0 < n <= g.growth_span_frames:
            r = (max(math.hypot(*meas), 1.0) / max(math.hypot(*pred), 1.0)) ** (1.0 / n) - 1.0
            p.growth += g.growth_gain * (min(max(r, -g.max_growth), g.max_growth) - p.growth)
        g = g.baseline_gain
        meas = (pred[0] + g * (meas[0] - pred[0]), pred[1] + g * (meas[1] - pred[1]))
    p.base, p.base_frames = meas, p.frames


def follow_update(g, p: Pair, shape, pred: tuple, explaining: list, nearby: list, mean,
                  obs_a, obs_b, merged) -> str:
    """Pair `p` moved by the blobs it explains at its prediction `pred` (mx, my, hx, hy,
    single) (receiver.vision.pair_match.explain; `mean`: the mean (dx, dy) of their shifts, None
    without any): its baseline measured, its envelopes placed, its misses counted. Returns
    LIVE, ENDED (coasted too long or an emitter left the image of `shape`) or WRONG (an
    undecoded two-track pair one of whose emitters never showed a blob of its own for
    `unseen_give_up_frames`: its two tracks are never paired again)."""
    mx, my, hx, hy, single = pred
    p.tracks, p.nearby = explaining, nearby
    ends = (both_ends(p, pred, explaining, merged)
            if p.a.track_id != p.b.track_id and (obs_a is None or obs_b is None) else None)
    if merged is not None or (obs_a is not None and obs_b is not None) or ends is not None:
        if ends is not None and merged is None:
            measure_baseline(g, p, hx, hy, *ends, None, whole=False)
        else:
            measure_baseline(g, p, hx, hy, obs_a, obs_b, merged)
        p.anchored = True
    elif g.anchor_coast_frames and p.misses + (not p.tracks) >= g.anchor_coast_frames:
        p.anchored = False
    if obs_a is not None:
        p.seen_a = p.frames
        p.obs_a = (obs_a, p.frames)
    if obs_b is not None:
        p.seen_b = p.frames
        p.obs_b = (obs_b, p.frames)
    p.both_seen = p.frames - max(p.seen_a, p.seen_b) <= 0 and \
        p.frames - min(p.seen_a, p.seen_b) < BOTH_SEEN_FRAMES
    if (g.unseen_give_up_frames and p.led_id is None and p.a.track_id != p.b.track_id
            and min(p.frames - min(p.seen_a, p.seen_b), p.frames) > g.unseen_give_up_frames):
        # one end of an undecoded two-track pair without a blob of its own for that long:
        # a wrong pairing (`PairSettings.unseen_give_up_frames`), as after give_up_frames
        return WRONG
    if p.tracks and p.kind == "SL":
        # A near street light grows by several % a frame, and while both its halves are lit
        # they show as one merged blob that leaves the emitters' envelopes as they were: the
        # next single or merged blob, grown past `merged_ratio` / `max_merged` of them, was
        # then "another light's" and the pair lost its head within a few frames. Its size
        # follows every blob it explains instead (`predict`, receiver.vision.pair_match.explain).
        t = p.tracks[0]
        if math.hypot(t.cx - mx, t.cy - my) < min(math.hypot(t.cx - mx + hx, t.cy - my + hy),
                                                  math.hypot(t.cx - mx - hx, t.cy - my - hy)):
            p.size = 0.5 * t.blob.area_px  # both lit, one blob
        elif obs_a is not None or obs_b is not None:
            p.size = t.blob.area_px
    if mean is None:
        p.misses += 1
        sx = sy = 0.0
    else:
        p.misses = 0
        sx, sy = mean
        p.vx += g.velocity_gain * sx
        p.vy += g.velocity_gain * sy
    p.mx, p.my = mx + sx, my + sy
    for e, obs, sign in ((p.a, obs_a, -1.0), (p.b, obs_b, 1.0)):
        # An emitter's own single blob becomes its envelope (shape and size); it sits at
        # the rigid pair's position, to the nearest whole pixel (`moved`: its centroid stays
        # the mask's, so sub-pixel steps add up instead of being rounded away every frame).
        x, y = p.mx + sign * hx, p.my + sign * hy
        blob = obs if obs is not None else e.blob
        e.blob = moved(blob, x, y)
    if p.misses > g.max_missed:
        return ENDED
    if shape is not None:
        h, w = shape[:2]
        for e in (p.a, p.b):
            if e.blob.x0 < 0 or e.blob.y0 < 0 or e.blob.x1 > w or e.blob.y1 > h:
                return ENDED
    return LIVE
