"""Jitter-free RP2040 backend: a PIO state machine clocks the level stream out, DMA feeds it.

The PIO program is one instruction, `out(pins, npins) [delay]`, with autopull every 32 bits:
each tick shifts the next `npins` bits (bit 0 -> pin A = `out_base`, bit 1 -> pin B, which must
be the next GPIO) onto the pins, every `1 + delay` state-machine cycles. The state machine
runs at `tick_hz * repeat * cycles_per_tick`, an integer, so edge timing is set by the PIO
clock divider alone: no interrupt, no CPU, no jitter beyond one system clock (8 ns at 125 MHz)
from the fractional divider.

The CPU never touches the stream after `start`: two chained DMA channels loop over the packed
words forever (the data channel writes them into the TX FIFO paced by the state machine's
DREQ; when it finishes, it chains to a control channel that rewrites the data channel's read
address with the trigger alias, which restarts it). So the serial loop may block for as long as
it likes without a glitch.

A PIO state machine cannot run slower than `sys_clk / 65536` (about 1.9 kHz at 125 MHz, 2.3 kHz
on a 150 MHz RP2350). Slow waveforms (S2-PSK at a 200 Hz clock is 400 ticks/s) are therefore
stretched twice over: up to 31 delay cycles per tick, and beyond that every level is repeated
`repeat` times in the packed stream (`pio_plan`).

Only `pio_plan` and `pack_levels` are pure, and they are what the host tests check; the rest
needs a board. The `rp2` import is guarded so this module imports anywhere.
"""

from array import array

try:
    import machine
    import rp2
    import uctypes
except ImportError:  # CPython, or a MicroPython port without PIO
    rp2 = None

WORD_BITS = 32
MAX_CYCLES_PER_TICK = 32  # 1 cycle for `out` + at most 31 delay cycles (no side-set bits)
MIN_SM_HZ = 2400  # above sys_clk/65536 for every RP2040/RP2350 clock up to 150 MHz
DMA_BASE = 0x50000000
DMA_CHANNEL_STRIDE = 0x40
DMA_AL3_READ_ADDR_TRIG = 0x3C  # writing the read address here also starts the channel
PIO_BASES = (0x50200000, 0x50300000)
PIO_TXF0 = 0x10
DREQ_PIO_TX0 = (0, 8)  # DMA request line of state machine 0's TX FIFO, per PIO block
TREQ_UNPACED = 0x3F


def _gcd(a, b):
    while b:
        a, b = b, a % b
    return a


def pio_plan(tick_hz, min_sm_hz=MIN_SM_HZ):
    """How to clock `tick_hz` ticks/s on a PIO: `(repeat, cycles_per_tick, sm_hz)`.

    Each level is emitted `repeat` times, each emission lasts `cycles_per_tick` state-machine
    cycles (1..32), and `sm_hz = tick_hz * repeat * cycles_per_tick >= min_sm_hz` exactly
    (all integers). Chooses the fewest repeats (smallest buffer), then the fewest cycles.
    """
    if tick_hz <= 0:
        raise ValueError("tick rate must be positive")
    repeat = 1
    while True:
        per = tick_hz * repeat
        cycles = (min_sm_hz + per - 1) // per
        if cycles < 1:
            cycles = 1
        if cycles <= MAX_CYCLES_PER_TICK:
            return repeat, cycles, per * cycles
        repeat += 1


def packed_periods(n_levels, npins, repeat=1):
    """How many waveform periods the packed stream holds so that it fills whole 32-bit words."""
    bits = n_levels * repeat * npins
    return WORD_BITS // _gcd(bits, WORD_BITS)


def pack_levels(levels, npins, repeat=1):
    """Pack a periodic level buffer into 32-bit words for `out(pins, npins)` with right shift.

    `levels`: one byte per tick, bit 0 = pin A, bit 1 = pin B. Each tick becomes `npins` bits
    (`repeat` times), least-significant bit of the word first, because the OSR shifts right.
    The stream covers `packed_periods(...)` whole periods so that looping over the words
    replays the waveform seamlessly. Returns `array('I')`.
    """
    if npins not in (1, 2):
        raise ValueError("npins must be 1 or 2")
    mask = (1 << npins) - 1
    periods = packed_periods(len(levels), npins, repeat)
    nbits = len(levels) * repeat * npins * periods
    words = array("I", [0] * (nbits // WORD_BITS))
    word = 0
    pos = 0
    k = 0
    for _ in range(periods):
        for lv in levels:
            v = lv & mask
            for _ in range(repeat):
                word |= v << pos
                pos += npins
                if pos == WORD_BITS:
                    words[k] = word
                    k += 1
                    word = 0
                    pos = 0
    return words


def _program(npins, delay):
    # Built per configuration: pin count and delay are encoded in the instruction itself.
    @rp2.asm_pio(out_init=(rp2.PIO.OUT_LOW,) * npins, out_shiftdir=rp2.PIO.SHIFT_RIGHT,
                 autopull=True, pull_thresh=WORD_BITS, fifo_join=rp2.PIO.JOIN_TX)
    def prog():
        out(pins, npins)[delay]  # noqa: F821 (names injected by asm_pio)

    return prog


class PioBackend:
    """Pin backend on an RP2040/RP2350 PIO state machine fed by a DMA ring.

    `pin_a`: GPIO number of pin A; pin B (S2-PSK) is `pin_a + 1`. `sm_id`: state machine 0..7.
    """

    def __init__(self, pin_a, sm_id=0, min_sm_hz=MIN_SM_HZ):
        if rp2 is None:
            raise OSError("rp2 PIO is not available on this platform")
        self.pin_a = pin_a
        self.sm_id = sm_id
        self.min_sm_hz = min_sm_hz
        self._sm = None
        self._dma = None
        self._words = None
        self._addr = array("I", [0])
        self._npins = 0

    def start(self, schedule):
        self.stop()
        repeat, cycles, sm_hz = pio_plan(schedule.tick_hz, self.min_sm_hz)
        self._words = pack_levels(schedule.levels, schedule.npins, repeat)
        self._npins = schedule.npins
        sm = rp2.StateMachine(self.sm_id, _program(schedule.npins, cycles - 1), freq=sm_hz,
                              out_base=machine.Pin(self.pin_a))
        block, index = divmod(self.sm_id, 4)
        data, ctrl = rp2.DMA(), rp2.DMA()
        self._addr[0] = uctypes.addressof(self._words)
        data.config(read=self._words, write=PIO_BASES[block] + PIO_TXF0 + 4 * index,
                    count=len(self._words),
                    ctrl=data.pack_ctrl(size=2, inc_read=True, inc_write=False,
                                        treq_sel=DREQ_PIO_TX0[block] + index,
                                        chain_to=ctrl.channel))
        ctrl.config(read=self._addr,
                    write=DMA_BASE + DMA_CHANNEL_STRIDE * data.channel + DMA_AL3_READ_ADDR_TRIG,
                    count=1,
                    ctrl=ctrl.pack_ctrl(size=2, inc_read=False, inc_write=False,
                                        treq_sel=TREQ_UNPACED, chain_to=ctrl.channel))
        self._sm, self._dma = sm, (data, ctrl)
        data.active(1)  # fills the TX FIFO, then waits for the state machine's DREQ
        sm.active(1)

    def stop(self):
        if self._sm is not None:
            self._sm.active(0)
            self._sm = None
        if self._dma is not None:
            for ch in (self._dma[1], self._dma[0]):  # control first, so nothing re-arms data
                ch.active(0)
                ch.close()
            self._dma = None
        if rp2 is not None:
            # Hand the pins back to software control, driven low: LED off while stopped.
            for k in range(max(self._npins, 1)):
                machine.Pin(self.pin_a + k, machine.Pin.OUT, value=0)
