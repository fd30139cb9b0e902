"""Which blobs an S2-PSK pair explains (receiver.vision.pairing: the per-frame flow).

A pair's own geometry is corrected each frame from the blobs it explains: a single blob near A
or B, a merged blob (area well above one emitter's, or one baseline wider) near the midpoint.
Blob area is otherwise no measure of size: a far half covers one or two rows, and a saturated
blob (peak at the sensor's white level, `white_gray`) blooms to 2-3x the emitter's area, so a
saturated blob is not held to the area gates. A decoded pair's lone smaller blob far from its
prediction does not move it (`lone_checked`), nor does a saturated blob well above its own
saturated emitters (`bloom_checked`: a nearer light's lamp), and a much larger saturated lamp
seen beside a placed pair stays another light's for as long as its track lives (`other_lamps`);
a coasting pair of two tracks is re-placed on two blobs one baseline apart (`reanchor`); a pair
that takes another pair's emitter is found by `anothers`. Also the Python reference of the frame's first pass over all pairs
(`pitch_and_claims`) and of the camera-shift votes (`shift_votes_of`, `dx_offsets_of`).

`g`: the gates a function reads, by the names of `PairTuning` / `PairSettings`, and this frame's
`vertical_known` (a receiver.vision.pairing.Pairer holds them). This Python code is the
reference of the compiled receiver/vision/_pairing.pyx.
"""

from __future__ import annotations

import math

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pair_model import Pair
from receiver.vision.track import Track


def explain(g, p: Pair, tracks: list[Track], xy: np.ndarray, mx: float, my: float,
             hx: float, hy: float, single: float, exclude=()):
    """The blobs pair `p` explains around midpoint (mx, my): (explaining tracks, nearby
    tracks, their (dx, dy) offsets from where the pair puts them, A's and B's own single
    blobs or None). Tracks in `exclude` (ids) are only nearby. Nothing is changed."""
    ax, ay, bx, by = mx - hx, my - hy, mx + hx, my + hy
    # The gate widens while the pair coasts: the prediction error grows (the camera's pitch
    # vibration moves every light by a few px within a second).
    tol0 = min(g.match_frac * 2 * math.hypot(hx, hy), max(g.match_min_px, g.match_size * math.sqrt(single)))
    tol = tol0 + g.miss_growth_px * p.misses
    # With the frame's vertical shift measured (`shake` "pairs" / "vertical"), the vertical
    # prediction error does not grow while the pair coasts: only the horizontal gate widens
    # (else a coasting pair reaches the heads just above or below it, farther down the road).
    tol_y = tol0 + g.miss_growth_px if g.vertical_known else math.inf
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
        wide = width_class(g, p, t.blob, hx)
        if wide == "merged" and dm <= tol:
            shifts.append((t.cx - mx, t.cy - my))  # both lit, one blob
            explaining.append(t)
            merged = t.blob
            continue
        # A saturated blob's area is the bloom's, not the emitter's: no upper bound then
        sat = t.blob.peak >= g.white_gray
        if dm < min(da, db):
            if g.merged_ratio * single < t.blob.area_px and (sat or t.blob.area_px <= g.max_merged * single):
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
        if not (1.0 / g.max_cut <= ratio and (ratio <= g.merged_ratio or sat)
                or (wide == "single" and ratio >= 1.0)):
            continue  # another light's blob
        shifts.append((t.cx - x, t.cy - y))
        explaining.append(t)
        if ratio >= 1.0 / g.merged_ratio:
            if e is p.a:
                obs_a = t.blob
            else:
                obs_b = t.blob
    return explaining, nearby, shifts, obs_a, obs_b, merged


def width_class(g, p: Pair, blob: Blob, hx: float) -> str | None:
    """"single" (as wide as one emitter's envelope), "merged" (one horizontal baseline wider:
    both emitters lit as one blob) or None (neither; px widths of the half-open boxes, within
    `width_tol` of the expected width plus one px)."""
    # both this blob and the pair's envelopes short: a far horizontal head, not a row or two
    # of a taller one cut by a clock edge during the rolling readout
    if max(blob.y1 - blob.y0, p.a.blob.y1 - p.a.blob.y0,
                                  p.b.blob.y1 - p.b.blob.y0) > g.width_max_rows:
        return None
    w1 = max(p.a.blob.x1 - p.a.blob.x0, p.b.blob.x1 - p.b.blob.x0)
    wm = w1 + 2.0 * abs(hx)
    wt = blob.x1 - blob.x0
    e1, em = abs(wt - w1), abs(wt - wm)
    if e1 <= em and e1 <= g.width_tol * w1 + 1.0:
        return "single"
    if em < e1 and 2.0 * abs(hx) >= g.width_min_px and em <= g.width_tol * wm + 1.0:
        return "merged"
    return None


def claim_tol(g, single: float) -> float:
    """How near (px) a blob must be to a decoded pair's emitter to be claimed by it
    (`Pairer._first_pass`), for one emitter's area `single` px^2."""
    return max(g.match_min_px, g.match_size * math.sqrt(single))


def lone_gate_px(g, p: Pair) -> float:
    """How far (px) a lone blob may lie from where decoded two-track pair `p` predicts its
    emitter and still move it: the centroid noise (`match_min_px`) plus `lone_sigmas` x the
    prediction's 1-sigma error, `shift_sigma_px` per frame since its last blob (the frame's
    shift estimate; the errors of the frames it coasted add up)."""
    return g.match_min_px + g.lone_sigmas * g.shift_sigma_px * math.sqrt(1.0 + p.misses)


def lone_checked(g, p: Pair, found: tuple) -> tuple:
    """`found` (explaining, nearby, mean shift, A's blob, B's blob, merged blob) of pair `p`,
    or nothing explained when `p` is a decoded pair of two tracks that explains one lone blob
    smaller than its emitters (under 1 / `merged_ratio` of the larger envelope) farther than
    `lone_gate_px` from its prediction. Such a blob is a clock edge's cut of its own
    emitter, or another, farther light's blob beside it (a car behind, its taillight a few
    px from this one's while this one's is dark or hidden): with no partner blob one
    baseline away it cannot tell which, and a pair moved onto another light carries its
    ID there. The pair coasts instead; its own emitters are found where it predicts them,
    or both at once one baseline apart (`reanchor`). A whole blob, or one within the gate,
    moves it as before."""
    expl, nearby, mean, obs_a, obs_b, merged = found
    if (p.led_id is None or p.a.track_id == p.b.track_id or len(expl) != 1 or merged is not None
            or mean is None or math.hypot(*mean) <= lone_gate_px(g, p)):
        return found
    whole = max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0)
    if max(expl[0].blob.area_px, 1.0) >= whole / g.merged_ratio:
        return found
    return [], nearby, None, None, None, None


def bloom_checked(g, p: Pair, pred: tuple, found: tuple) -> tuple:
    """`found` (as `lone_checked`) of a pair `p` of two tracks at its prediction `pred` (mx, my,
    hx, hy, single), without the saturated blobs taken as one emitter that are more than
    `merged_ratio` x the larger of its emitters' envelopes, once those envelopes saturate too
    (peak at `white_gray`), and without a "merged" blob (both emitters lit as one) shorter than
    half its baseline. A saturated blob's area is the bloom's, so it is no measure of one
    emitter against an unsaturated envelope; but a pair's two lamps are alike and at one range,
    so once its own blobs bloom, its next ones bloom alike. The envelopes are grown by the
    square of the baseline's measured growth per frame since the pair's last blob (area goes
    as the baseline squared). A blob well above that is a nearer light's lamp beside a hidden
    emitter (a car in front covering this car's taillight with its own taillight a few px
    away): taken, it moves the pair onto that light, which then carries this pair's ID. The
    mean shift is that of the blobs kept (offsets from the emitter or midpoint each explains).
    Cost: a loop over the pair's few explaining blobs."""
    expl, nearby, mean, obs_a, obs_b, merged = found
    if p.a.track_id == p.b.track_id or not expl:
        return found
    bloomed = max(p.a.blob.peak, p.b.blob.peak) >= g.white_gray
    mx, my, hx, hy, _ = pred
    whole = max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0)
    grow = (1.0 + max(p.growth, 0.0)) ** (2 * min(p.misses + 1, g.growth_span_frames))
    bound = g.merged_ratio * whole * grow
    keep, shifts = [], []
    for t in expl:
        if t.blob is merged:
            # both emitters lit as one blob span the baseline: a blob shorter than half of it
            # is one lamp at the midpoint (another light's), whatever its area
            extent = max(t.blob.x1 - t.blob.x0, t.blob.y1 - t.blob.y0)
            if extent < math.hypot(hx, hy):
                merged = None
                continue
            keep.append(t)
            shifts.append((t.cx - mx, t.cy - my))
            continue
        da = math.hypot(t.cx - (mx - hx), t.cy - (my - hy))
        db = math.hypot(t.cx - (mx + hx), t.cy - (my + hy))
        if bloomed and t.blob.peak >= g.white_gray and t.blob.area_px > bound:
            if t.blob is obs_a:
                obs_a = None
            if t.blob is obs_b:
                obs_b = None
            continue
        keep.append(t)
        x, y = (mx - hx, my - hy) if da <= db else (mx + hx, my + hy)
        shifts.append((t.cx - x, t.cy - y))
    if len(keep) == len(expl):
        return found
    mean = tuple(float(v) for v in np.mean(shifts, axis=0)) if shifts else None
    return keep, nearby, mean, obs_a, obs_b, merged


def other_lamps(g, p: Pair, pred: tuple, found: tuple, lamps: list[Track]) -> list[int]:
    """Ids of the tracks that are another light's lamp beside pair `p` (two tracks) at its
    prediction `pred` (mx, my, hx, hy, single), from this frame's `found` (as `bloom_checked`
    returns) and its seen saturated tracks `lamps` (peak at `white_gray`): when the pair is
    placed by blobs of its own, those within one baseline of either emitter that it does not
    explain, larger than `merged_ratio` x both its envelopes (grown as in `bloom_checked`) and
    the blobs it explains. A pair's two lamps are alike and at one range, so in one frame
    they bloom alike; a much larger lamp beside them is a nearer light's (a car in front whose
    taillight is about to cover one of this car's). Its track is that light for as long as the
    tracker follows it (`Pair.others`): in a later frame it may sit on the hidden emitter, at a
    size a clock edge has cut under any bound. Not the pair's founding tracks."""
    expl = found[0]
    if p.a.track_id == p.b.track_id or not expl or not lamps:
        return []
    mx, my, hx, hy, _ = pred
    grow = (1.0 + max(p.growth, 0.0)) ** (2 * min(p.misses + 1, g.growth_span_frames))
    bound = g.merged_ratio * max(max(p.a.blob.area_px, p.b.blob.area_px, p.size, 1.0) * grow,
                                 max(t.blob.area_px for t in expl))
    reach = 2.0 * math.hypot(hx, hy)
    mine = {t.track_id for t in expl} | set(p.founding)
    return [t.track_id for t in lamps
            if t.blob.area_px > bound and t.track_id not in mine
            and min(math.hypot(t.cx - mx + hx, t.cy - my + hy), math.hypot(t.cx - mx - hx, t.cy - my - hy)) <= reach]


def anothers(g, p: Pair, t: Track, pred: tuple, owners: list) -> bool:
    """Track `t`, explained by pair `p` at its prediction `pred` (mx, my, hx, hy, single), is
    another two-track pair's emitter. `owners`: (pair, its prediction, it explains a blob
    this frame, its founding track ids) of the pairs whose founding track `t` may be. It is
    another's when not `p`'s own track but the founding track of a decoded pair that explains no blob this
    frame, within that pair's reach of its prediction (`shake_radius_px` a frame coasted and
    the claim tolerance `claim_tol`): the ID was read from that track's light, which the
    other pair has just lost, and `p` may have taken it."""
    if t.track_id in (p.a.track_id, p.b.track_id) or any(u.track_id == t.track_id for u in p.tracks):
        return False
    for q, (mx, my, hx, hy, single), explains, _ in owners:
        if q is p or q.led_id is None or explains or t.track_id not in q.founding:
            continue
        d = min(math.hypot(t.cx - mx - k * hx, t.cy - my - k * hy) for k in (-1.0, 1.0))
        if d <= g.shake_radius_px * (q.misses + 1) + claim_tol(g, single):
            return True
    return False


def reanchor(g, p: Pair, pred: tuple, tracks: list[Track], table: np.ndarray, taken: set) -> tuple | None:
    """Pair `p` (two tracks) explained no blob at its prediction `pred`: the camera's shake
    or the light's own motion may have moved it past its gate while it coasted. Two seen
    blobs that no pair explains (`taken`: track ids), offset by its baseline within
    `reanchor_sep_tol` (+ `match_min_px`), of an emitter's size (area within the pairing's
    `max_area_ratio` of each other, unless saturated), their midpoint within
    `shake_radius_px` per frame it coasted before this one of its predicted midpoint (none
    in its first frame without a blob: both emitters are dark in a quarter of the frames,
    and any two blobs one baseline apart would do), place both its emitters
    at once (no lone blob can be taken for the wrong one); the nearest such two. A decoded
    pair carries its ID onto them, so for it the two must be lamps that could found a pair of
    that baseline (`pair_score`): at most the pairing's
    `max_baseline` blob diameters apart, their rows within `row_band` diameters of the pair's
    (its roll kept), a diameter measured as the blob's width (a clock edge during the rolling
    readout cuts rows, not columns). A lamp is never that much smaller for its spacing: two far
    lights' one-row blobs a near car's baseline apart are not its taillights. Tracks in
    `Pair.others` are never taken. Returns (explaining tracks, mean (dx, dy) shift, A's blob,
    B's blob) or None."""
    mx, my, hx, hy, single = pred
    bx, by = 2.0 * hx, 2.0 * hy
    tol = g.match_min_px + g.reanchor_sep_tol * math.hypot(bx, by)
    if p.misses < 1:
        return None  # its first frame without a blob: both emitters dark in a quarter of the frames
    reach = g.shake_radius_px * p.misses
    tr = table  # seen tracks near the prediction, all at once
    near = np.flatnonzero((tr[:, 7] != 0.0) & (np.abs(tr[:, 0] - mx) <= reach + abs(hx) + tol)
                          & (np.abs(tr[:, 1] - my) <= reach + abs(hy) + tol))
    cand = [t for t in map(tracks.__getitem__, near.tolist()) if t.track_id not in taken and t.track_id not in p.others]
    best = None
    ratio_max = g.geom["max_area_ratio"]
    for ta in cand:
        for tb in cand:
            if tb is ta or math.hypot(tb.cx - ta.cx - bx, tb.cy - ta.cy - by) > tol:
                continue
            ox, oy = 0.5 * (ta.cx + tb.cx) - mx, 0.5 * (ta.cy + tb.cy) - my
            d = math.hypot(ox, oy)
            if d > reach:
                continue
            sat = ta.blob.peak >= g.white_gray and tb.blob.peak >= g.white_gray
            r = max(ta.blob.area_px, 1.0) / max(tb.blob.area_px, 1.0)
            if not sat and not (1.0 / ratio_max <= r <= ratio_max):
                continue
            # a clock edge cuts a lamp's rows, not its columns: its width is its diameter
            diam = 0.5 * ((ta.blob.x1 - ta.blob.x0) + (tb.blob.x1 - tb.blob.x0))
            if p.led_id is not None and (abs(tb.cx - ta.cx) > g.geom["max_baseline"] * diam or
                                         abs(tb.cy - ta.cy - by) > g.geom["row_band"] * diam):
                continue  # lamps too small for their spacing, or not level (`pair_score`)
            if best is None or d < best[0]:
                best = (d, ta, tb, (ox, oy))
    if best is None:
        return None
    _, ta, tb, mean = best
    return [ta, tb], mean, ta.blob, tb.blob


def shift_votes_of(pred: np.ndarray, xy: np.ndarray, radius_px: float) -> np.ndarray:
    """`Pairer.shift_votes` of the predictions `pred` (P, 4) mx, my, hx, hy and the blob
    centroids `xy` (N, 2), px: (K, 2) votes."""
    # all pairs at once, in the order of a loop over the pairs: per pair its blobs' offsets
    # d, then d + (hx, hy), then d - (hx, hy), each in the blobs' order
    d = xy[None, :, :] - pred[:, None, :2]  # (P, N, 2)
    reach = radius_px + np.abs(pred[:, 2:])  # (P, 2)
    keep = (np.abs(d[:, :, 0]) <= reach[:, None, 0]) & (np.abs(d[:, :, 1]) <= reach[:, None, 1])
    h = pred[:, None, 2:]
    votes = np.stack((d, d + h, d - h), axis=1)  # (P, 3, N, 2)
    return votes[np.broadcast_to(keep[:, None, :], votes.shape[:3])]


def dx_offsets_of(g, preds: list, blobs: list, xy: np.ndarray, dy: float, radius_px: float) -> list[np.ndarray]:
    """`Pairer.dx_offsets` of the pairs' predictions `preds` ((pair, (mx, my, hx, hy, single)),
    px, px^2): per blob of `blobs` (centroids `xy` (N, 2)) near one, its candidate horizontal
    shifts (px)."""
    out = []
    for p, (mx, my, hx, hy, single) in preds:
        my += dy
        sel = np.flatnonzero((np.abs(xy[:, 1] - my) <= g.match_min_px + abs(hy))
                             & (np.abs(xy[:, 0] - mx) <= radius_px + abs(hx)))
        for j in sel:
            b = blobs[j]
            kind = width_class(g, p, b, hx)
            if kind is None:
                r = b.area_px / single
                kind = ("merged" if g.merged_ratio < r <= g.max_merged else
                        "single" if 1.0 / g.max_cut <= r <= g.merged_ratio else None)
            if kind == "merged":
                out.append(np.array([xy[j, 0] - mx]))
            elif kind == "single":
                out.append(np.array([xy[j, 0] - mx + hx, xy[j, 0] - mx - hx]))
    return out


def pitch_and_claims(g, preds: list, tracks: list[Track], xy: np.ndarray, pitch: bool) -> tuple[float, dict]:
    """`Pairer._first_pass` of the pairs' predictions `preds` ((pair, (mx, my, hx, hy, single)))
    against `tracks` (centroids `xy` (N, 2), px): (the median vertical offset of the pairs'
    explained blobs, px, with `pitch` and at least `shake_min_pairs` of them, else 0.0;
    {pair uid: ids of the tracks it must not take})."""
    dys, claims = [], {}
    for p, pred in preds:
        mx, my, hx, hy, single = pred
        expl, _, shifts, _, _, _ = explain(g, p, tracks, xy, *pred)
        if shifts:
            dys.append(float(np.mean([d[1] for d in shifts])))
        mine = {t.track_id for t in expl}
        if p.led_id is not None and len(xy):
            # a decoded pair also claims the blobs on its own emitters that it did not take
            # (another light's blob merged with one of them)
            tol = claim_tol(g, single)
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
    pitch = float(np.median(dys)) if pitch and len(dys) >= g.shake_min_pairs else 0.0
    return pitch, exclude
