"""One camera-motion estimate per frame, from every blob, kept by the lights that agree.

A dash camera shakes: yaw and pitch of a few tenths of a degree as slow swings (0.5-2.5 Hz)
plus frame-to-frame jitter. With a 1300-1500 px focal length every light moves by several px
from one frame to the next, more than the gap between the two emitters of a far head. That
motion is common to the whole image; what is not common is each light's own motion (the forward
drive spreads static lights away from the focus of expansion, several px per frame for a head
20-30 m ahead) and which emitters are lit (an S2-PSK emitter is dark in half the frames, so a
frame holds about half of the lights' blobs, and seldom the same half as the frame before).

So the image is not registered on the previous frame's blobs, but on the *lights*: every blob
seen is a light in stabilised image coordinates (the image place minus the camera's summed
shift `C`), with its own motion, radial from the focus of expansion F (`kappa` (p - F) per
frame: what driving forward does to a point at rest or to a car ahead at a like speed). A light
dark in this frame keeps its predicted place for `history_frames` frames, so a blob lit now
finds the light it belongs to whatever was lit in the frame before.

Per frame (`CameraMotion.step`):

1. votes: every displacement between a blob and a light's prediction within `radius_px` of the
   last camera offset; each blob has one vote, shared among the lights it may be (a far head's
   two halves, a row of like heads); the vote's peaks (`peaks`) are candidate offsets, and so
   is any shift given from elsewhere (the S2-PSK pairs' own estimate). A candidate's support is
   the number of blobs within `gate_px` of a light's prediction, its offset their median.
2. hypotheses: one frame's support is often 2-3 blobs and a wrong peak can tie with the right
   one, and a wrong offset taken for good would move every light it matched to a wrong place
   (the next frames would then agree with the wrong one). So `beam` hypotheses are kept, each
   with its own lights; a hypothesis' score adds, per frame, its candidate's support (blobs)
   and the log-likelihood of the shift under the shake (zero-mean, `shake_px` per axis), less
   `miss_cost` for a frame left unmeasured. The best hypothesis gives the frame's shift; one
   that was behind takes over when the next frames agree with its lights better.
3. lights: the chosen candidate's blobs update their lights (place, and `kappa` by
   `velocity_gain`); a light seen once takes its own motion from its second sighting, within
   `new_gate_px`; a blob near no light is a new light. F follows the lights' residuals
   (`foe_gain`): a light's `kappa` scales an error of F, the camera's shift does not.

The estimate has no roll: a frame-to-frame roll of the shake (0.05 degrees) moves a light 600 px
from the centre by 0.5 px, within `gate_px`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

# Two hypotheses whose camera offset and last shift are within this are one (px).
_SAME_PX = 0.5
# The vote's histogram bin (px): finer than the centroid noise of a far half.
_BIN_PX = 0.5
# Each light's own motion per frame, as the fraction kappa of its distance to F: a light
# 5 m ahead at 20 m/s grows by 0.13 per frame; a small negative value is a car pulling away.
_KAPPA_RANGE = (-0.01, 0.2)


# The largest pixel distance a gate may name (beyond any camera's frame), and the largest
# frame-to-frame shift searched (a vote grid of (2 * 200 / _BIN_PX)^2 cells).
MAX_DISTANCE_PX = 10000.0
MAX_RADIUS_PX = 200.0


@dataclass(frozen=True)
class MotionSettings:
    """The camera-motion estimate's knobs.

    radius_px [14 px]: the largest frame-to-frame image shift searched (0.5 degrees of shake at a
        1500 px focal length; at most 200 px, and at least match_px).
    match_px [1.5 px]: half-width of the vote's smoothing window (a far half's centroid noise of
        about 0.5 px plus the error of a light's own-motion prediction).
    gate_px [2 px]: how far from a light's prediction a blob may be and still be that light.
    new_gate_px [8 px]: how far a light seen once may have moved to its second sighting (its own
        motion is not known yet: a head 20 m ahead at 70 km/h moves about 8 px per frame).
    history_frames [8 frames]: how long a light is kept while dark (an S2-PSK emitter is dark in
        runs of up to three frames; a car can hide a light for a few more).
    max_area_ratio [2.0]: a blob is a light only if their areas (each plus 2 px^2 of slack for a
        far half of a few px) differ by less than this factor (one emitter lit against both).
    min_matches [1 blob]: the fewest blobs on lights' predictions that make a vote peak a
        candidate offset (the hypotheses, not one frame, settle an ambiguous peak).
    beam [8 hypotheses]: camera-offset hypotheses kept, each with its own lights.
    peaks [3]: vote peaks tried per hypothesis and frame.
    shake_px [4 px]: 1-sigma per-axis frame-to-frame image shift of the shake, the prior of a
        hypothesis' shifts (0.3 degrees rms of 0.5-2.5 Hz swings plus 0.05 degrees of jitter at a
        1400 px focal length).
    miss_cost [0.5 blobs]: what a frame left unmeasured costs a hypothesis (a blob that finds its
        light is worth one).
    velocity_gain [0.5]: the fraction of a light's own-motion error corrected per sighting
        (its blob's centroid noise against a slowly growing expansion).
    foe_gain [0.1]: the fraction of the focus of expansion's error corrected per frame.
    given_votes [0 blobs]: what a shift measured elsewhere (the pairs' own, from where each
        pair expects its emitters) weighs besides the blobs on lights at it (0: it is one
        candidate like a vote peak; its errors come with the pairs' own, not the lights').
    """

    radius_px: float = 14.0
    match_px: float = 1.5
    gate_px: float = 2.0
    new_gate_px: float = 8.0
    history_frames: int = 8
    max_area_ratio: float = 2.0
    min_matches: int = 1
    beam: int = 8
    peaks: int = 3
    shake_px: float = 4.0
    miss_cost: float = 0.5
    velocity_gain: float = 0.5
    foe_gain: float = 0.1
    given_votes: float = 0.0

    def __post_init__(self):
        # a count below one has no meaning (zero would act as one, or keep nothing)
        for name in ("history_frames", "min_matches", "beam", "peaks"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"{name} must be at least 1, not {getattr(self, name)!r}")
        for name in ("radius_px", "match_px", "gate_px", "new_gate_px", "max_area_ratio", "shake_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, not {getattr(self, name)!r}")
        for name in ("gate_px", "new_gate_px", "shake_px"):
            if not getattr(self, name) <= MAX_DISTANCE_PX:
                raise ValueError(f"{name} must be at most {MAX_DISTANCE_PX:g} px, not {getattr(self, name)!r}")
        # the vote grid is (2 radius / bin)^2 cells: a search wider than MAX_RADIUS_PX is no shake
        if not self.radius_px <= MAX_RADIUS_PX:
            raise ValueError(f"radius_px must be at most {MAX_RADIUS_PX:g} px, not {self.radius_px!r}")
        if not self.match_px <= self.radius_px:
            raise ValueError(f"match_px must be at most radius_px ({self.radius_px:g}), not {self.match_px!r}")
        for name in ("miss_cost", "given_votes", "velocity_gain", "foe_gain"):
            if not 0 <= getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be a finite number of at least 0, not {getattr(self, name)!r}")
        for name in ("velocity_gain", "foe_gain"):  # fractions of an error corrected
            if not getattr(self, name) <= 1:
                raise ValueError(f"{name} must be at most 1, not {getattr(self, name)!r}")


@dataclass(frozen=True)
class MotionEstimate:
    """The camera's image shift from the previous frame to this one.

    (dx_px, dy_px): the common shift (yaw and pitch) a light at rest would take, its own motion
    apart. `sigma_px`: 1-sigma error of the shift per axis (the matched blobs' spread over their
    number; a frame left unmeasured adds the shake's `shake_px`); `var_sum_px2`: the sum of
    every frame's sigma_px^2 so far (see `CameraMotion.sigma_since`); `matches`: blobs that
    found their light this frame (0: none did; the shift is then 0, or a given candidate's that
    no light contradicted)."""

    dx_px: float
    dy_px: float
    sigma_px: float
    var_sum_px2: float
    matches: int

    @property
    def measured(self) -> bool:
        return self.matches > 0


class _Lights:
    """One hypothesis: the camera offset `c` (summed shift, px), the lights in stabilised image
    coordinates and the hypothesis' score."""

    __slots__ = ("xy", "kappa", "dark", "seen", "area", "foe", "c", "shift", "score", "matches")

    def __init__(self, foe: np.ndarray):
        self.xy = np.zeros((0, 2))
        self.kappa = np.zeros(0)
        self.dark = np.zeros(0, int)   # frames since last seen (1: seen in the frame before)
        self.seen = np.zeros(0, int)   # sightings
        self.area = np.zeros(0)
        self.foe = foe
        self.c = np.zeros(2)
        self.shift = np.zeros(2)
        self.score = 0.0
        self.matches = 0

    def copy(self) -> "_Lights":
        h = _Lights(self.foe.copy())
        h.xy, h.kappa, h.dark = self.xy.copy(), self.kappa.copy(), self.dark.copy()
        h.seen, h.area, h.c = self.seen.copy(), self.area.copy(), self.c.copy()
        h.shift, h.score, h.matches = self.shift.copy(), self.score, self.matches
        return h

    def predicted(self) -> np.ndarray:
        """Each light's stabilised place this frame (its own radial motion added)."""
        return self.xy + self.kappa[:, None] * (self.xy - self.foe)


class CameraMotion:
    """The per-frame camera-motion estimate (see the module docstring): `step(xy, area_px)`
    once per frame with the frame's blob centroids and areas."""

    def __init__(self, center_px: tuple[float, float], settings: MotionSettings = MotionSettings()):
        self.settings = settings
        self.hyps = [_Lights(np.array(center_px, float))]
        self.var_sum_px2 = 0.0
        self.sigma_px = settings.shake_px
        self.frames = 0

    def sigma_since(self, var_sum_then_px2: float) -> float:
        """1-sigma error (px per axis) of the shifts summed since the frame whose estimate had
        `var_sum_px2` = `var_sum_then_px2` (a track's last sighting) up to the latest frame."""
        return math.sqrt(max(self.var_sum_px2 - var_sum_then_px2, 0.0))

    def step(self, xy: np.ndarray, area_px: np.ndarray | None = None, candidates=()) -> MotionEstimate:
        """This frame's estimate from its (N, 2) blob centroids (px), their (N,) areas (px^2;
        None or NaN: matched whatever the area) and `candidates`: shifts (dx, dy) px measured
        elsewhere, tried as well (their support decides, as for the vote's peaks)."""
        s = self.settings
        xy = np.asarray(xy, float).reshape(-1, 2)
        area = np.full(len(xy), np.nan) if area_px is None else np.asarray(area_px, float).reshape(-1)
        extra = [np.asarray(c, float) for c in candidates if c is not None and np.all(np.isfinite(c))]
        kids = []
        for h in self.hyps:
            for c, support, spread, bonus in self._candidates(h, xy, area, extra):
                kid = h.copy()
                self._commit(kid, c, support, xy, area, bonus)
                kids.append((kid, spread))
        kids.sort(key=lambda k: -k[0].score)
        kept = []
        for kid, spread in kids:
            if all(np.hypot(*(kid.c - o.c)) > _SAME_PX or np.hypot(*(kid.shift - o.shift)) > _SAME_PX
                   for o, _ in kept):
                kept.append((kid, spread))
            if len(kept) >= s.beam:
                break
        best, spread = kept[0]
        top = best.score
        for h, _ in kept:  # scores relative to the best (no drift over a long recording)
            h.score -= top
        self.hyps = [h for h, _ in kept]
        self.frames += 1
        n = best.matches if self.frames > 1 else 0
        if n:
            self.sigma_px = max(spread, 0.5 * s.match_px) / math.sqrt(n)
        else:
            self.sigma_px = math.hypot(self.sigma_px, s.shake_px)
        self.var_sum_px2 += self.sigma_px ** 2
        dx, dy = (best.shift if self.frames > 1 else (0.0, 0.0))
        return MotionEstimate(dx_px=float(dx), dy_px=float(dy), sigma_px=self.sigma_px,
                              var_sum_px2=self.var_sum_px2, matches=int(n))

    # -- one hypothesis ---------------------------------------------------------------------

    def _candidates(self, h: _Lights, xy: np.ndarray, area: np.ndarray, extra: list):
        """[(camera offset or None, support in blobs, matched blobs' rms spread px)] of
        hypothesis `h` for this frame: None (unmeasured) first, then the vote's peaks and the
        `extra` shifts that find at least `min_matches` blobs."""
        s = self.settings
        out = [(None, 0, 0.0, 0.0)]
        # a shift measured elsewhere stays a candidate when no blob is on a light at it (its
        # prior and the next frames judge it); with no light to judge it by, none is taken
        given = [h.c + e for e in extra]
        known = h.seen >= 1  # a light seen once has no own motion yet: it does not vote
        if not known.any():
            # none has: the lights seen once vote as at rest (a cold start; far lights move by
            # less than a px per frame)
            known = np.ones(len(h.seen), bool)
        if not known.any() or not len(xy):
            return out
        pred = h.predicted()[known]
        d = xy[:, None, :] - pred[None, :, :]           # the camera offset each pairing implies
        ok = np.all(np.abs(d - h.c) <= s.radius_px, axis=2)
        la = h.area[known]
        big = np.fmax(area[:, None], la[None, :]) + 2.0
        small = np.fmin(area[:, None], la[None, :]) + 2.0
        ok &= (big <= s.max_area_ratio * small) | np.isnan(area)[:, None] | np.isnan(la)[None, :]
        j, i = np.nonzero(ok)
        if not len(j):
            return out
        dd = d[j, i]
        peaks = [h.c + p for p in self._peaks(dd - h.c, j)]
        for k, c in enumerate(peaks + given):
            err = np.hypot(*(dd - c).T)
            # per blob, its pairing nearest the candidate
            order = np.lexsort((err, j))
            first = np.ones(len(order), bool)
            first[1:] = j[order][1:] != j[order][:-1]
            best = order[first]
            best = best[err[best] <= s.gate_px]
            bonus = s.given_votes if k >= len(peaks) else 0.0
            if len(best) >= s.min_matches:
                m = np.median(dd[best], axis=0)
                spread = float(np.sqrt(np.mean(np.sum((dd[best] - m) ** 2, axis=1)) / 2.0))
                out.append((m, len(best), spread, bonus))
            elif k >= len(peaks):
                out.append((c, 0, 0.0, bonus))
        return out

    def _peaks(self, rel: np.ndarray, j: np.ndarray) -> list:
        """The `peaks` highest places (relative to the hypothesis' offset, px) of a 2-D vote
        histogram of `rel`: each blob `j` one vote shared by the bins of its pairings, summed
        over +-`match_px`."""
        s = self.settings
        nb = int(math.ceil(s.radius_px / _BIN_PX))
        side = 2 * nb + 1
        ix = np.clip(np.floor(rel[:, 0] / _BIN_PX + 0.5).astype(np.int64) + nb, 0, 2 * nb)
        iy = np.clip(np.floor(rel[:, 1] / _BIN_PX + 0.5).astype(np.int64) + nb, 0, 2 * nb)
        key = np.unique(j * side * side + iy * side + ix)
        blob, cell = key // (side * side), key % (side * side)
        share = 1.0 / np.bincount(blob)[blob]
        hist = np.bincount(cell, weights=share, minlength=side * side).reshape(side, side)
        w = max(1, int(round(s.match_px / _BIN_PX)))
        sm = cv2.boxFilter(hist, -1, (2 * w + 1, 2 * w + 1), normalize=False, borderType=cv2.BORDER_CONSTANT)
        out = []
        for _ in range(s.peaks):
            iy0, ix0 = np.unravel_index(int(np.argmax(sm)), sm.shape)
            if sm[iy0, ix0] <= 0:
                break
            out.append(np.array([(ix0 - nb) * _BIN_PX, (iy0 - nb) * _BIN_PX]))
            # the next peak lies outside this one's window
            sm[max(iy0 - 2 * w - 1, 0):iy0 + 2 * w + 2, max(ix0 - 2 * w - 1, 0):ix0 + 2 * w + 2] = 0.0
        return out

    def _commit(self, h: _Lights, c, support: int, xy: np.ndarray, area: np.ndarray, bonus: float = 0.0) -> None:
        """Hypothesis `h` takes camera offset `c` (None: unmeasured, the offset stays) for this
        frame: its score, its lights (matched, moved on, new, dropped) and F."""
        s = self.settings
        measured = c is not None
        c = h.c if c is None else np.asarray(c, float)
        shift = c - h.c
        h.score += support + bonus - 0.5 * float(shift @ shift) / s.shake_px ** 2 - (0.0 if measured else s.miss_cost)
        h.c, h.shift, h.matches = c.copy(), shift, int(support)
        pred = h.predicted()
        img = pred + c
        free = np.ones(len(xy), bool)
        hit = np.zeros(len(h.xy), bool)
        known = h.seen >= 1
        residuals = []
        # nearest pairings first, one blob per light: known lights within gate_px, then the
        # lights seen once within new_gate_px
        for group, gate in ((known, s.gate_px), (~known, s.new_gate_px)):
            idx = np.flatnonzero(group)
            if not len(idx) or not len(xy):
                continue
            dist = np.hypot(*(xy[:, None, :] - img[None, idx, :]).transpose(2, 0, 1))
            bb, aa = np.nonzero(dist <= gate)
            for k in np.argsort(dist[bb, aa], kind="stable"):
                b, il = bb[k], idx[aa[k]]
                if not free[b] or hit[il]:
                    continue
                free[b], hit[il] = False, True
                q = xy[b] - c
                r = h.xy[il] - h.foe
                rr = max(float(r @ r), 100.0)   # a light on F itself: no radial motion to fit
                if known[il]:
                    residuals.append((q - pred[il], h.kappa[il]))
                    h.kappa[il] += s.velocity_gain * float((q - pred[il]) @ r) / rr / h.dark[il]
                else:
                    h.kappa[il] = float((q - h.xy[il]) @ r) / rr / h.dark[il]
                h.kappa[il] = min(max(h.kappa[il], _KAPPA_RANGE[0]), _KAPPA_RANGE[1])
                h.xy[il] = q
                h.seen[il] += 1
                if math.isfinite(area[b]):
                    h.area[il] = area[b]
        dark = ~hit
        h.xy[dark] = pred[dark]
        h.dark[dark] += 1
        h.dark[hit] = 1
        if len(h.xy) and len(xy):
            # a blob by a light just matched is that light's other blob piece, not a new light
            dist = np.hypot(*(xy[:, None, :] - img[None, :, :]).transpose(2, 0, 1))
            dist[:, hit] = np.inf
            free &= ~(dist <= s.gate_px).any(axis=1)
        new = np.flatnonzero(free)
        if len(new):
            h.xy = np.vstack([h.xy, xy[new] - c])
            h.kappa = np.concatenate([h.kappa, np.zeros(len(new))])
            h.dark = np.concatenate([h.dark, np.ones(len(new), int)])
            h.seen = np.concatenate([h.seen, np.zeros(len(new), int)])
            h.area = np.concatenate([h.area, area[new]])
        keep = h.dark <= s.history_frames
        h.xy, h.kappa, h.dark, h.seen, h.area = h.xy[keep], h.kappa[keep], h.dark[keep], h.seen[keep], h.area[keep]
        if s.foe_gain and len(residuals) >= 3:
            # an error e of F moves each light's prediction by -kappa e, the camera offset all
            # alike: the residuals' part that goes with kappa is F's error
            res = np.array([r for r, _ in residuals])
            kap = np.array([k for _, k in residuals])
            res -= res.mean(axis=0)
            kap -= kap.mean()
            if float(kap @ kap) > 1e-6:
                h.foe = h.foe - s.foe_gain * (kap @ res) / float(kap @ kap)
