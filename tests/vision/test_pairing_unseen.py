"""An undecoded S2-PSK pair of two tracks whose one end never shows a blob of its own is a wrong
pairing and ends (PairSettings.unseen_give_up_frames; hil --mode s2psk seed 3: a 90-118 px pair
from head 52 to head 92 lived on head 52's blobs alone and kept 52 from being paired)."""

import numpy as np

from receiver.core.records import Blob
from receiver.vision.pairing import Pair, Pairer
from receiver.vision.track import Track


def _blob(cx, cy, w=4, h=4):
    x0, y0 = int(round(cx - w / 2)), int(round(cy - h / 2))
    hull = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + h - 1], [x0, y0 + h - 1]], float)
    return Blob(cx=float(cx), cy=float(cy), area_px=float(w * h), hull=hull, x0=x0, y0=y0, x1=x0 + w, y1=y0 + h,
                border=False, peak=60.0, level=10.0, background=2.0)


def _pair(pr):
    """A two-track pair (founding tracks 3 and 4), emitters at x 80 and 120, y 50."""
    p = Pair(Track(3, _blob(80.0, 50.0), 0, 0), Track(4, _blob(120.0, 50.0), 0, 0), ids=(10, 11))
    pr.pairs = [p]
    return p


def _run(pr, p, places, frames):
    """Follow `p` for `frames` frames, one blob a frame at the x of `places` in turn; the frame
    count it ended at, or None."""
    for k in range(frames):
        x = places[k % len(places)]
        t = Track(20 + k % len(places), _blob(x, 50.0), 0, 0)
        if not pr._follow(p, [t], np.array([[t.cx, t.cy]]), (480, 640)):
            return k + 1
    return None


def test_a_pair_seeing_one_end_only_ends_and_is_banned():
    pr = Pairer()
    n = pr.unseen_give_up_frames
    assert n == 60  # the default (measured: PairSettings docstring)
    p = _pair(pr)
    assert _run(pr, p, [80.0], 3 * n) == n + 1  # B never had a blob of its own
    assert (3, 4) in pr.banned


def test_a_pair_seeing_both_ends_lives_and_a_decoded_one_is_not_judged():
    pr = Pairer()
    p = _pair(pr)
    assert _run(pr, p, [80.0, 120.0, 80.0], 3 * pr.unseen_give_up_frames) is None
    assert not pr.banned
    q = _pair(pr)
    q.led_id, q.kind = 77, "FV"  # decoded: its reporting rules judge it (Pairer.emitters)
    assert _run(pr, q, [80.0], 3 * pr.unseen_give_up_frames) is None
    off = Pairer(unseen_give_up_frames=0)
    assert _run(off, _pair(off), [80.0], 90) is None


def test_bans_of_dropped_tracks_are_forgotten_and_live_ones_kept():
    """Pairer.banned stays bounded on a long stream: above BANNED_PRUNE_AT entries a step keeps
    only the bans whose two tracks are still live (track IDs are never reused)."""
    from receiver.vision.pairing import BANNED_PRUNE_AT
    pr = Pairer()
    pr.banned = {(i, i + 1) for i in range(100, 100 + 2 * BANNED_PRUNE_AT, 2)} | {(3, 4)}
    tracks = [Track(3, _blob(80.0, 50.0), 0, 0), Track(4, _blob(120.0, 50.0), 0, 0)]
    pr.step(np.zeros((480, 640), np.uint8), tracks, lambda g, t: 10.0)
    assert pr.banned == {(3, 4)}
    small = Pairer()
    small.banned = {(100, 101), (3, 4)}              # below the bound: nothing is pruned
    small.step(np.zeros((480, 640), np.uint8), tracks, lambda g, t: 10.0)
    assert small.banned == {(100, 101), (3, 4)}
