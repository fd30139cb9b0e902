"""S2-PSK pairing: which two tracked blobs are the A/B emitters of one transmitter.

A pair (PROTOCOL.md section 3: two taillights of a car, two halves of a street-light head):
* the same row band: |cy_a - cy_b| <= `row_band` x the mean blob diameter,
* similar size: area ratio <= `max_area_ratio`,
* a plausible baseline: horizontal centre distance between `min_baseline` and
  `max_baseline` blob diameters (taillights 1.4 m apart, 0.15 m wide: ~9 diameters),
* a consistent on/off pattern: both emitters blink (each is lit in about half the frames),
  checked over the frames seen so far once `min_frames` are in.
Candidates are paired greedily, best score first, each track in at most one pair.

Once formed, a pair follows its two emitters itself instead of relying on the blob tracks. The
two halves of a street-light head may be close (~0.1 m apart): beyond a few tens of metres they
then show as one blob whenever both are lit (symbol 0, half of each clock period), and as one
single blob on either side otherwise (symbol 1); or far apart (0.6 m), two blobs at every range,
paired as two tracks like a car's taillights. Blob tracks jump between A, B and the merged
centroid, so a pair bound to two tracks read its intensities in the wrong places and died with
them. Instead the pair keeps its own geometry: a midpoint moving at constant velocity
(px/frame) and a rigid baseline vector (below), corrected each frame from the blobs it
explains: a single blob near A or B, a merged blob (area well above one emitter's) near the
midpoint. Far close-halved heads never show two blobs, so their pairs come from one track that
jumps back and forth by the same baseline (`_pair_jumpers`). Tracks whose blob is explained by a
pair are its `tracks` and are not paired again; the pair's two emitters (`Pair.ids`, reported by
`Pairer.emitters`, lit or dark) carry its ID in the output instead of those tracks. A pair ends after
`max_missed` frames without such a blob, when an emitter leaves the image, or when it has not
decoded after `give_up_frames` (a wrong pairing: its two tracks are then never paired again).

What a user sets is `PairSettings` (receiver.vision.settings: geometry gates, time limits, the
shake estimate); the internal constants are `TUNING` (`PairTuning`), each documented there.

One baseline model for every pair: the baseline is measured whenever both emitters' own blobs
are seen in one frame (or, for a far head, from a merged blob's width), blended into the
prediction, and grows at the measured rate per frame in between (a light's separation goes as
1 / range). A pair of two tracks starts from its founding blobs' separation; a far head's
(jumper) pair, founded on the mean of two jumps, scales that by the emitters' size until its
first measurement. Blob area is otherwise no measure of size: a far half covers one or two rows,
and a saturated blob (peak at the sensor's white level, `white_gray`) blooms to 2-3x the
emitter's area, so a saturated blob is not held to the area gates. The frame's camera shift
(`step`'s `shift`) moves every pair's prediction before its blobs are matched: a lone lit half
is A or B by where the shifted pair puts them.

Per frame, each emitter's intensity is the mean gray inside its envelope at its current
position (also when dark, so no frame is lost); `EmitterLevels` learns its on/off levels from
recent frames, and `pair_xor` (receiver.decode.s2psk) turns the two intensities into the soft
XOR of one sample.

Cost: the loops over pairs x blobs run compiled (receiver/vision/_pairing.pyx), once per
pass and frame, not per pair: `_explain` of every pair with `_first_pass`'s claims
(`_explain_batch`), `shift_votes`, `dx_offsets` and the heads' fluxes (`sample_fluxes`); the
intensities of a frame's emitters are read in one call (receiver.vision.profile.mean_in_masks).
Their decisions and numbers equal the Python code here to the bit (math.hypot's algorithm,
numpy's summation orders), which stays the reference (`OCCLOC_PURE=1`, tests/engine/test_pair_kernels.py).
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from receiver.core.native import load
from receiver.core.records import Blob
from receiver.vision.track import Track
from receiver.vision.settings import PairSettings
from receiver.core.settings import resolve_settings

# the compiled candidate search (receiver/vision/_pairing.pyx: `_explain` of every pair in one
# call per pass), or None: the Python reference below
_k = load("receiver.vision._pairing")


@functools.cache
def _quantile_index(n: int, q: float) -> tuple[int, int, float]:
    """(lo, hi, t): np.percentile's (method "linear") neighbours in a sorted list of `n` values
    and its weight of the upper one, for the `q` percentile (the same for every list of n)."""
    pos = (n - 1) * (q / 100.0)  # numpy's virtual index
    lo = min(max(int(math.floor(pos)), 0), n - 1)
    return lo, min(lo + 1, n - 1), pos - lo


BANNED_PRUNE_AT = 64  # Pairer.banned entries above which bans of dropped tracks are forgotten


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
    flux_floor: float = 2.0  # above the background, what a far head's flux counts (gray; sensor noise adds nothing)
    flux_min: float = 4.0  # fluxes above this count as lit (gray x px)
    flux_recent: int = 12  # the both-lit flux from the last this many lit fluxes (heads approach)
    jumper_levels_min_area_px: float = 16.0  # a near head's jumper pair inherits its track's levels
    head_follow: float = 0.2  # a far head's backlog follows its blobs by this much per frame
    head_gap_frames: int = 4  # ... until this many frames in a row without a blob
    jumper_unseen_frames: int = 12  # a far head's emitter without its own blob this long: not reported
    width_tol: float = 0.25  # a short (far) blob's width within 25 % (+1 px) of one emitter's / a merged
    width_min_px: float = 2.0  # merged one's (at least 2 px wider)
    width_max_rows: int = 3  # blobs of at most 3 rows are judged by width (a far half is 1-2 rows)
    baseline_gain: float = 0.5  # a new baseline measurement is blended in by this much
    baseline_max_ratio: float = 1.5  # measurements off by more than this factor are another light's
    growth_gain: float = 0.2  # smoothing of the baseline's growth per frame (an approaching light)
    growth_span_frames: int = 8  # growth is extrapolated over at most this many frames
    max_growth: float = 0.08  # and at most 8 % a frame (a head at 10 m at 70 km/h)
    report_coast_frames: int = 3  # a pair's emitters are reported while it explained a blob this recently (longest both-dark run)
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
    # False from a frame in which it explained another pair's emitter (`Pairer._anothers`: two
    # cars' taillights close together) until its emitters' samples from then on decode an ID
    # again (receiver.pipeline): its samples may be another light's since, so the ID it holds
    # is not reported (`reported_id`) meanwhile.
    confirmed: bool = True

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


class Pairer:
    """Keeps S2-PSK pairs over frames (init/step).

    Tunables: `PairSettings` (receiver.vision.settings), given as `settings=` or as keyword
    overrides of its fields.
    """

    def __init__(self, *, settings: PairSettings | None = None, new_id=None, white_gray: float = math.inf,
                 **overrides):
        """`new_id() -> int`: fresh LED ids for the pairs' emitters, never a track's id
        (receiver.vision.track.Tracker.new_id); None: a counter of this pairer's own.
        `white_gray`: the sensor's white level (receiver.vision.settings.DetectSettings.saturated_gray):
        a blob peaking there is saturated, its area (bloom, 2-3x the emitter's) no measure of size."""
        s = self.settings = resolve_settings(settings, PairSettings, overrides)
        self.white_gray = float(white_gray)
        k = TUNING
        self.new_id = new_id if new_id is not None else itertools.count().__next__
        self.report_coast_frames = k.report_coast_frames
        self.backlog_frames = s.backlog_frames
        # per unpaired track, its last `backlog_frames` frames: (t_s, seen, area px, intensity)
        self.past: dict[int, deque] = {}
        self.geom = dict(row_band=s.row_band, max_area_ratio=s.max_area_ratio,
                         min_baseline=s.min_baseline, max_baseline=s.max_baseline)
        self.min_frames = k.min_frames
        self.min_swing = s.min_swing
        self.match_frac, self.match_min_px, self.match_size = k.match_frac, s.match_min_px, k.match_size
        self.max_cut = k.max_cut
        self.max_merged = k.max_merged
        self.miss_growth_px = k.miss_growth_px
        self.merged_ratio = k.merged_ratio
        self.velocity_gain = k.velocity_gain
        self.max_missed = s.max_missed
        self.give_up_frames = s.give_up_frames
        self.unseen_give_up_frames = s.unseen_give_up_frames
        self.pairs: list[Pair] = []
        self.levels: dict[int, EmitterLevels] = {}  # per unpaired track, for the on/off check
        self.banned: set[tuple[int, int]] = set()  # track pairs that formed a pair and gave up
        self.jump_max_baseline, self.jump_agree = k.jump_max_baseline, k.jump_agree
        self.jump_agree_y_px = k.jump_agree_y_px
        self.shake_min_pairs = k.shake_min_pairs
        self.flux_margin_px, self.flux_floor = k.flux_margin_px, k.flux_floor
        self.flux_margin_y_px = k.flux_margin_y_px
        self.flux_min, self.flux_recent = k.flux_min, k.flux_recent
        self.jumper_levels_min_area_px = k.jumper_levels_min_area_px
        self.jumper_unseen_frames = k.jumper_unseen_frames
        self.width_tol, self.width_min_px = k.width_tol, k.width_min_px
        self.width_max_rows, self.baseline_max_ratio = k.width_max_rows, k.baseline_max_ratio
        self.baseline_gain = k.baseline_gain
        self.anchor_coast_frames = k.anchor_coast_frames
        self.reanchor_sep_tol, self.shake_radius_px = k.reanchor_sep_tol, s.shake_radius_px
        self.lone_sigmas, self.shift_sigma_px = k.lone_sigmas, k.shift_sigma_px
        self.growth_gain, self.growth_span_frames, self.max_growth = k.growth_gain, k.growth_span_frames, k.max_growth
        self.head_follow, self.head_gap_frames = k.head_follow, k.head_gap_frames
        # every frame's seen blobs, (t_s, view_sum then, (N, 2) centroids, (N,) areas), for the
        # backlog of a far head's new pair whatever tracks followed it (`_head_backlog`)
        self.scene_past: deque = deque(maxlen=max(self.backlog_frames, 1))
        self.view_sum = (0.0, 0.0)  # every frame's image shift added up (measured or `pitch_shift`), px
        self.last_seen: dict[int, tuple] = {}  # per track, its latest blob and shift_sum then (for jumps)
        self.jumps: dict[int, tuple[float, float]] = {}  # per track, its latest qualifying jump, px
        self.shift = (0.0, 0.0)  # the latest frame's common image shift, px
        self.shift_sum = (0.0, 0.0)  # the measured shifts added up, px (jumps over dark frames)
        self.vertical_known = False  # this frame's vertical shift was measured (step's `shift`)
        self._cfg_arr: np.ndarray | None = None  # the kernel's settings (`_cfg`)
        self._table: tuple | None = None  # (tracks list, its length, `_track_table`) of this frame
        self._preds: tuple | None = None  # (pairs list, its length, `_predictions`) until a pair moves

    def _predict(self, p: Pair) -> tuple[float, float, float, float, float]:
        """(mx, my, hx, hy, single): pair `p`'s predicted midpoint and half baseline (px) and
        one emitter's area (px^2). Rigid pair: the baseline as last measured, grown since at its
        measured rate (module docstring), so a blob can never pull one emitter onto the other."""
        single = max(0.5 * (p.a.blob.area_px + p.b.blob.area_px), p.size, 1.0)
        if p.base is not None:
            # measured: grown since at the measured rate (blob area is no measure of size: a far
            # half covers one or two rows, a saturated emitter blooms)
            scale = (1.0 + p.growth) ** min(p.frames - p.base_frames, self.growth_span_frames)
            return p.mx + p.vx, p.my + p.vy, 0.5 * scale * p.base[0], 0.5 * scale * p.base[1], single
        scale = math.sqrt(single / p.area0)  # a far head's jumper pair until its first measurement
        return p.mx + p.vx, p.my + p.vy, 0.5 * scale * p.base0[0], 0.5 * scale * p.base0[1], single

    def _predictions(self) -> list[tuple[Pair, tuple]]:
        """(pair, `_predict(pair)`) of every formed pair (`base0` set), in order. Computed once
        for `shift_votes`, `dx_offsets` and `_first_pass` of a frame: only following a pair
        (`_follow_start` / `_follow_end`, which drop the memo) or another pairs list moves them."""
        memo = self._preds
        if memo is not None and memo[0] is self.pairs and memo[1] == len(self.pairs):
            return memo[2]
        preds = [(p, self._predict(p)) for p in self.pairs if p.base0 is not None]
        self._preds = (self.pairs, len(self.pairs), preds)
        return preds

    def _explain(self, p: Pair, tracks: list[Track], xy: np.ndarray, mx: float, my: float,
                 hx: float, hy: float, single: float, exclude=()):
        """The blobs pair `p` explains around midpoint (mx, my): (explaining tracks, nearby
        tracks, their (dx, dy) offsets from where the pair puts them, A's and B's own single
        blobs or None). Tracks in `exclude` (ids) are only nearby. Nothing is changed."""
        ax, ay, bx, by = mx - hx, my - hy, mx + hx, my + hy
        # The gate widens while the pair coasts: the prediction error grows (the camera's pitch
        # vibration moves every light by a few px within a second).
        tol0 = min(self.match_frac * 2 * math.hypot(hx, hy), max(self.match_min_px, self.match_size * math.sqrt(single)))
        tol = tol0 + self.miss_growth_px * p.misses
        # With the frame's vertical shift measured (`shake` "pairs" / "vertical"), the vertical
        # prediction error does not grow while the pair coasts: only the horizontal gate widens
        # (else a coasting pair reaches the heads just above or below it, farther down the road).
        tol_y = tol0 + self.miss_growth_px if self.vertical_known else math.inf
        explaining, nearby, shifts, obs_a, obs_b, merged = [], [], [], None, None, None
        # Candidates first, for all tracks at once: within tol of A, B or the midpoint.
        near = np.flatnonzero(np.hypot(xy[:, 0] - mx, xy[:, 1] - my) <= tol + math.hypot(hx, hy))
        for i in near:
            t = tracks[i]
            da, db, dm = (math.hypot(t.cx - x, t.cy - y) for x, y in ((ax, ay), (bx, by), (mx, my)))
            if min(da, db, dm) > tol or abs(t.cy - my) > tol_y + abs(hy):
                continue
            nearby.append(t)  # not paired anew while this pair lives
            if not t.seen or t.track_id in exclude:
                continue
            # By width: one emitter's blob is as wide as its
            # envelope, both lit as one blob is one baseline wider (horizontal heads: a far
            # half covers one or two rows, so its area doubles between frames; its width holds).
            wide = self._width_class(p, t.blob, hx)
            if wide == "merged" and dm <= tol:
                shifts.append((t.cx - mx, t.cy - my))  # both lit, one blob
                explaining.append(t)
                merged = t.blob
                continue
            # A saturated blob's area is the bloom's, not the emitter's: no upper bound then
            sat = t.blob.peak >= self.white_gray
            if dm < min(da, db):
                if self.merged_ratio * single < t.blob.area_px and (sat or t.blob.area_px <= self.max_merged * single):
                    shifts.append((t.cx - mx, t.cy - my))  # both lit, one blob
                    explaining.append(t)
                    merged = t.blob
                continue  # a small blob between the two: not telling
            # One emitter, perhaps cut by a clock edge during the rolling readout (smaller: it
            # moves the pair but does not replace the emitter's envelope). Its size is judged
            # against the larger of the two emitters' envelopes: both halves of a head (two
            # taillights) are the same size, and an emitter seen in few frames keeps an
            # envelope from when the light was farther (an approaching head grows by several
            # times in a few seconds).
            e, x, y = (p.a, ax, ay) if da <= db else (p.b, bx, by)
            ratio = max(t.blob.area_px, 1.0) / max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0)
            # (by width, also one that covers a row more than its envelope: twice its area)
            if not (1.0 / self.max_cut <= ratio and (ratio <= self.merged_ratio or sat)
                    or (wide == "single" and ratio >= 1.0)):
                continue  # another light's blob
            shifts.append((t.cx - x, t.cy - y))
            explaining.append(t)
            if ratio >= 1.0 / self.merged_ratio:
                if e is p.a:
                    obs_a = t.blob
                else:
                    obs_b = t.blob
        return explaining, nearby, shifts, obs_a, obs_b, merged

    def _width_class(self, p: Pair, blob: Blob, hx: float) -> str | None:
        """"single" (as wide as one emitter's envelope), "merged" (one horizontal baseline wider:
        both emitters lit as one blob) or None (neither; px widths of the half-open boxes, within
        `width_tol` of the expected width plus one px)."""
        # both this blob and the pair's envelopes short: a far horizontal head, not a row or two
        # of a taller one cut by a clock edge during the rolling readout
        if max(blob.y1 - blob.y0, p.a.blob.y1 - p.a.blob.y0,
                                      p.b.blob.y1 - p.b.blob.y0) > self.width_max_rows:
            return None
        w1 = max(p.a.blob.x1 - p.a.blob.x0, p.b.blob.x1 - p.b.blob.x0)
        wm = w1 + 2.0 * abs(hx)
        wt = blob.x1 - blob.x0
        e1, em = abs(wt - w1), abs(wt - wm)
        if e1 <= em and e1 <= self.width_tol * w1 + 1.0:
            return "single"
        if em < e1 and 2.0 * abs(hx) >= self.width_min_px and em <= self.width_tol * wm + 1.0:
            return "merged"
        return None

    def shift_votes(self, xy: np.ndarray, radius_px: float) -> np.ndarray:
        """(K, 2) displacement votes for the frame's common image shift (receiver.vision.motion):
        for every formed pair and every blob centroid of `xy` (N, 2) within `radius_px` of its
        predicted midpoint, the blob's offset from the predicted A, B and midpoint (one of them
        is the shift when the blob is this pair's; the others scatter by the pair's baseline)."""
        if len(xy) == 0:
            return np.zeros((0, 2))
        pred = np.array([q[:4] for _, q in self._predictions()], float).reshape(-1, 4)
        if _k is not None:
            out = np.empty((3 * len(pred) * len(xy), 2))
            return out[:_k.shift_votes(np.ascontiguousarray(xy, float), pred, float(radius_px), out)]
        # all pairs at once, in the order of a loop over the pairs: per pair its blobs' offsets
        # d, then d + (hx, hy), then d - (hx, hy), each in the blobs' order
        d = xy[None, :, :] - pred[:, None, :2]  # (P, N, 2)
        reach = radius_px + np.abs(pred[:, 2:])  # (P, 2)
        keep = (np.abs(d[:, :, 0]) <= reach[:, None, 0]) & (np.abs(d[:, :, 1]) <= reach[:, None, 1])
        h = pred[:, None, 2:]
        votes = np.stack((d, d + h, d - h), axis=1)  # (P, 3, N, 2)
        return votes[np.broadcast_to(keep[:, None, :], votes.shape[:3])]

    def dx_offsets(self, blobs: list, xy: np.ndarray, dy: float, radius_px: float) -> list[np.ndarray]:
        """Per blob near a formed pair's prediction (moved down by this frame's vertical shift
        `dy` px; within `radius_px` horizontally of the pair's reach, `match_min_px` plus its
        half baseline vertically): the horizontal shifts (px) that put it where it may be, by
        its size (`_width_class`, else its area against one emitter's): a blob both lit at the
        midpoint, one emitter's at A or B (receiver.vision.motion.pair_dx). `xy`: (N, 2)
        centroids of `blobs`. With the kernel: one (K, 2) array of them, a blob's one shift
        padded with +inf (as motion.pair_dx takes them)."""
        out = []
        if not len(xy):
            return out
        if _k is not None:
            items = [(p, q, ()) for p, q in self._predictions()]
            if not items:
                return out
            bl = np.array([(b.cx, b.cy, b.area_px, b.x0, b.x1, b.y0, b.y1, 1) for b in blobs], float).reshape(-1, 8)
            res = np.full((len(items) * len(bl), 2), np.inf)
            n = _k.dx_offsets(bl, self._pair_rows(items, False), self._cfg(), float(dy), float(radius_px), res)
            return res[:n]
        for p, (mx, my, hx, hy, single) in self._predictions():
            my += dy
            sel = np.flatnonzero((np.abs(xy[:, 1] - my) <= self.match_min_px + abs(hy))
                                 & (np.abs(xy[:, 0] - mx) <= radius_px + abs(hx)))
            for j in sel:
                b = blobs[j]
                kind = self._width_class(p, b, hx)
                if kind is None:
                    r = b.area_px / single
                    kind = ("merged" if self.merged_ratio < r <= self.max_merged else
                            "single" if 1.0 / self.max_cut <= r <= self.merged_ratio else None)
                if kind == "merged":
                    out.append(np.array([xy[j, 0] - mx]))
                elif kind == "single":
                    out.append(np.array([xy[j, 0] - mx + hx, xy[j, 0] - mx - hx]))
        return out

    def pitch_shift(self, tracks: list[Track], xy: np.ndarray) -> float:
        """This frame's common vertical image shift (px, + down): the median over the pairs that
        explain a blob of how far it sits below their prediction; 0 with fewer than
        `shake_min_pairs` such pairs. The camera's pitch vibration moves every light by the same
        few pixels from frame to frame, which no pair's own velocity predicts, and a pair whose
        two emitters are dark in this frame (a quarter of the frames) has no blob to correct
        it: its emitters' intensities would be read beside them. Only the vertical part: a
        blob is matched to A, B or the midpoint of a blinking pair, so its horizontal offset
        mixes the shake with which of them lit it."""
        pitch = self._first_pass(tracks, xy)[0]
        self._table = None
        return pitch

    def _first_pass(self, tracks: list[Track], xy: np.ndarray, pitch: bool = True) -> tuple[float, dict]:
        """(`pitch_shift`, {pair uid: ids of the tracks it must not take}) of this frame, from
        every formed pair's explained blobs at its prediction. A blob that two decoded pairs
        explain (two lights overlapping in the image, a car's taillight on another's) moves
        neither: it would drag one's emitter onto the other light. A blob a decoded pair
        explains is not an undecoded pair's (a wide wrong pairing lying on a head).
        `pitch` False: the frame's shift is measured elsewhere, the pitch is not computed (0.0)."""
        dys, claims = [], {}
        if _k is not None:
            items = [(p, q, ()) for p, q in self._predictions()]
            if not items:
                return 0.0 if self.shake_min_pairs > 0 or not pitch else float(np.median(dys)), {}
            res, mine = self._explain_kernel(items, tracks, True)
            if pitch:
                dys = res[res[:, 0] > 0, 3].tolist()
                pitch = float(np.median(dys)) if len(dys) >= self.shake_min_pairs else 0.0
            else:
                pitch = 0.0
            # the tracks two or more pairs claim: not taken by an undecoded one when a decoded one
            # claims it too, by none of them when two decoded ones do (the loop below)
            c = mine.astype(bool)
            both = c.sum(axis=0) >= 2
            if not both.any():  # (most frames) no track claimed twice
                return pitch, {}
            dec = np.array([p.led_id is not None for p, _, _ in items])
            n_dec = c[dec].sum(axis=0)
            ex = c & both & ((n_dec >= 2) | ((n_dec >= 1) & ~dec[:, None]))
            exclude = {items[k][0].uid: {tracks[i].track_id for i in np.flatnonzero(ex[k])}
                       for k in np.flatnonzero(ex.any(axis=1))}
            return pitch, exclude
        for p, pred in self._predictions():
            mx, my, hx, hy, single = pred
            expl, _, shifts, _, _, _ = self._explain(p, tracks, xy, *pred)
            if shifts:
                dys.append(float(np.mean([d[1] for d in shifts])))
            mine = {t.track_id for t in expl}
            if p.led_id is not None and len(xy):
                # a decoded pair also claims the blobs on its own emitters that it did not take
                # (another light's blob merged with one of them)
                tol = self._claim_tol(single)
                d = np.minimum(np.hypot(xy[:, 0] - (mx - hx), xy[:, 1] - (my - hy)),
                               np.hypot(xy[:, 0] - (mx + hx), xy[:, 1] - (my + hy)))
                mine.update(tracks[i].track_id for i in np.flatnonzero(d <= tol) if tracks[i].seen)
            for tid in mine:
                claims.setdefault(tid, []).append(p)
        exclude: dict[int, set] = {}
        for tid, ps in claims.items():
            if len(ps) < 2:
                continue
            decoded = [p for p in ps if p.led_id is not None]
            for p in ps:
                if len(decoded) >= 2 or (decoded and p.led_id is None):
                    exclude.setdefault(p.uid, set()).add(tid)
        pitch = float(np.median(dys)) if pitch and len(dys) >= self.shake_min_pairs else 0.0
        return pitch, exclude

    def _claim_tol(self, single: float) -> float:
        """How near (px) a blob must be to a decoded pair's emitter to be claimed by it
        (`_first_pass`), for one emitter's area `single` px^2."""
        return max(self.match_min_px, self.match_size * math.sqrt(single))

    def _track_table(self, tracks: list[Track]) -> np.ndarray:
        """(N, 8) cx, cy, area_px, x0, x1, y0, y1, seen of the tracks' blobs (the kernel's
        `tr`; seen: 0 unseen, 1 seen, 2 seen and saturated at `white_gray`), built once per frame (the tracks do not change within `step`)."""
        memo = self._table
        if memo is not None and memo[0] is tracks and len(tracks) == memo[1]:
            return memo[2]
        white = self.white_gray
        tr = np.array([(t.blob.cx, t.blob.cy, t.blob.area_px, t.blob.x0, t.blob.x1, t.blob.y0, t.blob.y1,
                        (2.0 if t.blob.peak >= white else 1.0) if t.seen else 0.0) for t in tracks],
                      float).reshape(-1, 8)
        self._table = (tracks, len(tracks), tr)
        return tr

    def _pair_rows(self, items: list, claims: bool) -> np.ndarray:
        """(P, 14) the kernel's `pp` rows of (pair, prediction, exclude) `items`; the claim
        tolerance (`_claim_tol`) with `claims` for the decoded pairs, else -1."""
        rows = []
        for p, (mx, my, hx, hy, single), _ in items:
            a, b = p.a.blob, p.b.blob
            ctol = self._claim_tol(single) if claims and p.led_id is not None else -1.0
            rows.append((mx, my, hx, hy, single, p.misses, a.area_px, b.area_px, p.size, a.x1 - a.x0,
                         b.x1 - b.x0, a.y1 - a.y0, b.y1 - b.y0, ctol))
        return np.array(rows, float).reshape(-1, 14)

    def _cfg(self) -> np.ndarray:
        """The kernel's `cfg`: PairSettings' gates and this frame's `vertical_known`."""
        cfg = self._cfg_arr
        if cfg is None:
            cfg = self._cfg_arr = np.array((self.match_frac, self.match_min_px, self.match_size, self.miss_growth_px,
                                            0.0, self.merged_ratio, self.max_merged, self.max_cut, 1.0,
                                            self.width_tol, self.width_min_px, self.width_max_rows), float)
        cfg[4] = float(self.vertical_known)
        return cfg

    def _explain_kernel(self, items: list, tracks: list[Track], claims: bool, lists: bool = False) -> tuple:
        """The kernel's `explain_pairs` of `items` (non-empty) against `tracks`: (res (P, 10),
        mine (P, N) uint8[, the used part of flat (per pair: nearby, explaining, claimed track
        indices) with `lists`])."""
        n = len(tracks)
        excl = np.zeros((len(items), n), np.uint8)
        if any(e for _, _, e in items):
            ids = [t.track_id for t in tracks]
            for k, (_, _, exclude) in enumerate(items):
                if exclude:
                    for i, tid in enumerate(ids):
                        if tid in exclude:
                            excl[k, i] = 1
        scratch = np.empty((3, len(items), max(n, 1)), np.int32)
        flat = np.empty(3 * len(items) * max(n, 1), np.int32)
        res = np.empty((len(items), 10))
        mine = np.empty((len(items), n), np.uint8)
        used = _k.explain_pairs(self._track_table(tracks), self._pair_rows(items, claims and n > 0), excl,
                                self._cfg(), scratch, res, flat, mine)
        return (res, mine, flat[:used]) if lists else (res, mine)

    def _explain_batch(self, items: list, tracks: list[Track], claims: bool) -> list[tuple]:
        """`_explain` of every (pair, its prediction (mx, my, hx, hy, single), exclude) of
        `items` against `tracks` in one kernel call (receiver/vision/_pairing.pyx), with the
        same decisions and sums. Per item: (explaining, nearby, number of shifts, their mean
        (dx, dy) (np.mean of the (dx, dy) rows), the mean dy (np.mean of the dys), A's and B's
        own blobs, the merged blob, and with `claims` the seen tracks on a decoded pair's
        emitters (`_first_pass`), else [])."""
        if not items:
            return []
        res, _, flat = self._explain_kernel(items, tracks, claims, lists=True)
        picked = [tracks[i] for i in flat.tolist()]  # per pair: nearby, explaining, claimed
        out, pos = [], 0
        for r in res.tolist():
            ns, nn, ne, nc = int(r[0]), int(r[7]), int(r[8]), int(r[9])
            ia, ib, im = int(r[4]), int(r[5]), int(r[6])
            out.append((picked[pos + nn:pos + nn + ne], picked[pos:pos + nn], ns, r[1], r[2], r[3],
                        tracks[ia].blob if ia >= 0 else None, tracks[ib].blob if ib >= 0 else None,
                        tracks[im].blob if im >= 0 else None, picked[pos + nn + ne:pos + nn + ne + nc]))
            pos += nn + ne + nc
        return out

    def _follow(self, p: Pair, tracks: list[Track], xy: np.ndarray, shape, dy: float = 0.0,
                dx: float = 0.0, exclude=()) -> bool:
        """Move pair `p` by this frame's blobs (see the module docstring); False when it ends.
        `xy`: (N, 2) centroids of `tracks`, px; `dy`: the frame's common vertical image shift
        (`pitch_shift`), px, added to the prediction."""
        pred = self._follow_start(p, dx, dy)
        if pred is None:
            return False
        expl, nearby, shifts, obs_a, obs_b, merged = self._explain(p, tracks, xy, *pred, exclude)
        mean = tuple(float(v) for v in np.mean(shifts, axis=0)) if shifts else None
        return self._follow_end(p, shape, pred, expl, nearby, mean, obs_a, obs_b, merged)

    def _follow_all(self, tracks: list[Track], shape, dy: float, dx: float, exclude: dict,
                    xy: np.ndarray | None = None) -> list[Pair]:
        """`_follow` of every pair (the live ones), their blobs found by one kernel call (the
        Python reference `_explain` per pair without the kernel, `xy` the tracks' centroids);
        a pair of two tracks that explains none is re-placed on two seen blobs one baseline
        apart that no pair explains (`_reanchor`); one that explains another pair's emitter
        (`_anothers`) loses `Pair.confirmed`."""
        items = []
        for p in self.pairs:
            pred = self._follow_start(p, dx, dy)
            if pred is not None:
                items.append((p, pred, exclude.get(p.uid, ())))
        if _k is not None:
            found = [(expl, nearby, (sx, sy) if ns else None, obs_a, obs_b, merged)
                     for expl, nearby, ns, sx, sy, _, obs_a, obs_b, merged, _ in self._explain_batch(items, tracks, False)]
        else:
            found = []
            for p, pred, excl in items:
                expl, nearby, shifts, obs_a, obs_b, merged = self._explain(p, tracks, xy, *pred, excl)
                mean = tuple(float(v) for v in np.mean(shifts, axis=0)) if shifts else None
                found.append((expl, nearby, mean, obs_a, obs_b, merged))
        found = [self._lone_checked(p, f) for (p, _, _), f in zip(items, found)]
        taken = {t.track_id for f in found for t in f[0]}
        # the two-track pairs whose emitter another pair may take (`_anothers`): the decoded ones
        # that explain no blob at their prediction, by their founding tracks (a far head's
        # jumper pairs share their one track by design: `_drop_twins`)
        owners: dict[int, list] = {}
        for (p, pred, _), f in zip(items, found):
            if p.a.track_id != p.b.track_id and p.led_id is not None and not f[0]:
                o = (p, pred, False, p.founding)
                for tid in p.founding:
                    owners.setdefault(tid, []).append(o)
        out = []
        for (p, pred, _), (expl, nearby, mean, obs_a, obs_b, merged) in zip(items, found):
            if mean is None and p.a.track_id != p.b.track_id:
                again = self._reanchor(p, pred, tracks, taken)
                if again is not None:
                    expl, mean, obs_a, obs_b = again
                    nearby = nearby + [t for t in expl if t not in nearby]
                    taken.update(t.track_id for t in expl)
            if owners and p.a.track_id != p.b.track_id and any(
                    self._anothers(p, t, pred, ow) for t in expl if (ow := owners.get(t.track_id)) is not None):
                p.confirmed = False  # another pair's emitter: its samples may be another light's
            if self._follow_end(p, shape, pred, expl, nearby, mean, obs_a, obs_b, merged):
                out.append(p)
        return out

    def _lone_gate_px(self, p: Pair) -> float:
        """How far (px) a lone blob may lie from where decoded two-track pair `p` predicts its
        emitter and still move it: the centroid noise (`match_min_px`) plus `lone_sigmas` x the
        prediction's 1-sigma error, `shift_sigma_px` per frame since its last blob (the frame's
        shift estimate; the errors of the frames it coasted add up)."""
        return self.match_min_px + self.lone_sigmas * self.shift_sigma_px * math.sqrt(1.0 + p.misses)

    def _lone_checked(self, p: Pair, found: tuple) -> tuple:
        """`found` (explaining, nearby, mean shift, A's blob, B's blob, merged blob) of pair `p`,
        or nothing explained when `p` is a decoded pair of two tracks that explains one lone blob
        smaller than its emitters (under 1 / `merged_ratio` of the larger envelope) farther than
        `_lone_gate_px` from its prediction. Such a blob is a clock edge's cut of its own
        emitter, or another, farther light's blob beside it (a car behind, its taillight a few
        px from this one's while this one's is dark or hidden): with no partner blob one
        baseline away it cannot tell which, and a pair moved onto another light carries its
        ID there. The pair coasts instead; its own emitters are found where it predicts them,
        or both at once one baseline apart (`_reanchor`). A whole blob, or one within the gate,
        moves it as before."""
        expl, nearby, mean, obs_a, obs_b, merged = found
        if (p.led_id is None or p.a.track_id == p.b.track_id or len(expl) != 1 or merged is not None
                or mean is None or math.hypot(*mean) <= self._lone_gate_px(p)):
            return found
        whole = max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0)
        if max(expl[0].blob.area_px, 1.0) >= whole / self.merged_ratio:
            return found
        return [], nearby, None, None, None, None

    def _anothers(self, p: Pair, t: Track, pred: tuple, owners: list) -> bool:
        """Track `t`, explained by pair `p` at its prediction `pred` (mx, my, hx, hy, single), is
        another two-track pair's emitter. `owners`: (pair, its prediction, it explains a blob
        this frame, its founding track ids) of the pairs whose founding track `t` may be. It is
        another's when not `p`'s own track but the founding track of a decoded pair that explains no blob this
        frame, within that pair's reach of its prediction (`shake_radius_px` a frame coasted and
        the claim tolerance `_claim_tol`): the ID was read from that track's light, which the
        other pair has just lost, and `p` may have taken it."""
        if t.track_id in (p.a.track_id, p.b.track_id) or any(u.track_id == t.track_id for u in p.tracks):
            return False
        for q, (mx, my, hx, hy, single), explains, _ in owners:
            if q is p or q.led_id is None or explains or t.track_id not in q.founding:
                continue
            d = min(math.hypot(t.cx - mx - k * hx, t.cy - my - k * hy) for k in (-1.0, 1.0))
            if d <= self.shake_radius_px * (q.misses + 1) + self._claim_tol(single):
                return True
        return False

    def _reanchor(self, p: Pair, pred: tuple, tracks: list[Track], taken: set) -> tuple | None:
        """Pair `p` (two tracks) explained no blob at its prediction `pred`: the camera's shake
        or the light's own motion may have moved it past its gate while it coasted. Two seen
        blobs that no pair explains (`taken`: track ids), offset by its baseline within
        `reanchor_sep_tol` (+ `match_min_px`), of an emitter's size (area within the pairing's
        `max_area_ratio` of each other, unless saturated), their midpoint within
        `shake_radius_px` per frame it coasted before this one of its predicted midpoint (none
        in its first frame without a blob: both emitters are dark in a quarter of the frames,
        and any two blobs one baseline apart would do), place both its emitters
        at once (no lone blob can be taken for the wrong one); the nearest such two. Returns
        (explaining tracks, mean (dx, dy) shift, A's blob, B's blob) or None."""
        mx, my, hx, hy, single = pred
        bx, by = 2.0 * hx, 2.0 * hy
        tol = self.match_min_px + self.reanchor_sep_tol * math.hypot(bx, by)
        if p.misses < 1:
            return None  # its first frame without a blob: both emitters dark in a quarter of the frames
        reach = self.shake_radius_px * p.misses
        tr = self._track_table(tracks)  # seen tracks near the prediction, all at once
        near = np.flatnonzero((tr[:, 7] != 0.0) & (np.abs(tr[:, 0] - mx) <= reach + abs(hx) + tol)
                              & (np.abs(tr[:, 1] - my) <= reach + abs(hy) + tol))
        cand = [t for t in map(tracks.__getitem__, near.tolist()) if t.track_id not in taken]
        best = None
        ratio_max = self.geom["max_area_ratio"]
        for ta in cand:
            for tb in cand:
                if tb is ta or math.hypot(tb.cx - ta.cx - bx, tb.cy - ta.cy - by) > tol:
                    continue
                ox, oy = 0.5 * (ta.cx + tb.cx) - mx, 0.5 * (ta.cy + tb.cy) - my
                d = math.hypot(ox, oy)
                if d > reach:
                    continue
                sat = ta.blob.peak >= self.white_gray and tb.blob.peak >= self.white_gray
                r = max(ta.blob.area_px, 1.0) / max(tb.blob.area_px, 1.0)
                if not sat and not (1.0 / ratio_max <= r <= ratio_max):
                    continue
                if best is None or d < best[0]:
                    best = (d, ta, tb, (ox, oy))
        if best is None:
            return None
        _, ta, tb, mean = best
        return [ta, tb], mean, ta.blob, tb.blob

    def _follow_start(self, p: Pair, dx: float, dy: float) -> tuple | None:
        """`_follow`'s first part: the frame counted, None when the pair gives up, else its
        prediction (mx, my, hx, hy, single) moved by the frame's shift (dx, dy) px."""
        self._preds = None  # the pairs move
        p.frames += 1
        if p.led_id is None and p.frames > self.give_up_frames:
            self.banned.add(p.founding)   # what new pairs are checked by (an alias never matches)
            return None
        if p.base0 is None:  # first follow: the founding blobs fix the baseline vector
            p.base0 = (p.b.cx - p.a.cx, p.b.cy - p.a.cy)
            p.area0 = max(0.5 * (p.a.blob.area_px + p.b.blob.area_px), 1.0)
            p.mx, p.my = 0.5 * (p.a.cx + p.b.cx), 0.5 * (p.a.cy + p.b.cy)
            if p.a.track_id != p.b.track_id:
                # two emitters' own blobs: the founding baseline is a measurement (a far head's
                # jumping track gives it only as the mean of two jumps: scaled until measured)
                p.base, p.base_frames = p.base0, p.frames
        mx, my, hx, hy, single = self._predict(p)
        # the camera's shake moves every light alike: a lone lit half is matched to A or B only
        # after it (a yaw step of half a baseline would otherwise swap them)
        mx += dx
        my += dy
        return mx, my, hx, hy, single

    def _follow_end(self, p: Pair, shape, pred: tuple, explaining: list, nearby: list, mean,
                    obs_a, obs_b, merged) -> bool:
        """`_follow`'s second part, from the blobs pair `p` explains at its prediction `pred`
        (`_explain`; `mean`: the mean (dx, dy) of their shifts, None without any)."""
        mx, my, hx, hy, single = pred
        self._preds = None  # the pairs move
        p.tracks, p.nearby = explaining, nearby
        if merged is not None or (obs_a is not None and obs_b is not None):
            self._measure_baseline(p, hx, hy, obs_a, obs_b, merged)
            p.anchored = True
        elif self.anchor_coast_frames and p.misses + (not p.tracks) >= self.anchor_coast_frames:
            p.anchored = False
        if obs_a is not None:
            p.seen_a = p.frames
            p.obs_a = (obs_a, p.frames)
        if obs_b is not None:
            p.seen_b = p.frames
            p.obs_b = (obs_b, p.frames)
        p.both_seen = p.frames - max(p.seen_a, p.seen_b) <= 0 and \
            p.frames - min(p.seen_a, p.seen_b) < BOTH_SEEN_FRAMES
        if (self.unseen_give_up_frames and p.led_id is None and p.a.track_id != p.b.track_id
                and min(p.frames - min(p.seen_a, p.seen_b), p.frames) > self.unseen_give_up_frames):
            # one end of an undecoded two-track pair without a blob of its own for that long:
            # a wrong pairing (`PairSettings.unseen_give_up_frames`), as after give_up_frames
            self.banned.add(p.founding)
            return False
        if p.tracks and p.kind == "SL":
            # A near street light grows by several % a frame, and while both its halves are lit
            # they show as one merged blob that leaves the emitters' envelopes as they were: the
            # next single or merged blob, grown past `merged_ratio` / `max_merged` of them, was
            # then "another light's" and the pair lost its head within a few frames. Its size
            # follows every blob it explains instead (`_predict`, `_explain`).
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
            p.vx += self.velocity_gain * sx
            p.vy += self.velocity_gain * sy
        p.mx, p.my = mx + sx, my + sy
        for e, obs, sign in ((p.a, obs_a, -1.0), (p.b, obs_b, 1.0)):
            # An emitter's own single blob becomes its envelope (shape and size); it sits at
            # the rigid pair's position, to the nearest whole pixel (`moved`: its centroid stays
            # the mask's, so sub-pixel steps add up instead of being rounded away every frame).
            x, y = p.mx + sign * hx, p.my + sign * hy
            blob = obs if obs is not None else e.blob
            e.blob = moved(blob, x, y)
        if p.misses > self.max_missed:
            return False
        if shape is not None:
            h, w = shape[:2]
            for e in (p.a, p.b):
                if e.blob.x0 < 0 or e.blob.y0 < 0 or e.blob.x1 > w or e.blob.y1 > h:
                    return False
        return True

    def _measure_baseline(self, p: Pair, hx: float, hy: float, obs_a, obs_b, merged) -> None:
        """Re-measure a jumper pair's (one jumping track's: a far head) baseline from this frame's
        blobs, free of the camera's shake (both ends in one frame): A's and B's own blobs, or a
        merged blob's width less one emitter's envelope width (horizontal part; the vertical one is
        kept).
        `hx`, `hy`: the predicted half baseline, px. The baseline was otherwise only scaled by the
        emitters' area from formation, and a far head's area is no measure of its size (one or
        two rows): on vehicle-road it fell 20-40 % short, merged blobs then read as one emitter
        of twice its size and the pair lost its head at 45-60 m."""
        meas = None
        if obs_a is not None and obs_b is not None:
            meas = (obs_b.cx - obs_a.cx, obs_b.cy - obs_a.cy)
        elif merged is not None:
            w1 = max(p.a.blob.x1 - p.a.blob.x0, p.b.blob.x1 - p.b.blob.x0)
            d = (merged.x1 - merged.x0) - w1
            if d >= self.width_min_px:
                meas = (math.copysign(d, hx if hx else 1.0), 2.0 * hy)
        if meas is None:
            return
        pred = (2.0 * hx, 2.0 * hy)
        r = max(math.hypot(*meas), 1e-6) / max(math.hypot(*pred), 1e-6)
        if not (1.0 / self.baseline_max_ratio <= r <= self.baseline_max_ratio):
            return  # another light's blob, or a merged blob of another shape
        if p.base is not None:
            n = p.frames - p.base_frames
            if 0 < n <= self.growth_span_frames:
                r = (max(math.hypot(*meas), 1.0) / max(math.hypot(*pred), 1.0)) ** (1.0 / n) - 1.0
                p.growth += self.growth_gain * (min(max(r, -self.max_growth), self.max_growth) - p.growth)
            g = self.baseline_gain
            meas = (pred[0] + g * (meas[0] - pred[0]), pred[1] + g * (meas[1] - pred[1]))
        p.base, p.base_frames = meas, p.frames

    def step(self, gray: np.ndarray, tracks: list[Track], intensity, shift=None, t_s: float | None = None,
             intensities=None) -> list[Pair]:
        """Update pairs with this frame. `intensity(gray, track) -> float` reads an emitter's
        mean gray in its envelope; `intensities(gray, tracks) -> list of float`, if given, the
        same of many at once. `shift`: the frame's common image shift (dx, dy) px from the
        previous frame (receiver.vision.motion), or None: the vertical one from the pairs
        (`pitch_shift`). `t_s`: the frame's time (s), for the new pairs' `backlog` (None: no
        backlog). Returns the live pairs; their levels are updated."""
        live = {t.track_id: t for t in tracks}
        self._table = None  # `_track_table` of these tracks, built on first use
        shape = None if gray is None else gray.shape
        if _k is not None:  # the kernel's table of the tracks holds their centroids
            table = self._track_table(tracks)
            xy = table[:, :2]
        else:
            table, xy = None, np.array([[t.cx, t.cy] for t in tracks], float).reshape(-1, 2)
        pitch, exclude = self._first_pass(tracks, xy, pitch=shift is None)
        dx, dy = (0.0, pitch) if shift is None else shift
        self.shift = (dx, dy) if shift is not None else (0.0, 0.0)  # for the jumps
        self.shift_sum = (self.shift_sum[0] + self.shift[0], self.shift_sum[1] + self.shift[1])
        self.vertical_known = shift is not None
        self.view_sum = (self.view_sum[0] + dx, self.view_sum[1] + dy)
        if t_s is not None and self.backlog_frames > 0:
            if table is not None:
                lit = table[table[:, 7] != 0.0]
                self.scene_past.append((float(t_s), self.view_sum, lit[:, :2], lit[:, 2]))
            else:
                seen = [t for t in tracks if t.seen]
                self.scene_past.append((float(t_s), self.view_sum,
                                        np.array([(t.cx, t.cy) for t in seen], float).reshape(-1, 2),
                                        np.array([t.blob.area_px for t in seen], float)))
        self.pairs = self._follow_all(tracks, shape, dy, dx, exclude, xy)
        self.pairs = self._drop_twins(self.pairs)
        self._mark_beside(tracks)
        paired = {t.track_id for p in self.pairs for ts in (p.tracks, p.nearby) for t in ts}
        for tid in list(self.levels):
            if tid not in live or tid in paired:
                del self.levels[tid]
                self.past.pop(tid, None)
        if len(self.banned) > BANNED_PRUNE_AT:
            # the tracker never reuses a track ID: a ban naming a track it dropped can never match
            self.banned = {k for k in self.banned if k[0] in live and k[1] in live}
        todo = [t for t in tracks if t.track_id not in paired]
        vals = intensities(gray, todo) if intensities is not None else [intensity(gray, t) for t in todo]
        for t, v in zip(todo, vals):
            self.levels.setdefault(t.track_id, EmitterLevels()).add(v)
            if t_s is not None and self.backlog_frames > 0:
                self.past.setdefault(t.track_id, deque(maxlen=self.backlog_frames)).append(
                    (float(t_s), t.seen, t.blob.area_px, v))
        free = [t for t in tracks if t.track_id not in paired and len(self.levels[t.track_id].values) >= self.min_frames
                and self.levels[t.track_id].blinks(self.min_swing)]
        cands = []
        for i, a in enumerate(free):
            for b in free[i + 1:]:
                s = pair_score(a, b, **self.geom)
                if s is not None:
                    cands.append((s, a, b))
        cands.sort(key=lambda c: c[0])
        keys = {p.key for p in self.pairs}  # one live pair per key (receiver.locate.vehicle follows pairs by it)
        taken: set[int] = set()
        for _, a, b in cands:
            if a.track_id in taken or b.track_id in taken:
                continue
            if a.cx > b.cx:
                a, b = b, a
            if (a.track_id, b.track_id) in self.banned:
                continue
            p = Pair(_emitter(a), _emitter(b), tracks=[a, b], nearby=[a, b], ids=(self.new_id(), self.new_id()),
                     obs_a=(a.blob, 0) if a.seen else None, obs_b=(b.blob, 0) if b.seen else None)
            # The history that proved the blinking also seeds the pair's level estimates.
            for lv, t in ((p.levels_a, a), (p.levels_b, b)):
                for v in self.levels.pop(t.track_id).values:
                    lv.add(v)
            p.backlog = self._two_track_backlog(p, self.past.pop(a.track_id, ()), self.past.pop(b.track_id, ()))
            if p.key in keys:
                # a live pair's founding tracks, wandered off its light, paired again: the key
                # must stay one pair's (receiver.locate.vehicle follows pairs by it)
                p.alias = p.ids
            keys.add(p.key)
            taken.update((a.track_id, b.track_id))
            self.pairs.append(p)
        self._pair_jumpers(tracks, paired | taken)
        self._table = self._preds = None
        return self.pairs

    def _mark_beside(self, tracks: list[Track]) -> None:
        """`Pair.beside` of every pair in this frame: a decoded
        jumper pair that explained no blob, with a blob of this frame that no pair explains within
        its baseline plus `match_min_px` horizontally and `match_min_px` vertically of one of its
        emitters. That blob is most likely its own head's half that the gate missed: the pair
        then sits beside its head (the yaw shift is ambiguous by the baseline), and one of its
        emitters may be nearer a neighbouring head than its own."""
        cand = [p for p in self.pairs if p.led_id is not None and p.a.track_id == p.b.track_id]
        for p in self.pairs:
            p.beside = False
        if not cand:
            return
        taken = {t.track_id for p in self.pairs for t in p.tracks}
        free = [t for t in tracks if t.seen and t.track_id not in taken]
        for p in cand:
            if p.misses == 0 or not free:
                continue
            reach = abs(p.b.cx - p.a.cx) + self.match_min_px
            size = max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0)
            lo, hi = min(p.a.cx, p.b.cx), max(p.a.cx, p.b.cx)
            p.beside = any((lo - reach <= t.cx < lo or hi < t.cx <= hi + reach)
                           and abs(t.cy - p.my) <= abs(p.b.cy - p.a.cy) / 2 + self.match_min_px
                           and 1.0 / self.max_cut <= t.blob.area_px / size <= self.max_merged
                           for t in free)

    def _drop_twins(self, pairs: list[Pair]) -> list[Pair]:
        """`pairs` without the undecoded jumper pairs whose midpoint lies on a decoded jumper
        pair's head (within its baseline plus `match_min_px` horizontally, `match_min_px`
        vertically): one far head followed twice, half a baseline apart (which half a blob is
        cannot be told), when one copy decoded; the twin's emitters would sit beside the
        decoded ones, on nobody's light."""
        heads = [p for p in pairs if p.led_id is not None and p.a.track_id == p.b.track_id]
        if not heads:
            return pairs
        out = []
        for p in pairs:
            if p.led_id is None and p.a.track_id == p.b.track_id and any(
                    abs(p.mx - d.mx) <= abs(d.b.cx - d.a.cx) + self.match_min_px
                    and abs(p.my - d.my) <= self.match_min_px for d in heads):
                continue
            out.append(p)
        return out

    def _pair_jumpers(self, tracks: list[Track], busy: set[int]) -> None:
        """Pairs from single tracks that jump between two places: a far head's halves are
        never two blobs of one frame (module docstring), so one track takes the blob of
        whichever half is lit. Two jumps of about the same baseline between single-emitter-
        sized blobs (either direction) make a pair at the two places."""
        live = {t.track_id for t in tracks}
        for d in (self.last_seen, self.jumps):
            for tid in [tid for tid in d if tid not in live]:
                del d[tid]
        for t in tracks:
            last = self.last_seen.get(t.track_id)
            if not t.seen:
                continue
            self.last_seen[t.track_id] = (t.blob, self.shift_sum)
            if last is None or t.track_id in busy:
                continue
            # the jump without the camera's shake since the track's previous blob (it may have
            # been dark for a few frames)
            last, s0 = last
            ox, oy = self.shift_sum[0] - s0[0], self.shift_sum[1] - s0[1]
            jx, jy = t.cx - last.cx - ox, t.cy - last.cy - oy
            if jx < 0:
                jx, jy = -jx, -jy  # left-to-right baseline either way
            diam = math.sqrt(max(0.5 * (t.blob.area_px + last.area_px), 1.0))
            ratio = max(t.blob.area_px, 1.0) / max(last.area_px, 1.0)
            if not (self.geom["min_baseline"] * diam <= jx <= self.jump_max_baseline * diam
                    and abs(jy) <= self.geom["row_band"] * diam
                    and 1.0 / self.merged_ratio <= ratio <= self.merged_ratio):
                continue
            prev = self.jumps.get(t.track_id)
            self.jumps[t.track_id] = (jx, jy)
            # Each jump is the baseline plus the light's motion over one frame, in opposite
            # directions for a back-and-forth track (B -> A, A -> B): the left-to-right jumps
            # then differ by about twice that motion. The camera's pitch vibration moves lights
            # by 1-2 px per frame, mostly vertically, so `jump_agree_y_px` of the vertical
            # difference is forgiven before the two must agree within jump_agree diameters.
            if prev is None or math.hypot(jx - prev[0], max(abs(jy - prev[1]) - self.jump_agree_y_px, 0.0)
                                          ) > self.jump_agree * diam:
                continue
            # their mean is the baseline without the motion
            jx, jy = 0.5 * (jx + prev[0]), 0.5 * (jy + prev[1])
            right = t.cx - last.cx - ox > 0  # the current blob is the right-hand emitter
            ax, ay = (t.cx - jx, t.cy - jy) if right else (t.cx, t.cy)
            if (t.track_id, t.track_id) in self.banned:
                continue
            a, b = _emitter(t), _emitter(t)
            a.blob = moved(t.blob, ax, ay)
            b.blob = moved(t.blob, ax + jx, ay + jy)
            p = Pair(a, b, fresh=False, tracks=[t], nearby=[t], ids=(self.new_id(), self.new_id()))
            lv = self.levels.get(t.track_id)
            if lv is not None and t.blob.area_px >= self.jumper_levels_min_area_px:
                # A near head (halves of >= jumper_levels_min_area_px): its track's learned
                # on / off levels (lit when it had a half's blob, dark otherwise) seed both
                # emitters', so its first samples are read against them, not against one or
                # two values (a wrong sign each, folded into the packet's first estimate). A far
                # head's per-emitter reads stay neutral until its own levels are learned: which
                # half is lit cannot be told under the yaw shake (its flux is read instead).
                for v in (lv.on, lv.off):
                    p.levels_a.add(v)
                    p.levels_b.add(v)
            p.backlog = self._jumper_backlog(self.past.pop(t.track_id, ()), t.blob.area_px, last.area_px)
            head = self._head_backlog(ax + 0.5 * jx, ay + 0.5 * jy, jx, max(0.5 * (t.blob.area_px + last.area_px), 1.0))
            if len(head) > len(p.backlog):
                p.backlog = head
            self.pairs.append(p)
            busy.add(t.track_id)
            self.jumps.pop(t.track_id, None)

    def _head_backlog(self, mx: float, my: float, base_px: float, single: float) -> list[tuple]:
        """`Pair.backlog` of a new far-head pair (midpoint (mx, my) and horizontal baseline
        `base_px` in this frame's view, one emitter's area `single` px^2) from every blob of the
        last frames near the head, whichever track had it: a far head's blobs are shared by
        several short tracks (one per half and one for both, each ending when another takes
        its blobs), so its own track often holds only the last few frames of the packet.
        Going back frame by frame, the head's place is moved by the image shifts since
        (`view_sum`) and follows its blobs slowly (the head's own motion); the blobs within
        half a baseline plus `match_min_px` horizontally and `match_min_px` vertically are
        classified as in `_jumper_backlog`: none = both dark, up to `merged_ratio` x `single`
        = one half lit (anti-phase), more = both lit."""
        hist = list(self.scene_past)[:-1]  # this frame: the pair's own sample
        sx_now, sy_now = self.view_sum
        tol_x = 0.5 * abs(base_px) + max(self.match_min_px, math.sqrt(single))
        tol_y = self.match_min_px
        cx, cy = mx, my
        out, kept, empty = [], 0, 0
        for t_s, (sx, sy), xy, area in reversed(hist):
            ox, oy = sx_now - sx, sy_now - sy
            px, py = cx - ox, cy - oy
            sel = (np.abs(xy[:, 0] - px) <= tol_x) & (np.abs(xy[:, 1] - py) <= tol_y) if len(xy) else np.zeros(0, bool)
            if not sel.any():
                empty += 1
                if empty > self.head_gap_frames:  # lost (or not yet detected): stop there
                    break
                out.append((t_s, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0))
                continue
            empty, kept = 0, len(out) + 1
            both = float(area[sel].sum()) > self.merged_ratio * single
            out.append((t_s, 1.0, 1.0 if both else 0.0, 1.0, 1.0, 0.0, 0.0))
            c = xy[sel].mean(axis=0)
            cx += self.head_follow * (c[0] + ox - cx)
            cy += self.head_follow * (c[1] + oy - cy)
        return out[:kept][::-1]  # from the oldest frame with a blob

    @staticmethod
    def _two_track_backlog(p: Pair, past_a, past_b) -> list[tuple]:
        """`Pair.backlog` of a pair of two tracks: the frames before this one in which both
        were read, with the pair's levels (seeded by the same history). The decoder then
        starts from the tracks' birth, not from the pair's formation 4-15 frames later, and
        has its packet when the light's is whole."""
        va = {t: v for t, _, _, v in past_a}
        la, lb = p.levels_a, p.levels_b
        lv = (la.on, lb.on, la.off, lb.off)
        return [(t, va[t], vb) + lv for t, _, _, vb in list(past_b)[:-1] if t in va]  # this frame: the pair's own

    def _jumper_backlog(self, past, area_now: float, area_last: float) -> list[tuple]:
        """`Pair.backlog` of a pair from one jumping track (a far head it alone followed,
        `_pair_jumpers`), from its blob sizes: a blob of one emitter's size is one half lit,
        anti-phase (a = 1, b = 0); a merged blob (over `merged_ratio` of one emitter, both lit)
        or none (both dark) is in phase (1, 1) / (0, 0); levels on 1, off 0."""
        single = max(0.5 * (area_now + area_last), 1.0)
        out = []
        for t, seen, area, _ in list(past)[:-1]:  # this frame: the pair's own sample
            b = 0.0 if seen and area <= self.merged_ratio * single else float(seen)
            out.append((t, float(seen), b, 1.0, 1.0, 0.0, 0.0))
        return out

    def emitters(self) -> list[tuple[int, Blob, Pair]]:
        """This frame's S2-PSK emitter observations: (LED id, envelope at the emitter's current
        position, its pair) for both emitters of every live pair that explained a blob within
        the last `report_coast_frames` frames. An emitter is reported also when it is dark in
        this frame: S2-PSK lights each emitter in half of every 5 ms clock period, so a frame
        exposed for 0.1 ms sees both halves of a head dark in about a quarter of the frames
        (symbol 0, off half-period) and one half dark in another half of them (symbol 1); the
        pair knows where they are (it reads their intensities there), and its ID belongs to
        both. An undecoded pair's emitter within `match_min_px` of a decoded pair's emitter is
        left out (one head followed by two pairs: the LED is the decoded one's)."""
        live = [p for p in self.pairs if p.misses <= self.report_coast_frames]
        if not live:
            return []
        # A far head's (jumper) pair may sit a baseline aside (which half a blob was cannot be
        # told): its emitter that has not had a blob of its own for `jumper_unseen_frames`
        # frames lies beside the head, on nobody's light, and is not reported (0 = off).
        # One that coasted may now sit a baseline aside, one emitter on the head behind or
        # beside it: not reported until a blob both lit places it again (`anchor_coast_frames`).
        dec = [(i, e.blob, p, seen == p.frames) for p in live if p.led_id is not None
               for i, e, seen in zip(p.ids, (p.a, p.b), (p.seen_a, p.seen_b))
               if not (self.jumper_unseen_frames and p.a.track_id == p.b.track_id
                       and p.frames - seen > self.jumper_unseen_frames)
               and (p.anchored or p.a.track_id != p.b.track_id) and not p.beside]
        xy = np.array([(b.cx, b.cy) for _, b, _, _ in dec], float).reshape(-1, 2)
        owner = np.array([id(p) for _, _, p, _ in dec])
        size = np.array([max(p.a.blob.area_px, p.b.blob.area_px) for _, _, p, _ in dec], float)
        out = []
        if dec:
            # every decoded emitter against every other pair's at once (row k: emitter k)
            d = np.hypot(xy[None, :, 0] - xy[:, 0, None], xy[None, :, 1] - xy[:, 1, None])
            other = owner[None, :] != owner[:, None]
            # both emitters of a pair are the same size: its larger envelope (the other may be
            # stale), and the larger of the two lights'
            area = np.maximum(size[:, None], size[None, :])
            gate = np.maximum(self.match_min_px, self.match_size * np.sqrt(np.maximum(area, 1.0)))
            clear = ((d > gate) | ~other).all(axis=1)
            # An emitter without its own blob in this frame sits where the pair predicts it: left
            # out when that is as near another decoded pair's emitter (overlapping lights).
            out = [(i, b, p) for (i, b, p, own), ok in zip(dec, clear.tolist()) if own or ok]
        und = [(i, e.blob, p) for p in live if p.led_id is None for i, e in zip(p.ids, (p.a, p.b))]
        if und and len(xy):
            u = np.array([(b.cx, b.cy) for _, b, _ in und], float)
            near = np.hypot(xy[None, :, 0] - u[:, 0, None], xy[None, :, 1] - u[:, 1, None]).min(axis=1)
            und = [e for e, ok in zip(und, (near > self.match_min_px).tolist()) if ok]
        return out + und

    @staticmethod
    def sample(p: Pair, gray: np.ndarray, intensity) -> tuple[float, float]:
        """This frame's (a, b) intensities of a pair; updates its levels."""
        if p.fresh:
            p.fresh = False
            return p.levels_a.values[-1], p.levels_b.values[-1]
        ia, ib = intensity(gray, p.a), intensity(gray, p.b)
        p.levels_a.add(ia)
        p.levels_b.add(ib)
        return ia, ib

    @staticmethod
    def sample_all(pairs: list[Pair], gray: np.ndarray, intensities) -> list[tuple[float, float]]:
        """`sample` of every pair of `pairs`, their emitters read by one
        `intensities(gray, tracks) -> list of float` call."""
        vals = iter(intensities(gray, [e for p in pairs if not p.fresh for e in (p.a, p.b)]))
        out = []
        for p in pairs:
            if p.fresh:
                p.fresh = False
                out.append((p.levels_a.values[-1], p.levels_b.values[-1]))
                continue
            ia, ib = next(vals), next(vals)
            p.levels_a.add(ia)
            p.levels_b.add(ib)
            out.append((ia, ib))
        return out

    def sample_flux(self, p: Pair, gray: np.ndarray) -> float:
        """This frame's `head_flux` of pair `p` (gray x px), kept in `Pair.flux`."""
        f = self.head_flux(p, gray)
        p.flux.append(f)
        return f

    def reads_flux(self, p: Pair) -> bool:
        """Pair `p` is read by its head's total flux (`head_flux`), not per emitter: a pair from
        one jumping track (`_pair_jumpers`: a far head whose halves merge)."""
        return p.a.track_id == p.b.track_id

    def flux_on(self, p: Pair) -> float:
        """Pair `p`'s both-lit flux 2F (gray x px) for `flux_xor`: twice the median of its last
        `flux_recent` fluxes above `flux_min` (the frames with a half or both lit: one half, F,
        in two thirds of them). Recent ones only: an approaching head's flux grows as
        1 / distance^2, doubling within a packet at 60-80 m."""
        lit = sorted([v for v in p.flux if v > self.flux_min][-self.flux_recent:])
        if not lit:
            return 0.0
        # np.median's value: the middle one, or the mean of the middle two ((a + b) / 2)
        n = len(lit)
        return 2.0 * (lit[n // 2] if n % 2 else (lit[n // 2 - 1] + lit[n // 2]) / 2.0)

    def head_flux(self, p: Pair, gray: np.ndarray) -> float:
        """The summed gray above the background (+ `flux_floor` gray, so sensor noise adds
        nothing) in a box around pair `p`'s head (gray x px). A far head's halves are a few px
        apart and the camera's yaw shake moves it by more than that from frame to frame, so
        which half a blob is cannot be told; but the XOR needs no side: the head's flux is
        ~0 (both dark), F (one half lit: symbol 1) or 2F (both lit). The box is centred on the
        blob the pair explained in this frame (whichever half it is), else on the pair's
        midpoint, and reaches one baseline plus `flux_margin_px` either side, and
        `flux_margin_px` above and below the emitters' envelopes."""
        x0, x1, y0, y1, bg = self._flux_box(p, gray.shape)
        if x1 <= x0 or y1 <= y0:
            return 0.0
        roi = gray[y0:y1, x0:x1].astype(np.float32)
        return float(np.maximum(roi - bg, 0.0).sum())

    def _flux_box(self, p: Pair, shape) -> tuple[int, int, int, int, float]:
        """`head_flux`'s box x0, x1, y0, y1 (px, half-open, clipped to the frame of `shape`) and
        its background level (gray)."""
        cx, cy = p.mx, p.my
        base = math.hypot(p.b.cx - p.a.cx, p.b.cy - p.a.cy)
        half_h = 0.5 * max(p.a.blob.y1 - p.a.blob.y0, p.b.blob.y1 - p.b.blob.y0)
        mx, my = self.flux_margin_px, self.flux_margin_y_px
        h, w = shape[:2]
        x0, x1 = max(int(math.floor(cx - base - mx)), 0), min(int(math.ceil(cx + base + mx)) + 1, w)
        y0, y1 = max(int(math.floor(cy - half_h - my)), 0), min(int(math.ceil(cy + half_h + my)) + 1, h)
        return x0, x1, y0, y1, float(p.a.blob.background) + self.flux_floor

    def sample_fluxes(self, pairs: list[Pair], gray: np.ndarray) -> list[float]:
        """`sample_flux` of every pair of `pairs` (one kernel call), in order."""
        if _k is None or not pairs or gray.dtype != np.uint8 or gray.ndim != 2:
            return [self.sample_flux(p, gray) for p in pairs]
        boxes = [self._flux_box(p, gray.shape) for p in pairs]
        out = np.empty(len(pairs))
        _k.head_fluxes(gray, np.array([b[:4] for b in boxes], np.int64).reshape(-1, 4),
                       np.array([b[4] for b in boxes], float), out)
        vals = out.tolist()
        for p, f in zip(pairs, vals):
            p.flux.append(f)
        return vals
