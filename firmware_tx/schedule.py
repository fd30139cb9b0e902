"""Waveform scheduler: packet stream -> exact drive timing for one pin or a pin pair.

A drive waveform is periodic and piecewise constant on a grid of equal **ticks**:

* OOK: one tick per chip, `tick_hz = rate_hz` (PROTOCOL.md section 2).
* S2-PSK: two ticks per clock period, `tick_hz = 2 * clk_hz`; pin A is high in the first
  tick of each clock period, pin B = A XOR symbol, a symbol lasts `symclk` whole clock
  periods, so symbols change only at clock-period starts (PROTOCOL.md section 3).
* Tone: two ticks per period of the tone, `tick_hz = 2 * freq_hz` (PROTOCOL.md section 4).

One period of the waveform is precomputed into a preallocated `bytearray` `levels`, one byte
per tick, bit 0 = pin A, bit 1 = pin B. Tick `i` starts at `i * 1_000_000 // tick_hz`
microseconds after the period start (exact integer arithmetic, so no drift accumulates
however long the stream runs); a pin backend only has to step through `levels`.
MicroPython-compatible.
"""

from firmware_tx.framing import ook_packet, s2psk_packet

MODES = ("ook", "s2psk", "tone")

OOK_RATE_MIN_HZ = 1000
OOK_RATE_MAX_HZ = 50000


class Schedule:
    """One period of a drive waveform.

    Attributes:
      mode: 'ook', 's2psk' or 'tone'.
      tick_hz: ticks per second (int).
      levels: bytearray, one entry per tick; bit 0 = pin A, bit 1 = pin B.
      npins: 1 (OOK, tone) or 2 (S2-PSK).
      units: the stream units DUMP reports (chips, symbols or half-periods), a bytearray of 0/1.
      ticks_per_unit: ticks spanned by one unit (1 for OOK chips and tone half-periods,
        2*symclk for S2-PSK symbols).
    """

    def __init__(self, mode, tick_hz, levels, npins, units, ticks_per_unit):
        self.mode = mode
        self.tick_hz = tick_hz
        self.levels = levels
        self.npins = npins
        self.units = units
        self.ticks_per_unit = ticks_per_unit

    def period_us(self):
        """Length of one waveform period in microseconds (float)."""
        return len(self.levels) * 1000000 / self.tick_hz

    def tick_start_us(self, i):
        """Start of tick `i` (any integer >= 0, wraps over periods) in whole microseconds."""
        return i * 1000000 // self.tick_hz

    def dump(self, n):
        """First `n` stream units from a packet start, as a bytearray of 0/1 (periodic)."""
        u = self.units
        out = bytearray(n)
        for i in range(n):
            out[i] = u[i % len(u)]
        return out


def ook_schedule(led_id, rate_hz):
    """OOK chip stream of `led_id` at `rate_hz` chips/s on one pin (1 = LED on)."""
    if not OOK_RATE_MIN_HZ <= rate_hz <= OOK_RATE_MAX_HZ:
        raise ValueError("OOK chip rate must be 1000..50000 Hz")
    chips = ook_packet(led_id)
    return Schedule("ook", rate_hz, bytearray(chips), 1, chips, 1)


def s2psk_levels(symbols, symclk, out=None):
    """Pin-pair levels for a symbol sequence, `2*symclk` ticks per symbol.

    Writes into `out` (a preallocated bytearray of len(symbols)*2*symclk) when given.
    """
    n = 2 * symclk
    if out is None:
        out = bytearray(len(symbols) * n)
    k = 0
    for s in symbols:
        hi = 1 | ((1 ^ s) << 1)  # first half of the clock: A = 1, B = 1 XOR s
        lo = 0 | (s << 1)  # second half: A = 0, B = 0 XOR s
        for _ in range(symclk):
            out[k] = hi
            out[k + 1] = lo
            k += 2
    return out


def s2psk_schedule(led_id, clk_hz=200, symclk=16):
    """S2-PSK stream of `led_id`: both pins square at `clk_hz`, B = A XOR symbol."""
    if clk_hz <= 0 or symclk <= 0:
        raise ValueError("S2-PSK clock and clocks per symbol must be positive")
    symbols = s2psk_packet(led_id)
    return Schedule("s2psk", 2 * clk_hz, s2psk_levels(symbols, symclk), 2, symbols, 2 * symclk)


def tone_schedule(freq_hz):
    """50 % duty square wave at `freq_hz` on one pin (high half first)."""
    if freq_hz <= 0:
        raise ValueError("tone frequency must be positive")
    return Schedule("tone", 2 * freq_hz, bytearray(b"\x01\x00"), 1, bytearray(b"\x01\x00"), 1)


def make_schedule(mode, led_id, rate_hz, symclk=16):
    """Schedule for a driver configuration (`rate_hz`: chip rate, S2-PSK clock or tone)."""
    if mode == "ook":
        return ook_schedule(led_id, rate_hz)
    if mode == "s2psk":
        return s2psk_schedule(led_id, rate_hz, symclk)
    if mode == "tone":
        return tone_schedule(rate_hz)
    raise ValueError("unknown mode")


def pin_edges(schedule, pin, t0_us, t1_us):
    """Level changes of one pin (0 = A, 1 = B) in `[t0_us, t1_us)`, waveform started at t=0.

    Returns a list of `(t_us, level)` pairs: the level at `t0_us` first, then every change.
    """
    lv = schedule.levels
    n = len(lv)
    i = t0_us * schedule.tick_hz // 1000000
    prev = (lv[i % n] >> pin) & 1
    out = [(t0_us, prev)]
    while True:
        i += 1
        t = schedule.tick_start_us(i)
        if t >= t1_us:
            return out
        level = (lv[i % n] >> pin) & 1
        if level != prev:
            out.append((t, level))
            prev = level


# Largest waveform period any valid configuration needs, in ticks: an S2-PSK packet of 30
# symbols at the protocol's maximum of 64 clocks per symbol (2 ticks per clock).
MAX_SYMCLK = 64
MAX_LEVELS = 30 * 2 * MAX_SYMCLK


def schedule_into(mode, led_id, rate_hz, symclk, buf):
    """Like `make_schedule`, but writes the levels into the preallocated bytearray `buf`.

    The returned Schedule's `levels` is a memoryview of the first ticks of `buf`, so
    reconfiguring a running board never allocates a new waveform buffer (MicroPython's heap
    fragments when large buffers come and go). `buf` must hold at least the period
    (`MAX_LEVELS` bytes always suffice); ValueError otherwise, or on a bad configuration.
    """
    if mode == "ook":
        if not OOK_RATE_MIN_HZ <= rate_hz <= OOK_RATE_MAX_HZ:
            raise ValueError("OOK chip rate must be 1000..50000 Hz")
        units = ook_packet(led_id)
        n = len(units)
        if n > len(buf):
            raise ValueError("level buffer too small")
        for i in range(n):
            buf[i] = units[i]
        return Schedule("ook", rate_hz, memoryview(buf)[:n], 1, units, 1)
    if mode == "s2psk":
        if rate_hz <= 0 or symclk <= 0:
            raise ValueError("S2-PSK clock and clocks per symbol must be positive")
        units = s2psk_packet(led_id)
        n = len(units) * 2 * symclk
        if n > len(buf):
            raise ValueError("level buffer too small")
        levels = memoryview(buf)[:n]
        s2psk_levels(units, symclk, levels)
        return Schedule("s2psk", 2 * rate_hz, levels, 2, units, 2 * symclk)
    if mode == "tone":
        if rate_hz <= 0:
            raise ValueError("tone frequency must be positive")
        if len(buf) < 2:
            raise ValueError("level buffer too small")
        buf[0] = 1
        buf[1] = 0
        return Schedule("tone", 2 * rate_hz, memoryview(buf)[:2], 1, bytearray(b"\x01\x00"), 1)
    raise ValueError("unknown mode")
