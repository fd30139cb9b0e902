"""Frame clock (receiver/frameclock.py) and timed OOK placement (OokDecoder timing hint).

Scene: lights at one chip rate seen by a rolling shutter whose frame k starts at
k / fps + jitter (jitter common to all lights, 100 us = 2 chips std), each light with its own
packet phase and crystal error, exact exposure integrals (tests/signals.py)."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_tx.schedule import make_schedule
from receiver.decode.ook import OokDecoder
from receiver.decode.frameclock import ClockTick, FrameClock
from signals import pin_waveform, row_profile

RATE, T_ROW, T_EXP, FPS = 20000.0, 15.0, 20.0, 30.0
JITTER_S = 100e-6


class Light:
    def __init__(self, led_id, y0, n_rows, rng, ppm=None):
        sch = make_schedule("ook", led_id, int(RATE))
        self.led_id, self.y0, self.n_rows = led_id, y0, n_rows
        self.wave, self.tick_hz = pin_waveform(sch, 0), sch.tick_hz
        self.phase_s = rng.uniform(0.0, len(self.wave) / sch.tick_hz)
        self.scale = 1.0 + (rng.uniform(-50, 50) if ppm is None else ppm) * 1e-6

    def profile(self, t_frame, rng):
        t0 = (t_frame + self.y0 * T_ROW * 1e-6 + self.phase_s) * self.scale
        return row_profile(self.wave, self.tick_hz, T_ROW, T_EXP, self.n_rows, t0, noise=3.0, rng=rng)


def frame_times(n, rng):
    return [k / FPS + rng.normal() * JITTER_S for k in range(n)]


def decoded_reference(light, times, rng):
    """A decoder of a big light, decoded on the first frames."""
    dec = OokDecoder(RATE, T_ROW, T_EXP)
    for t in times:
        if dec.step(*light.profile(t, rng)).led_id == light.led_id:
            return dec
    raise AssertionError("reference did not decode")


def run_scene(target, ref, n_frames, seed, *, clock_on=True, corrupt=None):
    """Frames of the target light decoded with (or without) the clock of the reference light.
    corrupt(k, tick) -> tick lets a test falsify the hint. Returns (decoder, ids per frame)."""
    rng = np.random.default_rng(seed)
    ref_dec = decoded_reference(ref, frame_times(6, rng), rng)
    clock = FrameClock()
    dec = OokDecoder(RATE, T_ROW, T_EXP)
    ids = []
    for k, t in enumerate(frame_times(n_frames, rng)):
        clock.begin(k)
        u = ref_dec.row0_coordinate(*ref.profile(t, rng), ref.y0)
        if u is not None:
            clock.observe("ref", u)
        tick = clock.close() if clock_on else None
        if tick is not None and corrupt is not None:
            tick = corrupt(k, tick)
        ids.append(dec.step(*target.profile(t, rng), clock=tick, y0=target.y0).led_id)
    return dec, ids


def test_clock_removes_common_jitter():
    """Two decoded lights: their row-0 packet coordinates jump by the frame jitter (chips),
    their difference from the clock of the other stays put to a few hundredths of a chip."""
    rng = np.random.default_rng(3)
    a, b = Light(0x1234, 100, 150, rng), Light(0xBEEF, 400, 120, rng)
    da, db = decoded_reference(a, frame_times(6, rng), rng), decoded_reference(b, frame_times(6, rng), rng)
    clock = FrameClock()
    ub, ck = [], []
    for k, t in enumerate(frame_times(40, rng)):
        clock.begin(k)
        clock.observe("a", da.row0_coordinate(*a.profile(t, rng), a.y0))
        ub.append(db.row0_coordinate(*b.profile(t, rng), b.y0))
        ck.append(clock.close().value)
    ub, ck = np.array(ub), np.array(ck)
    jitter = np.unwrap((ck - RATE * np.arange(40) / FPS) * 2 * np.pi / 54) * 54 / (2 * np.pi)
    assert np.std(jitter) > 1.0  # the jitter is there (2 chips std) ...
    d = np.unwrap((ub - ck) * 2 * np.pi / 54) * 54 / (2 * np.pi)
    fit = np.polyval(np.polyfit(np.arange(40), d, 1), np.arange(40))
    assert np.abs(d - fit).max() < 0.1  # ... and cancels between lights


def test_frame_clock_consensus_drops_a_slipped_reference():
    clock = FrameClock()
    ticks = []
    for k in range(12):
        c = (0.3 + 18.67 * k + (0.5 if k % 2 else -0.5)) % 54  # any jitter: only differences matter
        clock.begin(k)
        clock.observe("a", c)
        clock.observe("b", (c + 7.25 + 0.01 * k) % 54)
        clock.observe("c", (c - 11.5 + (2.0 if k == 8 else 0.0)) % 54)  # c slips 2 chips once
        ticks.append(clock.close())
    assert all(t is not None for t in ticks)
    assert ticks[8].refs == 2 and ticks[7].refs == 3
    assert max(t.resid for t in ticks) < 0.05
    assert len({t.epoch for t in ticks}) == 1
    # the chain breaks when no known reference is left: new epoch
    clock.begin(30)
    clock.observe("z", 5.0)
    assert clock.close().epoch == ticks[-1].epoch + 1


@pytest.mark.parametrize("seed", range(4))
def test_timed_placement_decodes_small_light_sooner(seed):
    """A ~18-chip light: consecutive frames barely overlap (the packet advances 18.67 chips
    per frame plus 2 chips of jitter); with the clock it decodes within a few frames."""
    rng = np.random.default_rng(100 + seed)
    ref, target = Light(0x2A2A, 100, 160, rng), Light(0x4D2 + seed, 500, 60, rng)
    dec, ids = run_scene(target, ref, 20, seed)
    _, ids_off = run_scene(target, ref, 20, seed, clock_on=False)
    first = ids.index(target.led_id)
    first_off = ids_off.index(target.led_id) if target.led_id in ids_off else 99
    assert set(ids) <= {None, target.led_id} and set(ids_off) <= {None, target.led_id}
    assert first <= 8 and first <= first_off
    assert dec.timing_ok and dec.timing_stats["timed"] > 0
    assert max(dec.timing_frac_resid) < 0.25


@pytest.mark.parametrize("mode", ["random", "slip2", "offset", "drift"])
def test_wrong_timing_hint_never_gives_a_wrong_id(mode):
    """Falsified clocks (random values, a 2-chip slip every 3rd frame, half a chip off, a
    fast drift) never yield a wrong ID: the chip grid's fraction, the overlap with trusted
    chips and the syncs catch the inconsistency (timing is dropped), CRC does the rest."""
    bad = {
        "random": lambda k, t, r: r.uniform(0, 54),
        "slip2": lambda k, t, r: t.value + (2.0 if k % 3 == 2 else 0.0),
        "offset": lambda k, t, r: t.value + (0.5 if k >= 4 else 0.0),
        "drift": lambda k, t, r: t.value + 0.3 * k,
    }[mode]
    for seed in range(6):
        rng = np.random.default_rng(200 + seed)
        r = np.random.default_rng(seed)
        ref, target = Light(0x3C3C, 100, 160, rng), Light(0x1000 + 97 * seed, 500, 60, rng)

        def corrupt(k, tick):
            return ClockTick(tick.k, bad(k, tick, r) % 54, tick.epoch, tick.refs, tick.resid)

        dec, ids = run_scene(target, ref, 30, seed, corrupt=corrupt)
        assert set(ids) <= {None, target.led_id}, (mode, seed, ids)


def test_a_misplaced_timed_frame_blocks_the_decode():
    """The last guard: a CRC-valid packet is reported only if every recent timed frame fits
    it at the shift timing gave it; one frame 2 chips off drops timing and all trust."""
    rng = np.random.default_rng(11)
    ref, target = Light(0x2A2A, 100, 160, rng), Light(0x0777, 500, 60, rng)
    dec, ids = run_scene(target, ref, 20, 11)
    assert ids[-1] == target.led_id and dec.timed_frames
    soft, shift = dec.timed_frames[-1]
    assert dec._timed_frames_fit(target.led_id)
    dec.timed_frames.append((soft, (shift + 2) % 54))
    assert not dec._timed_frames_fit(target.led_id)
    assert not dec.timing_ok and not (dec.trust_w > 0).any()


def test_consensus_mean_is_numpys():
    """frameclock._mean (the references' mean without a numpy call) gives np.mean's number."""
    from receiver.decode.frameclock import _mean
    rng = np.random.default_rng(4)
    for _ in range(20000):
        n = int(rng.integers(1, 12))
        v = (rng.normal(0, 1, n) * 10.0 ** rng.integers(-3, 3, n)).tolist()
        assert repr(_mean(v)) == repr(float(np.mean(v)))
    assert repr(_mean([-0.0, -0.0])) == repr(float(np.mean([-0.0, -0.0])))
