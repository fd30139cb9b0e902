"""Founding S2-PSK pairs: a far head's (jumper) pair from one track that jumps between its
two halves, the backlogs a new pair's decoder starts from, and the jumper pairs that are one
head followed twice or sit beside their head (receiver.vision.pairing: the per-frame flow).

`g`: the gates a function reads, by the names of `PairTuning` / `PairSettings`, and the frame
history `scene_past` / `view_sum` (a receiver.vision.pairing.Pairer holds them).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pair_model import EmitterLevels, Pair, _emitter, moved
from receiver.vision.track import Track


def mark_beside(g, pairs: list[Pair], tracks: list[Track]) -> None:
    """`Pair.beside` of every pair in this frame: a decoded
    jumper pair that explained no blob, with a blob of this frame that no pair explains within
    its baseline plus `match_min_px` horizontally and `match_min_px` vertically of one of its
    emitters. That blob is most likely its own head's half that the gate missed: the pair
    then sits beside its head (the yaw shift is ambiguous by the baseline), and one of its
    emitters may be nearer a neighbouring head than its own."""
    cand = [p for p in pairs if p.led_id is not None and p.a.track_id == p.b.track_id]
    for p in pairs:
        p.beside = False
    if not cand:
        return
    taken = {t.track_id for p in pairs for t in p.tracks}
    free = [t for t in tracks if t.seen and t.track_id not in taken]
    for p in cand:
        if p.misses == 0 or not free:
            continue
        reach = abs(p.b.cx - p.a.cx) + g.match_min_px
        size = max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0)
        lo, hi = min(p.a.cx, p.b.cx), max(p.a.cx, p.b.cx)
        p.beside = any((lo - reach <= t.cx < lo or hi < t.cx <= hi + reach)
                       and abs(t.cy - p.my) <= abs(p.b.cy - p.a.cy) / 2 + g.match_min_px
                       and 1.0 / g.max_cut <= t.blob.area_px / size <= g.max_merged
                       for t in free)

def drop_twins(g, pairs: list[Pair]) -> list[Pair]:
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
                abs(p.mx - d.mx) <= abs(d.b.cx - d.a.cx) + g.match_min_px
                and abs(p.my - d.my) <= g.match_min_px for d in heads):
            continue
        out.append(p)
    return out


def _sums(rows: list) -> tuple[float, float, float]:
    """The sums of the rows' area, cx and cy ([cx, cy, area] each) as numpy sums them (an
    area array's sum, the centroids' mean over axis 0): in order from 0.0 under 8 rows,
    numpy itself from 8 (its pairwise summation)."""
    if len(rows) >= 8:
        arr = np.array(rows, float)
        return float(arr[:, 2].copy().sum()), *(float(v) for v in arr[:, :2].copy().sum(axis=0))
    a = x = y = 0.0
    for bx, by, ba in rows:
        a += ba
        x += bx
        y += by
    return a, x, y


def head_backlog(g, mx: float, my: float, base_px: float, single: float) -> list[tuple]:
    """`Pair.backlog` of a new far-head pair (midpoint (mx, my) and horizontal baseline
    `base_px` in this frame's view, one emitter's area `single` px^2) from every blob of the
    last frames near the head, whichever track had it: a far head's blobs are shared by
    several short tracks (one per half and one for both, each ending when another takes
    its blobs), so its own track often holds only the last few frames of the packet.
    Going back frame by frame, the head's place is moved by the image shifts since
    (`view_sum`) and follows its blobs slowly (the head's own motion); the blobs within
    half a baseline plus `match_min_px` horizontally and `match_min_px` vertically are
    classified as in `jumper_backlog`: none = both dark, up to `merged_ratio` x `single`
    = one half lit (anti-phase), more = both lit."""
    hist = list(g.scene_past)[:-1]  # this frame: the pair's own sample
    sx_now, sy_now = g.view_sum
    tol_x = 0.5 * abs(base_px) + max(g.match_min_px, math.sqrt(single))
    tol_y = g.match_min_px
    cx, cy = mx, my
    out, kept, empty = [], 0, 0
    for t_s, (sx, sy), blobs in reversed(hist):
        ox, oy = sx_now - sx, sy_now - sy
        px, py = cx - ox, cy - oy
        near = [b for b in blobs if abs(b[0] - px) <= tol_x and abs(b[1] - py) <= tol_y]
        if not near:
            empty += 1
            if empty > g.head_gap_frames:  # lost (or not yet detected): stop there
                break
            out.append((t_s, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0))
            continue
        empty, kept = 0, len(out) + 1
        area, mx_, my_ = _sums(near)
        both = area > g.merged_ratio * single
        out.append((t_s, 1.0, 1.0 if both else 0.0, 1.0, 1.0, 0.0, 0.0))
        cx += g.head_follow * (mx_ / len(near) + ox - cx)
        cy += g.head_follow * (my_ / len(near) + oy - cy)
    return out[:kept][::-1]  # from the oldest frame with a blob


def two_track_backlog(p: Pair, past_a, past_b) -> list[tuple]:
    """`Pair.backlog` of a pair of two tracks: the frames before this one in which both
    were read, with the pair's levels (seeded by the same history). The decoder then
    starts from the tracks' birth, not from the pair's formation 4-15 frames later, and
    has its packet when the light's is whole."""
    va = {t: v for t, _, _, v in past_a}
    la, lb = p.levels_a, p.levels_b
    lv = (la.on, lb.on, la.off, lb.off)
    return [(t, va[t], vb) + lv for t, _, _, vb in list(past_b)[:-1] if t in va]  # this frame: the pair's own


def jumper_backlog(g, past, area_now: float, area_last: float) -> list[tuple]:
    """`Pair.backlog` of a pair from one jumping track (a far head it alone followed,
    `JumpWatch`), from its blob sizes: a blob of one emitter's size is one half lit,
    anti-phase (a = 1, b = 0); a merged blob (over `merged_ratio` of one emitter, both lit)
    or none (both dark) is in phase (1, 1) / (0, 0); levels on 1, off 0."""
    single = max(0.5 * (area_now + area_last), 1.0)
    out = []
    for t, seen, area, _ in list(past)[:-1]:  # this frame: the pair's own sample
        b = 0.0 if seen and area <= g.merged_ratio * single else float(seen)
        out.append((t, float(seen), b, 1.0, 1.0, 0.0, 0.0))
    return out


class JumpWatch:
    """Per track, its latest seen blob (with the camera's summed shift then) and its latest
    qualifying jump (px): a far head's halves are never two blobs of one frame, so one track
    takes the blob of whichever half is lit. Two jumps of about the same baseline between
    single-emitter-sized blobs (either direction) make a pair at the two places."""

    def __init__(self):
        self.last_seen: dict[int, tuple[Blob, tuple[float, float]]] = {}  # blob, shift_sum then
        self.last_jump: dict[int, tuple[float, float]] = {}  # left-to-right jump, px

    def jumps(self, g, tracks: list[Track], busy: set[int], shift_sum: tuple[float, float]):
        """Yield (track, its previous blob, A's place (ax, ay), the baseline (jx, jy)) px of the
        seen tracks not in `busy` whose last two jumps agree, in track order; `shift_sum`: the
        measured image shifts added up (px), taken off each jump. Forgets the tracks gone."""
        live = {t.track_id for t in tracks}
        for d in (self.last_seen, self.last_jump):
            for tid in [tid for tid in d if tid not in live]:
                del d[tid]
        for t in tracks:
            last = self.last_seen.get(t.track_id)
            if not t.seen:
                continue
            self.last_seen[t.track_id] = (t.blob, shift_sum)
            if last is None or t.track_id in busy:
                continue
            # the jump without the camera's shake since the track's previous blob (it may have
            # been dark for a few frames)
            last, s0 = last
            ox, oy = shift_sum[0] - s0[0], shift_sum[1] - s0[1]
            jx, jy = t.cx - last.cx - ox, t.cy - last.cy - oy
            if jx < 0:
                jx, jy = -jx, -jy  # left-to-right baseline either way
            diam = math.sqrt(max(0.5 * (t.blob.area_px + last.area_px), 1.0))
            ratio = max(t.blob.area_px, 1.0) / max(last.area_px, 1.0)
            if not (g.geom["min_baseline"] * diam <= jx <= g.jump_max_baseline * diam
                    and abs(jy) <= g.geom["row_band"] * diam
                    and 1.0 / g.merged_ratio <= ratio <= g.merged_ratio):
                continue
            prev = self.last_jump.get(t.track_id)
            self.last_jump[t.track_id] = (jx, jy)
            # Each jump is the baseline plus the light's motion over one frame, in opposite
            # directions for a back-and-forth track (B -> A, A -> B): the left-to-right jumps
            # then differ by about twice that motion. The camera's pitch vibration moves lights
            # by 1-2 px per frame, mostly vertically, so `jump_agree_y_px` of the vertical
            # difference is forgiven before the two must agree within jump_agree diameters.
            if prev is None or math.hypot(jx - prev[0], max(abs(jy - prev[1]) - g.jump_agree_y_px, 0.0)
                                          ) > g.jump_agree * diam:
                continue
            # their mean is the baseline without the motion
            jx, jy = 0.5 * (jx + prev[0]), 0.5 * (jy + prev[1])
            right = t.cx - last.cx - ox > 0  # the current blob is the right-hand emitter
            ax, ay = (t.cx - jx, t.cy - jy) if right else (t.cx, t.cy)
            yield t, last, ax, ay, jx, jy


def jumper_pair(g, t: Track, last: Blob, a_xy: tuple[float, float], base: tuple[float, float], ids: tuple[int, int],
                levels: EmitterLevels | None, past) -> Pair:
    """A far head's pair from track `t` (previous blob `last`) that jumps between its halves:
    emitter A at `a_xy`, B one baseline `base` (px) to its right, LED ids `ids`; its levels
    seeded from the track's `levels` when the head is near, its backlog from the track's `past`
    frames or the blobs around the head (`head_backlog`), whichever is longer."""
    ax, ay = a_xy
    jx, jy = base
    a, b = _emitter(t), _emitter(t)
    a.blob = moved(t.blob, ax, ay)
    b.blob = moved(t.blob, ax + jx, ay + jy)
    p = Pair(a, b, fresh=False, tracks=[t], nearby=[t], ids=ids)
    if levels is not None and t.blob.area_px >= g.jumper_levels_min_area_px:
        # A near head (halves of >= jumper_levels_min_area_px): its track's learned
        # on / off levels (lit when it had a half's blob, dark otherwise) seed both
        # emitters', so its first samples are read against them, not against one or
        # two values (a wrong sign each, folded into the packet's first estimate). A far
        # head's per-emitter reads stay neutral until its own levels are learned: which
        # half is lit cannot be told under the yaw shake (its flux is read instead).
        for v in (levels.on, levels.off):
            p.levels_a.add(v)
            p.levels_b.add(v)
    p.backlog = jumper_backlog(g, past, t.blob.area_px, last.area_px)
    head = head_backlog(g, ax + 0.5 * jx, ay + 0.5 * jy, jx, max(0.5 * (t.blob.area_px + last.area_px), 1.0))
    if len(head) > len(p.backlog):
        p.backlog = head
    return p
