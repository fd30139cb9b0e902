"""S2-PSK far heads read by their whole flux (receiver.vision.pairing.Pairer.head_flux,
receiver.decode.s2psk.flux_xor): a head whose halves are a few px apart, shaken sideways by
more than that from frame to frame, decodes from its flux but not from its two emitters."""

from __future__ import annotations

import numpy as np
import pytest

from receiver.decode.s2psk import S2pskDecoder, flux_xor, pair_xor
from receiver.vision.pairing import Pair, Pairer, _emitter
from receiver.vision.track import Track
from tests.vision.test_track import blob
from tools.synth.waveform import led_drive

LED_ID = 0x2D
SEP_PX = 6.0      # the halves' centres, px (a head at ~100 m)
SHAKE_PX = 7.0    # uniform horizontal shake, +- px per frame (yaw vibration)
FPS, EXPOSURE_S = 29.97, 100e-6  # NTSC rate: the frames drift across the 80 ms symbols


def test_flux_xor_levels():
    on = 200.0  # both halves lit: 2F
    assert flux_xor(100.0, on) == pytest.approx(1.0)   # one half lit: anti-phase, symbol 1
    assert flux_xor(0.0, on) == pytest.approx(-1.0)    # both dark
    assert flux_xor(200.0, on) == pytest.approx(-1.0)  # both lit
    assert flux_xor(50.0, on) == pytest.approx(0.0)    # halfway: no opinion
    assert flux_xor(300.0, on) == pytest.approx(-1.0)  # clipped
    assert flux_xor(10.0, 0.0) == 0.0                  # no level learned yet


def _far_head_frames(n: int, seed: int = 3):
    """(t_s, image, true centre x) of a far head: two 1-row, 2-px halves SEP_PX apart, lit by
    the S2-PSK drive of LED_ID (A on pin 0, B on pin 1), shaken sideways."""
    rng = np.random.default_rng(seed)
    da, db = (led_drive("s2psk", LED_ID, 200, 16, pin=k, phase_s=0.0123) for k in (0, 1))
    out = []
    for k in range(n):
        t = k / FPS + rng.normal(0.0, 0.5e-3)  # frame-time jitter
        a = float(da.exposure_mean(np.array([t]), EXPOSURE_S)[0])
        b = float(db.exposure_mean(np.array([t]), EXPOSURE_S)[0])
        img = np.clip(rng.normal(1.0, 0.4, (24, 80)), 0, 255)
        cx = 40.0 + rng.uniform(-SHAKE_PX, SHAKE_PX)
        for x, lvl in ((cx - SEP_PX / 2, a), (cx + SEP_PX / 2, b)):
            x0 = int(round(x)) - 1
            img[11:13, x0:x0 + 2] += 40.0 * lvl
            img[12, x0:x0 + 2] += 20.0 * lvl
        out.append((t, np.clip(np.round(img), 0, 255).astype(np.uint8), cx))
    return out


def _pair(pr: Pairer) -> Pair:
    """A jumper pair (one track for both emitters) at the head's unshaken place."""
    t = Track(7, blob(40.0, 12.0, r=1.0), 0, 0)
    a, b = _emitter(t), _emitter(t)
    a.blob, b.blob = blob(40.0 - SEP_PX / 2, 12.0, r=1.0), blob(40.0 + SEP_PX / 2, 12.0, r=1.0)
    p = Pair(a, b, fresh=False)
    p.mx, p.my = 40.0, 12.0
    return p


def _mean(gray, e):
    bl = e.blob
    return float(gray[bl.y0:bl.y1, bl.x0:bl.x1].mean())


def test_far_shaken_head_decodes_from_its_flux_not_from_its_emitters():
    frames = _far_head_frames(150)
    pr = Pairer()
    p = _pair(pr)
    assert pr.reads_flux(p)
    by_flux, by_emitters = S2pskDecoder(), S2pskDecoder()
    got_flux = got_emitters = None
    for t, img, _ in frames:
        f = pr.sample_flux(p, img)
        st = by_flux.step(t, flux_xor(f, pr.flux_on(p)))
        got_flux = got_flux or st.led_id
        # the emitters read where the pair puts them (it cannot see the sideways shake)
        ia, ib = pr.sample(p, img, _mean)
        st2 = by_emitters.step(t, pair_xor(ia, ib, p.levels_a.on, p.levels_b.on, p.levels_a.off, p.levels_b.off))
        got_emitters = got_emitters or st2.led_id
    assert got_flux == LED_ID
    assert got_emitters is None


def test_flux_needs_a_jumper_pair():
    pr = Pairer()
    assert pr.reads_flux(_pair(pr))
    p = _pair(pr)
    p.b = Track(8, p.b.blob, 0, 0)  # two founding tracks: read per emitter
    assert not pr.reads_flux(p)


def test_head_flux_ignores_noise_and_stays_in_the_image():
    pr = Pairer()
    p = _pair(pr)
    rng = np.random.default_rng(0)
    dark = np.clip(np.round(rng.normal(1.0, 0.4, (24, 80))), 0, 255).astype(np.uint8)
    assert pr.head_flux(p, dark) == 0.0
    p.mx = -50.0  # off the image: nothing to read, no error
    assert pr.head_flux(p, dark) == 0.0


def test_a_decoded_far_head_drops_its_undecoded_twin_only():
    pr = Pairer()
    d, twin, other = _pair(pr), _pair(pr), _pair(pr)
    d.led_id = 28
    twin.mx = d.mx - SEP_PX       # the same head, followed a baseline to the left
    other.mx = d.mx + 40.0        # another head
    assert pr._drop_twins([d, twin, other]) == [d, other]
    d.led_id = None               # no decoded head: nothing dropped
    assert pr._drop_twins([d, twin, other]) == [d, twin, other]


def test_head_backlog_reads_every_blob_near_the_head_and_stops_where_it_was_not_seen():
    pr = Pairer()
    single = 6.0
    # oldest first: 6 frames without the head (not yet detected), then one half lit, both lit,
    # dark, the other half lit; a second head 20 px to the right lit in every frame. The
    # camera pitches by +1 px per frame (view_sum), which the backlog undoes.
    states = [None] * 6 + ["a", "ab", "", "b", "a", "ab"]
    for k, st in enumerate(states):
        dy = float(k)
        xy = [(120.0, 50.0 + dy)]
        area = [single]
        if st:
            x = {"a": 97.0, "b": 103.0, "ab": 100.0}[st]
            xy.append((x, 50.0 + dy))
            area.append(single if st != "ab" else 2.2 * single)
        pr.scene_past.append((k / 30.0, (0.0, dy), [[x, y, a] for (x, y), a in zip(xy, area)]))
    pr.view_sum = (0.0, float(len(states) - 1))
    # the pair forms in the last frame ("ab"), midpoint (100, 50 + 11), baseline 6 px
    out = pr._head_backlog(100.0, 50.0 + len(states) - 1, 6.0, single)
    got = [(a, b) for _, a, b, *_ in out]
    assert got == [(1.0, 0.0), (1.0, 1.0), (0.0, 0.0), (1.0, 0.0), (1.0, 0.0)]
    assert [t for t, *_ in out] == [k / 30.0 for k in range(6, 11)]


def test_fine_noise_threshold_of_a_truncated_noisy_background_stays_near_the_noise():
    """8-bit truncation of noise of 2 gray around 8 puts almost half the samples at or above
    median + 1: the upper-tail estimate alone read sigma ~20 and a threshold of ~120 gray, over
    every light (the S2-PSK default detection follows the noise)."""
    from receiver.vision.detect import auto_level
    rng = np.random.default_rng(5)
    img = np.clip(rng.normal(8.93, 2.0, (480, 640)), 0, 255).astype(np.uint8)  # truncation
    level, bg = auto_level(img, k_mad=8.0, min_contrast=4.0, fine_noise=True)
    assert level - bg <= 8.0 * 2.6


def test_a_weak_sync_symbol_decodes_but_a_wrong_one_never():
    """The S2-PSK sync margin (0.25) takes a sync symbol read at 0.28 (two samples, one
    straddling, as a lane-changing car in `occloc hil --mode s2psk` shows), which a margin of 0.3
    rejects; a wrong symbol anywhere is still rejected with every other symbol strong."""
    from firmware_tx.framing import s2psk_packet
    from receiver.decode.s2psk import MIN_MARGIN, SYNC_MARGIN, decode_symbols
    for led_id in (0x1C, 0xE4):
        m = (np.array(s2psk_packet(led_id), dtype=np.float64) * 2 - 1) * 0.9
        for pos in range(6):  # the sync symbols
            weak = m.copy()
            weak[pos] = 0.28 * np.sign(weak[pos])
            assert decode_symbols(weak, sync_margin=SYNC_MARGIN, min_margin=MIN_MARGIN)[0] == led_id
            assert decode_symbols(weak, sync_margin=0.3, min_margin=MIN_MARGIN)[0] is None
        for pos in range(30):
            bad = m.copy()
            bad[pos] = -bad[pos]
            assert decode_symbols(bad, sync_margin=SYNC_MARGIN, min_margin=MIN_MARGIN)[0] is None


def test_a_given_up_aliased_pair_bans_its_founding_tracks():
    """A pair re-formed from a live pair's founding tracks carries an alias key (its emitters'
    LED ids); when it gives up undecoded, what is banned is its founding tracks, which new pairs
    are checked by, not the alias (which never matches a candidate)."""
    pr = Pairer()
    p = _pair(pr)
    p.alias = (901, 902)
    p.frames = pr.give_up_frames
    assert not pr._follow(p, [], np.zeros((0, 2)), (24, 80))
    assert (7, 7) in pr.banned and (901, 902) not in pr.banned


def test_head_backlog_sums_are_numpys():
    """The head's blob sums (`pair_found._sums`, plain floats) are numpy's to the bit: an area
    array's sum and the centroids' mean over axis 0, under and from numpy's 8-value blocks."""
    from receiver.vision.pair_found import _sums
    rng = np.random.default_rng(5)
    for n in range(1, 13):
        for _ in range(50):
            rows = (rng.random((n, 3)) * [1280.0, 720.0, 400.0]).tolist()
            xy, area = np.array([r[:2] for r in rows]), np.array([r[2] for r in rows])
            a, x, y = _sums(rows)
            mean = xy.mean(axis=0)
            assert a == area.sum() and x / n == mean[0] and y / n == mean[1], n
