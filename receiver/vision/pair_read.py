"""What is read and reported of the S2-PSK pairs: their emitters in the output, their
intensities and a far head's flux (receiver.vision.pairing: the per-frame flow).

`g`: the gates a function reads, by the names of `PairTuning` / `PairSettings` (a
receiver.vision.pairing.Pairer holds them).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pair_model import Pair


def live_pairs(g, pairs: list[Pair]) -> list[Pair]:
    """The pairs that explained a blob within the last `report_coast_frames` frames."""
    return [p for p in pairs if p.misses <= g.report_coast_frames]


def decoded_emitters(g, live: list[Pair]) -> list[tuple[int, Blob, Pair, bool]]:
    """(LED id, envelope, pair, seen this frame) of each emitter of the decoded pairs in `live`
    that may be reported. An emitter that has not had a blob of its own for
    `jumper_unseen_frames` frames is not reported (0 = off): S2-PSK lights each emitter in half
    of the symbols, so it is hidden (a nearer car in front of one taillight, its own lamp
    perhaps right there) or, for a far head's (jumper) pair, which may sit a baseline aside
    (which half a blob was cannot be told), beside the head on nobody's light; where the pair
    predicts it is a guess either way. A car whose hidden taillight lies behind a nearer car
    (`behind`) sits at that car's edge: its other taillight is reported only in the frames it
    is seen (when dark, it may be behind that car as well). One that coasted may now sit a
    baseline aside, one emitter on the head behind or beside it: not reported until a blob both
    lit places it again (`anchor_coast_frames`)."""
    hidden = {p.uid for p in live if g.jumper_unseen_frames and behind(g, p, live)}
    return [(i, e.blob, p, seen == p.frames) for p in live if p.led_id is not None
            for i, e, seen in zip(p.ids, (p.a, p.b), (p.seen_a, p.seen_b))
            if not (g.jumper_unseen_frames and p.frames - seen > g.jumper_unseen_frames)
            and (seen == p.frames or p.uid not in hidden)
            and (p.anchored or p.a.track_id != p.b.track_id) and not p.beside]


def behind(g, p: Pair, live: list[Pair]) -> bool:
    """Car `p` (a taillight pair) has a taillight without a blob of its own for
    `jumper_unseen_frames` frames that lies behind a nearer car: between the taillights of a
    pair in `live` with a longer baseline, within half that baseline of their row (a car's
    body is about as tall as its lamps are apart)."""
    if p.kind != "FV" or p.a.track_id == p.b.track_id:
        return False
    for e, seen in ((p.a, p.seen_a), (p.b, p.seen_b)):
        if p.frames - seen <= g.jumper_unseen_frames:
            continue
        for q in live:
            w = q.b.cx - q.a.cx
            if (q is not p and q.a.track_id != q.b.track_id and w > p.b.cx - p.a.cx
                    and q.a.cx <= e.cx <= q.b.cx and abs(e.cy - 0.5 * (q.a.cy + q.b.cy)) <= 0.5 * w):
                return True
    return False


def emitters(g, pairs: list[Pair]) -> list[tuple[int, Blob, Pair]]:
    """This frame's S2-PSK emitter observations: (LED id, envelope at the emitter's current
    position, its pair) for both emitters of every live pair that explained a blob within
    the last `report_coast_frames` frames. An emitter is reported also when it is dark in
    this frame: S2-PSK lights each emitter in half of every 5 ms clock period, so a frame
    exposed for 0.1 ms sees both halves of a head dark in about a quarter of the frames
    (symbol 0, off half-period) and one half dark in another half of them (symbol 1); the
    pair knows where they are (it reads their intensities there), and its ID belongs to
    both. An undecoded pair's emitter within `match_min_px` of a decoded pair's emitter is
    left out (one head followed by two pairs: the LED is the decoded one's)."""
    live = live_pairs(g, pairs)
    if not live:
        return []
    dec = decoded_emitters(g, live)
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
        gate = np.maximum(g.match_min_px, g.match_size * np.sqrt(np.maximum(area, 1.0)))
        clear = ((d > gate) | ~other).all(axis=1)
        # An emitter without its own blob in this frame sits where the pair predicts it: left
        # out when that is as near another decoded pair's emitter (overlapping lights).
        out = [(i, b, p) for (i, b, p, own), ok in zip(dec, clear.tolist()) if own or ok]
    und = [(i, e.blob, p) for p in live if p.led_id is None for i, e in zip(p.ids, (p.a, p.b))]
    if und and len(xy):
        u = np.array([(b.cx, b.cy) for _, b, _ in und], float)
        near = np.hypot(xy[None, :, 0] - u[:, 0, None], xy[None, :, 1] - u[:, 1, None]).min(axis=1)
        und = [e for e, ok in zip(und, (near > g.match_min_px).tolist()) if ok]
    return out + und


def flux_on(g, p: Pair) -> float:
    """Pair `p`'s both-lit flux 2F (gray x px) for `flux_xor`: twice the median of its last
    `flux_recent` fluxes above `flux_min` (the frames with a half or both lit: one half, F,
    in two thirds of them). Recent ones only: an approaching head's flux grows as
    1 / distance^2, doubling within a packet at 60-80 m."""
    lit = sorted([v for v in p.flux if v > g.flux_min][-g.flux_recent:])
    if not lit:
        return 0.0
    # np.median's value: the middle one, or the mean of the middle two ((a + b) / 2)
    n = len(lit)
    return 2.0 * (lit[n // 2] if n % 2 else (lit[n // 2 - 1] + lit[n // 2]) / 2.0)

def head_flux(g, p: Pair, gray: np.ndarray) -> float:
    """The summed gray above the background (+ `flux_floor` gray, so sensor noise adds
    nothing) in a box around pair `p`'s head (gray x px). A far head's halves are a few px
    apart and the camera's yaw shake moves it by more than that from frame to frame, so
    which half a blob is cannot be told; but the XOR needs no side: the head's flux is
    ~0 (both dark), F (one half lit: symbol 1) or 2F (both lit). The box is centred on the
    blob the pair explained in this frame (whichever half it is), else on the pair's
    midpoint, and reaches one baseline plus `flux_margin_px` either side, and
    `flux_margin_px` above and below the emitters' envelopes."""
    x0, x1, y0, y1, bg = flux_box(g, p, gray.shape)
    if x1 <= x0 or y1 <= y0:
        return 0.0
    roi = gray[y0:y1, x0:x1].astype(np.float32)
    return float(np.maximum(roi - bg, 0.0).sum())

def flux_box(g, p: Pair, shape) -> tuple[int, int, int, int, float]:
    """`head_flux`'s box x0, x1, y0, y1 (px, half-open, clipped to the frame of `shape`) and
    its background level (gray)."""
    cx, cy = p.mx, p.my
    base = math.hypot(p.b.cx - p.a.cx, p.b.cy - p.a.cy)
    half_h = 0.5 * max(p.a.blob.y1 - p.a.blob.y0, p.b.blob.y1 - p.b.blob.y0)
    mx, my = g.flux_margin_px, g.flux_margin_y_px
    h, w = shape[:2]
    x0, x1 = max(int(math.floor(cx - base - mx)), 0), min(int(math.ceil(cx + base + mx)) + 1, w)
    y0, y1 = max(int(math.floor(cy - half_h - my)), 0), min(int(math.ceil(cy + half_h + my)) + 1, h)
    return x0, x1, y0, y1, float(p.a.blob.background) + g.flux_floor


def sample(p: Pair, gray: np.ndarray, intensity) -> tuple[float, float]:
    """This frame's (a, b) intensities of a pair; updates its levels."""
    if p.fresh:
        p.fresh = False
        return p.levels_a.values[-1], p.levels_b.values[-1]
    ia, ib = intensity(gray, p.a), intensity(gray, p.b)
    p.levels_a.add(ia)
    p.levels_b.add(ib)
    return ia, ib


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
