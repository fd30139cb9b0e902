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


The frame's camera shift (`step`'s `shift`) moves every pair's prediction before its blobs are
matched: a lone lit half is A or B by where the shifted pair puts them.

Layout: receiver.vision.pair_model (the `Pair` record, `EmitterLevels`, `PairTuning`, the
baseline model, a pair's update from the blobs it explains), pair_match (which blobs a pair
explains, lone blobs, re-anchoring), pair_found (a far head's jumper pairs, new pairs'
backlogs, twin pairs), pair_read (the emitters reported, their intensities, a far head's flux);
`Pairer` here: the per-frame flow and the compiled kernels' calls.

Cost: the loops over pairs x blobs run compiled (receiver/vision/_pairing.pyx), once per
pass and frame, not per pair: `_explain` of every pair with `_first_pass`'s claims
(`_explain_batch`), `shift_votes`, `dx_offsets` and the heads' fluxes (`sample_fluxes`); the
intensities of a frame's emitters are read in one call (receiver.vision.profile.mean_in_masks).
Their decisions and numbers equal the Python code (here and in pair_match) to the bit (math.hypot's algorithm,
numpy's summation orders), which stays the reference (`OCCLOC_PURE=1`, tests/engine/test_pair_kernels.py).
"""

from __future__ import annotations

import itertools
import math
from collections import deque

import numpy as np

from receiver.core.native import load
from receiver.core.records import Blob
from receiver.core.settings import resolve_settings
from receiver.vision.pair_found import JumpWatch, drop_twins, head_backlog, jumper_pair, mark_beside, two_track_backlog
from receiver.vision.pair_match import (anothers, bloom_checked, claim_tol, dx_offsets_of, explain, lone_checked,
                                        other_lamps, pitch_and_claims, reanchor, shift_votes_of, width_class)
from receiver.vision.pair_model import (BOTH_SEEN_FRAMES, LIVE, TUNING, WRONG, EmitterLevels, Pair, PairTuning,
                                        _emitter, follow_update, measure_baseline, moved, pair_score, predict)
from receiver.vision.pair_read import emitters, flux_box, flux_on, head_flux
from receiver.vision.pair_read import sample as read_sample
from receiver.vision.pair_read import sample_all as read_sample_all
from receiver.vision.settings import PairSettings
from receiver.vision.track import Track

__all__ = ["BANNED_PRUNE_AT", "BOTH_SEEN_FRAMES", "TUNING", "EmitterLevels", "Pair", "PairTuning", "Pairer",
           "moved", "pair_score"]

# the compiled candidate search (receiver/vision/_pairing.pyx: `_explain` of every pair in one
# call per pass), or None: the Python reference (here and receiver.vision.pair_match)
_k = load("receiver.vision._pairing")

BANNED_PRUNE_AT = 64  # Pairer.banned entries above which bans of dropped tracks are forgotten



def _rows_table(rows: list, width: int) -> np.ndarray:
    """(len(rows), width) float64 of equal-length tuples of numbers: np.array(rows, float), made
    by np.fromiter over the flattened values (half the cost: no nested-sequence discovery)."""
    return np.fromiter(itertools.chain.from_iterable(rows), float, width * len(rows)).reshape(-1, width)


class Pairer:
    """Keeps S2-PSK pairs over frames (init/step).

    Tunables: `PairSettings` (receiver.vision.settings), given as `settings=` or as keyword
    overrides of its fields.
    """

    def __init__(self, *, settings: PairSettings | None = None, new_id=None, white_gray: float = math.inf,
                 **overrides):
        """`new_id() -> int`: fresh LED ids for the pairs' emitters, never a track's id
        (receiver.vision.track.Tracker.new_id); None: a counter of this pairer's own.
        `white_gray`: the sensor's white level (receiver.vision.detect.SATURATED_GRAY):
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
        # every frame's seen blobs, (t_s, view_sum then, [cx, cy, area_px] per blob), for the
        # backlog of a far head's new pair whatever tracks followed it (`_head_backlog`)
        self.scene_past: deque = deque(maxlen=max(self.backlog_frames, 1))
        self.view_sum = (0.0, 0.0)  # every frame's image shift added up (measured or `pitch_shift`), px
        self.jump_watch = JumpWatch()  # per track, its latest blob and jump (a far head's jumper pairs)
        self.shift = (0.0, 0.0)  # the latest frame's common image shift, px
        self.shift_sum = (0.0, 0.0)  # the measured shifts added up, px (jumps over dark frames)
        self.vertical_known = False  # this frame's vertical shift was measured (step's `shift`)
        self._cfg_arr: np.ndarray | None = None  # the kernel's settings (`_cfg`)
        self._table: tuple | None = None  # (tracks list, its length, `_track_table`) of this frame
        self._preds: tuple | None = None  # (pairs list, its length, `_predictions`) until a pair moves

    def _predict(self, p: Pair) -> tuple[float, float, float, float, float]:
        """receiver.vision.pair_model.predict of pair `p`: (mx, my, hx, hy, single) px, px^2."""
        return predict(p, self.growth_span_frames)

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
        """receiver.vision.pair_match.explain with this pairer's gates."""
        return explain(self, p, tracks, xy, mx, my, hx, hy, single, exclude)

    def _width_class(self, p: Pair, blob: Blob, hx: float) -> str | None:
        """receiver.vision.pair_match.width_class with this pairer's gates."""
        return width_class(self, p, blob, hx)

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
        return shift_votes_of(pred, xy, radius_px)

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
            bl = _rows_table([(b.cx, b.cy, b.area_px, b.x0, b.x1, b.y0, b.y1, 1) for b in blobs], 8)
            res = np.full((len(items) * len(bl), 2), np.inf)
            n = _k.dx_offsets(bl, self._pair_rows(items, False), self._cfg(), float(dy), float(radius_px), res)
            return res[:n]
        return dx_offsets_of(self, self._predictions(), blobs, xy, dy, radius_px)

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
        dys = []
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
            # claims it too, by none of them when two decoded ones do (pair_match.pitch_and_claims)
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
        return pitch_and_claims(self, self._predictions(), tracks, xy, pitch)

    def _track_table(self, tracks: list[Track]) -> np.ndarray:
        """(N, 8) cx, cy, area_px, x0, x1, y0, y1, seen of the tracks' blobs (the kernel's
        `tr`; seen: 0 unseen, 1 seen, 2 seen and saturated at `white_gray`), built once per frame (the tracks do not change within `step`)."""
        memo = self._table
        if memo is not None and memo[0] is tracks and len(tracks) == memo[1]:
            return memo[2]
        white = self.white_gray
        tr = _rows_table([(t.blob.cx, t.blob.cy, t.blob.area_px, t.blob.x0, t.blob.x1, t.blob.y0, t.blob.y1,
                           (2.0 if t.blob.peak >= white else 1.0) if t.seen else 0.0) for t in tracks], 8)
        self._table = (tracks, len(tracks), tr)
        return tr

    def _pair_rows(self, items: list, claims: bool) -> np.ndarray:
        """(P, 14) the kernel's `pp` rows of (pair, prediction, exclude) `items`; the claim
        tolerance (`pair_match.claim_tol`) with `claims` for the decoded pairs, else -1."""
        rows = []
        for p, (mx, my, hx, hy, single), _ in items:
            a, b = p.a.blob, p.b.blob
            ctol = claim_tol(self, single) if claims and p.led_id is not None else -1.0
            rows.append((mx, my, hx, hy, single, p.misses, a.area_px, b.area_px, p.size, a.x1 - a.x0,
                         b.x1 - b.x0, a.y1 - a.y0, b.y1 - b.y0, ctol))
        return _rows_table(rows, 14)

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
        apart that no pair explains (`pair_match.reanchor`); one that explains another pair's emitter
        (`pair_match.anothers`) loses `Pair.confirmed`; the nearer lights' lamps seen beside a
        placed pair join its `Pair.others` (`pair_match.other_lamps`), never explained by it."""
        items = []
        for p in self.pairs:
            pred = self._follow_start(p, dx, dy)
            if pred is not None:
                excl = exclude.get(p.uid, ())
                items.append((p, pred, p.others.union(excl) if p.others else excl))
        if _k is not None:
            found = [(expl, nearby, (sx, sy) if ns else None, obs_a, obs_b, merged)
                     for expl, nearby, ns, sx, sy, _, obs_a, obs_b, merged, _ in self._explain_batch(items, tracks, False)]
        else:
            found = []
            for p, pred, excl in items:
                expl, nearby, shifts, obs_a, obs_b, merged = self._explain(p, tracks, xy, *pred, excl)
                mean = tuple(float(v) for v in np.mean(shifts, axis=0)) if shifts else None
                found.append((expl, nearby, mean, obs_a, obs_b, merged))
        found = [bloom_checked(self, p, pred, lone_checked(self, p, f)) for (p, pred, _), f in zip(items, found)]
        lamps = [t for t in tracks if t.seen and t.blob.peak >= self.white_gray]  # `other_lamps`
        for (p, pred, _), f in zip(items, found):
            if lamps and f[0]:
                p.others.update(other_lamps(self, p, pred, f, lamps))
        taken = {t.track_id for f in found for t in f[0]}
        # the two-track pairs whose emitter another pair may take (`pair_match.anothers`): the decoded ones
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
                again = reanchor(self, p, pred, tracks, self._track_table(tracks), taken)
                if again is not None:
                    expl, mean, obs_a, obs_b = again
                    nearby = nearby + [t for t in expl if t not in nearby]
                    taken.update(t.track_id for t in expl)
            if owners and p.a.track_id != p.b.track_id and any(
                    anothers(self, p, t, pred, ow) for t in expl if (ow := owners.get(t.track_id)) is not None):
                p.confirmed = False  # another pair's emitter: its samples may be another light's
            if self._follow_end(p, shape, pred, expl, nearby, mean, obs_a, obs_b, merged):
                out.append(p)
        return out

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
        """`_follow`'s second part (receiver.vision.pair_model.follow_update); False when the
        pair ends (its founding tracks banned when it was a wrong pairing)."""
        self._preds = None  # the pairs move
        fate = follow_update(self, p, shape, pred, explaining, nearby, mean, obs_a, obs_b, merged)
        if fate == WRONG:
            self.banned.add(p.founding)
        return fate == LIVE
    def _measure_baseline(self, p: Pair, hx: float, hy: float, obs_a, obs_b, merged) -> None:
        """receiver.vision.pair_model.measure_baseline with this pairer's gates."""
        measure_baseline(self, p, hx, hy, obs_a, obs_b, merged)

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
                lit = table[table[:, 7] != 0.0, :3].tolist()
            else:
                lit = [[float(t.cx), float(t.cy), float(t.blob.area_px)] for t in tracks if t.seen]
            self.scene_past.append((float(t_s), self.view_sum, lit))
        self.pairs = self._follow_all(tracks, shape, dy, dx, exclude, xy)
        self.pairs = drop_twins(self, self.pairs)
        mark_beside(self, self.pairs, tracks)
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
            p.backlog = two_track_backlog(p, self.past.pop(a.track_id, ()), self.past.pop(b.track_id, ()))
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

    def _drop_twins(self, pairs: list[Pair]) -> list[Pair]:
        """receiver.vision.pair_found.drop_twins with this pairer's gates."""
        return drop_twins(self, pairs)

    def _pair_jumpers(self, tracks: list[Track], busy: set[int]) -> None:
        """Pairs from single tracks that jump between two places: a far head's halves are
        never two blobs of one frame (module docstring), so one track takes the blob of
        whichever half is lit (receiver.vision.pair_found.JumpWatch); `busy`: the track ids
        that are a pair's already, this frame's new jumper pairs' added."""
        for t, last, ax, ay, jx, jy in self.jump_watch.jumps(self, tracks, busy, self.shift_sum):
            if (t.track_id, t.track_id) in self.banned:
                continue
            p = jumper_pair(self, t, last, (ax, ay), (jx, jy), (self.new_id(), self.new_id()),
                            self.levels.get(t.track_id), self.past.pop(t.track_id, ()))
            self.pairs.append(p)
            busy.add(t.track_id)
            self.jump_watch.last_jump.pop(t.track_id, None)
    def _head_backlog(self, mx: float, my: float, base_px: float, single: float) -> list[tuple]:
        """receiver.vision.pair_found.head_backlog from this pairer's frame history."""
        return head_backlog(self, mx, my, base_px, single)

    def emitters(self) -> list[tuple[int, Blob, Pair]]:
        """This frame's S2-PSK emitter observations (LED id, envelope, its pair):
        receiver.vision.pair_read.emitters of the live pairs."""
        return emitters(self, self.pairs)

    sample = staticmethod(read_sample)
    sample_all = staticmethod(read_sample_all)

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
        """receiver.vision.pair_read.flux_on: pair `p`'s both-lit flux 2F (gray x px)."""
        return flux_on(self, p)

    def head_flux(self, p: Pair, gray: np.ndarray) -> float:
        """receiver.vision.pair_read.head_flux: the flux around pair `p`'s head (gray x px)."""
        return head_flux(self, p, gray)

    def _flux_box(self, p: Pair, shape) -> tuple[int, int, int, int, float]:
        """receiver.vision.pair_read.flux_box with this pairer's margins."""
        return flux_box(self, p, shape)

    def sample_fluxes(self, pairs: list[Pair], gray: np.ndarray) -> list[float]:
        """`sample_flux` of every pair of `pairs` (one kernel call), in order."""
        if _k is None or not pairs or gray.dtype != np.uint8 or gray.ndim != 2:
            return [self.sample_flux(p, gray) for p in pairs]
        boxes = [flux_box(self, p, gray.shape) for p in pairs]
        out = np.empty(len(pairs))
        _k.head_fluxes(gray, np.array([b[:4] for b in boxes], np.int64).reshape(-1, 4),
                       np.array([b[4] for b in boxes], float), out)
        vals = out.tolist()
        for p, f in zip(pairs, vals):
            p.flux.append(f)
        return vals
