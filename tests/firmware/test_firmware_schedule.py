"""Waveform timing through the pin backends: exact chip durations, no drift, S2-PSK symbol
changes only at clock starts, XOR of the pins equals the symbol stream, PIO word packing,
and the machine.Timer backend against a fake `machine` module."""

import sys
import types

import numpy as np
import pytest

from firmware_tx.framing import ook_packet, s2psk_packet
from firmware_tx.pins import TimerBackend, VirtualBackend, VirtualPin, run_virtual
from firmware_tx.rp2_pio import MAX_CYCLES_PER_TICK, MIN_SM_HZ, pack_levels, pio_plan
from firmware_tx.schedule import MAX_LEVELS, make_schedule, pin_edges, schedule_into


def level_at(edges, t_us):
    """Level of a recorded pin at times `t_us` (array), from its (t, level) edge list."""
    times = np.array([e[0] for e in edges], dtype=np.float64)
    levels = np.array([e[1] for e in edges], dtype=np.uint8)
    i = np.searchsorted(times, t_us, side="right") - 1
    assert np.all(i >= 0)
    return levels[i]


@pytest.mark.parametrize("rate_hz", [1000, 3000, 7000, 20000, 50000])
def test_ook_chip_timing_exact_without_drift(rate_hz):
    led_id = 0xBEEF
    s = make_schedule("ook", led_id, rate_hz)
    n_chips = 40 * 54 + 17  # many packets, ending mid-packet
    t_end = n_chips * 1000000 // rate_hz
    pin = VirtualPin()
    run_virtual(s, [pin], 0, t_end)
    # Every edge sits exactly on the integer grid floor(k * 1e6 / rate): no accumulated drift.
    k = np.array([t for t, _ in pin.edges[1:]], dtype=np.int64) * rate_hz
    idx = (k + rate_hz - 1) // 1000000  # tick index of each edge
    assert np.array_equal(idx * 1000000 // rate_hz, [t for t, _ in pin.edges[1:]])
    # Within 1 us of the ideal time even at the end of the run.
    assert np.max(np.abs(idx * 1e6 / rate_hz - np.array([t for t, _ in pin.edges[1:]]))) < 1.0
    # The waveform sampled mid-chip is the periodic chip stream.
    mid = (np.arange(n_chips - 1) + 0.5) * 1e6 / rate_hz
    stream = np.tile(np.frombuffer(bytes(ook_packet(led_id)), np.uint8), n_chips // 54 + 1)
    assert np.array_equal(level_at(pin.edges, mid), stream[: n_chips - 1])
    # Gaps between edges are whole numbers of chips (1..4) to within the 1 us grid rounding.
    gaps = np.diff(np.array([t for t, _ in pin.edges[1:]]))
    chips = gaps * rate_hz / 1e6
    assert np.all(np.abs(chips - np.round(chips)) * 1e6 / rate_hz <= 1.0)
    assert set(np.round(chips).astype(int)) <= {1, 2, 3, 4}


@pytest.mark.parametrize("rate_hz", [3000, 7000, 33333])
def test_ook_no_drift_after_a_day(rate_hz):
    # Tick starts are exact integers from the waveform start, so a window a day later is
    # still on the ideal grid, and still in the right place of the packet.
    s = make_schedule("ook", 0x002A, rate_hz)
    t0 = 86400 * 10**6 + 123
    pin = VirtualPin()
    run_virtual(s, [pin], t0, t0 + 54 * 3 * 1000000 // rate_hz)
    times = np.array([t for t, _ in pin.edges[1:]], dtype=np.int64)
    k = -(-times * rate_hz // 1000000)
    assert np.array_equal(k * 1000000 // rate_hz, times)
    mid = (np.arange(k[0], k[-1]) + 0.5) * 1e6 / rate_hz
    chips = np.frombuffer(bytes(ook_packet(0x002A)), np.uint8)
    assert np.array_equal(level_at(pin.edges, mid), chips[np.arange(k[0], k[-1]) % 54])


def test_bench_schedule_rebuild(benchmark):
    buf = bytearray(MAX_LEVELS)
    s = benchmark(schedule_into, "s2psk", 0x81, 200, 64, buf)
    assert len(s.levels) == MAX_LEVELS


def test_run_virtual_matches_pin_edges():
    for mode, led_id, rate, symclk in [("ook", 42, 7000, 16), ("s2psk", 0x81, 125, 3),
                                       ("tone", 0, 3333, 16)]:
        s = make_schedule(mode, led_id, rate, symclk)
        pins = [VirtualPin(), VirtualPin()]
        run_virtual(s, pins, 12345, 12345 + 200000)
        for k in range(s.npins):
            assert pins[k].edges == pin_edges(s, k, 12345, 12345 + 200000)


@pytest.mark.parametrize("clk_hz,symclk", [(200, 16), (125, 16), (333, 5), (7, 2)])
def test_s2psk_xor_is_symbol_stream_and_changes_only_at_clock_starts(clk_hz, symclk):
    led_id = 0x2A
    s = make_schedule("s2psk", led_id, clk_hz, symclk)
    symbols = np.frombuffer(bytes(s2psk_packet(led_id)), np.uint8)
    n_sym = 30 * 3 + 7
    t_end = n_sym * symclk * 1000000 // clk_hz
    a, b = VirtualPin(), VirtualPin()
    run_virtual(s, [a, b], 0, t_end)
    ta = np.array([t for t, _ in a.edges])
    tb = np.array([t for t, _ in b.edges])
    # Both pins are square at f_clk, 50 % duty: A toggles every half period, exactly.
    half = np.arange(1, ta.size)
    assert np.array_equal(ta[1:], half * 1000000 // (2 * clk_hz))
    # Random sampling instants away from edges: A XOR B is the symbol in force.
    rng = np.random.default_rng(5)
    t = rng.uniform(0, t_end, size=20000)
    edges = np.union1d(ta, tb)
    near = np.abs(t[:, None] - edges[None, :]).min(axis=1) < 2.0
    t = t[~near]
    xor = level_at(a.edges, t) ^ level_at(b.edges, t)
    sym_index = np.floor(t * clk_hz / 1e6 / symclk).astype(int) % 30
    assert np.array_equal(xor, symbols[sym_index])
    # XOR changes (edges of exactly one pin) happen only at clock-period starts that are
    # symbol boundaries.
    only_one = np.setxor1d(ta[1:], tb[1:])
    ticks = np.round(only_one * 2 * clk_hz / 1e6).astype(int)
    assert np.array_equal(ticks * 1000000 // (2 * clk_hz), only_one)
    assert np.all(ticks % (2 * symclk) == 0)
    # A is high in the first half of each clock period.
    assert a.edges[0] == (0, 1)


def test_tone_square_wave_exact():
    s = make_schedule("tone", 0, 3000)
    pin = VirtualPin()
    run_virtual(s, [pin], 0, 1000000)
    times = np.array([t for t, _ in pin.edges])
    assert times.size == 6000
    assert np.array_equal(times, np.arange(6000) * 1000000 // 6000)
    assert [lv for _, lv in pin.edges[:4]] == [1, 0, 1, 0]


def test_schedule_into_matches_make_schedule():
    buf = bytearray(MAX_LEVELS)
    rng = np.random.default_rng(11)
    configs = [("ook", int(i), int(r), 16) for i, r in zip(rng.integers(0, 65536, 20),
                                                          rng.integers(1000, 50001, 20))]
    configs += [("s2psk", int(i), 200, int(k)) for i, k in zip(rng.integers(0, 256, 20),
                                                              rng.integers(1, 65, 20))]
    configs += [("tone", 0, 2500, 16), ("s2psk", 255, 125, 64)]
    for mode, led_id, rate, symclk in configs:
        a = make_schedule(mode, led_id, rate, symclk)
        b = schedule_into(mode, led_id, rate, symclk, buf)
        assert bytes(a.levels) == bytes(b.levels)
        assert (a.tick_hz, a.npins, a.ticks_per_unit) == (b.tick_hz, b.npins, b.ticks_per_unit)
        assert bytes(a.units) == bytes(b.units)
    with pytest.raises(ValueError):
        schedule_into("s2psk", 1, 200, 16, bytearray(10))


def test_virtual_backend_chunked_advance_equals_one_run():
    s = make_schedule("s2psk", 0x81, 200, 4)
    ref = [VirtualPin(), VirtualPin()]
    run_virtual(s, ref, 5000, 900000, t_start_us=5000)
    pins = [VirtualPin(), VirtualPin()]
    be = VirtualBackend(pins)
    be.advance(5000)
    be.start(s)
    rng = np.random.default_rng(3)
    for t in np.sort(rng.integers(5000, 900000, size=50)):
        be.advance(int(t))
    be.advance(900000)
    assert pins[0].edges == ref[0].edges and pins[1].edges == ref[1].edges
    be.stop()
    assert pins[0].level == 0 and pins[1].level == 0


def test_virtual_backend_bounded_catchup_keeps_grid():
    s = make_schedule("ook", 42, 20000)
    pin = VirtualPin(max_edges=1000)
    be = VirtualBackend([pin], max_catchup_ticks=500)
    be.start(s)
    be.advance(3600 * 10**6)  # an hour later: only the last 500 ticks are simulated
    assert 0 < len(pin.edges) <= 1000
    ticks = [t * 20000 / 1e6 for t, _ in pin.edges[1:]]
    assert all(abs(x - round(x)) < 1e-9 for x in ticks)


@pytest.mark.parametrize("tick_hz", [1, 7, 20, 62, 63, 250, 400, 1907, 2399, 2400, 3000,
                                     20000, 50000, 100000])
def test_pio_plan(tick_hz):
    repeat, cycles, sm_hz = pio_plan(tick_hz)
    assert 1 <= cycles <= MAX_CYCLES_PER_TICK
    assert sm_hz == tick_hz * repeat * cycles >= MIN_SM_HZ
    if repeat > 1:  # fewest repeats: one fewer could not reach the minimum clock
        assert tick_hz * (repeat - 1) * MAX_CYCLES_PER_TICK < MIN_SM_HZ
    assert tick_hz * repeat * (cycles - 1) < MIN_SM_HZ or cycles == 1


def unpack_words(words, npins):
    w = np.array(words, dtype=np.uint64)
    bits = ((w[:, None] >> np.arange(32, dtype=np.uint64)[None, :]) & 1).astype(np.uint8).ravel()
    groups = bits.reshape(-1, npins)
    return (groups * (1 << np.arange(npins))[None, :]).sum(axis=1)


@pytest.mark.parametrize("mode,led_id,rate,symclk,repeat", [
    ("ook", 0xBEEF, 20000, 16, 1), ("ook", 42, 1000, 16, 3), ("s2psk", 0x81, 200, 16, 1),
    ("s2psk", 0x2A, 10, 3, 4), ("tone", 0, 2000, 16, 1), ("tone", 0, 100, 16, 5)])
def test_pack_levels_round_trip(mode, led_id, rate, symclk, repeat):
    s = make_schedule(mode, led_id, rate, symclk)
    words = pack_levels(s.levels, s.npins, repeat)
    assert words.itemsize == 4
    got = unpack_words(words, s.npins)
    lv = np.repeat(np.frombuffer(bytes(s.levels), np.uint8), repeat)
    assert got.size % lv.size == 0  # whole periods, so looping the words is seamless
    assert np.array_equal(got, np.tile(lv, got.size // lv.size))
    assert got.size // lv.size == 32 // np.gcd(lv.size * s.npins, 32)


class _FakePin:
    def __init__(self):
        self.values = []

    def value(self, v):
        self.values.append(v)


def test_timer_backend_with_fake_machine(monkeypatch):
    made = []

    class Timer:
        PERIODIC = 1

        def __init__(self, tid):
            self.tid = tid
            made.append(self)

        def init(self, freq, mode, callback):
            self.freq, self.mode, self.callback = freq, mode, callback

        def deinit(self):
            self.dead = True

    monkeypatch.setitem(sys.modules, "machine", types.SimpleNamespace(Timer=Timer))
    pins = [_FakePin(), _FakePin()]
    be = TimerBackend(pins, timer_id=2)
    s = make_schedule("s2psk", 0x81, 200, 2)
    be.start(s)
    t = made[-1]
    assert (t.tid, t.freq, t.mode) == (2, 400, Timer.PERIODIC)
    assert pins[0].values[:2] == [0, 1]  # stop() drives low, then tick 0 is written at once
    del pins[0].values[:1], pins[1].values[:1]
    n = len(s.levels) * 2 + 5
    for _ in range(n - 1):
        t.callback(t)
    lv = [s.levels[i % len(s.levels)] for i in range(n)]
    assert pins[0].values == [v & 1 for v in lv]
    assert pins[1].values == [(v >> 1) & 1 for v in lv]
    be.stop()
    assert t.dead and pins[0].values[-1] == 0 and pins[1].values[-1] == 0
