"""Founding S2-PSK pairs: the backlogs a new pair's decoder starts from, and the far heads'
(jumper) pairs that are one head followed twice or sit beside their head
(receiver.vision.pairing: the per-frame flow).

`g`: the gates a function reads, by the names of `PairTuning` / `PairSettings`, and the frame
history `scene_past` / `view_sum` (a receiver.vision.pairing.Pairer holds them).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.vision.pair_model import Pair
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


def head_backlog(g, mx: float, my: float, base_px: float, single: float) -> list[tuple]:
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
    hist = list(g.scene_past)[:-1]  # this frame: the pair's own sample
    sx_now, sy_now = g.view_sum
    tol_x = 0.5 * abs(base_px) + max(g.match_min_px, math.sqrt(single))
    tol_y = g.match_min_px
    cx, cy = mx, my
    out, kept, empty = [], 0, 0
    for t_s, (sx, sy), xy, area in reversed(hist):
        ox, oy = sx_now - sx, sy_now - sy
        px, py = cx - ox, cy - oy
        sel = (np.abs(xy[:, 0] - px) <= tol_x) & (np.abs(xy[:, 1] - py) <= tol_y) if len(xy) else np.zeros(0, bool)
        if not sel.any():
            empty += 1
            if empty > g.head_gap_frames:  # lost (or not yet detected): stop there
                break
            out.append((t_s, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0))
            continue
        empty, kept = 0, len(out) + 1
        both = float(area[sel].sum()) > g.merged_ratio * single
        out.append((t_s, 1.0, 1.0 if both else 0.0, 1.0, 1.0, 0.0, 0.0))
        c = xy[sel].mean(axis=0)
        cx += g.head_follow * (c[0] + ox - cx)
        cy += g.head_follow * (c[1] + oy - cy)
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
    `_pair_jumpers`), from its blob sizes: a blob of one emitter's size is one half lit,
    anti-phase (a = 1, b = 0); a merged blob (over `merged_ratio` of one emitter, both lit)
    or none (both dark) is in phase (1, 1) / (0, 0); levels on 1, off 0."""
    single = max(0.5 * (area_now + area_last), 1.0)
    out = []
    for t, seen, area, _ in list(past)[:-1]:  # this frame: the pair's own sample
        b = 0.0 if seen and area <= g.merged_ratio * single else float(seen)
        out.append((t, float(seen), b, 1.0, 1.0, 0.0, 0.0))
    return out
