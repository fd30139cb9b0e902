"""Driver state: configuration, the waveform rebuilt into one preallocated buffer, a pin backend.

The driver is what the serial commands act on (`protocol.py` parses, this module decides).
Every setter validates first and changes nothing when it raises, so a bad command leaves
the driver exactly as it was.

Configuration rules (also the serial protocol's, INTERFACES.md):

* `mode`: 'ook' (default), 's2psk' or 'tone'.
* `led_id`: the current mode's ID. Each mode keeps its own (`ids`, default 0), as it keeps its
  rate, so `MODE` always succeeds and an identity is never truncated: OOK carries 16 bits,
  S2-PSK 8 bits; tone mode has no ID on air but keeps (and range-checks, 16 bits) its own.
  `MODE S2PSK` then `ID 42` sets the S2-PSK ID and leaves the OOK one as it was.
* `rate`: each mode remembers its own rate, so switching modes back and forth never leaves an
  OOK chip rate as an S2-PSK clock. Defaults and ranges per mode (`DEFAULT_RATE_HZ`,
  `RATE_RANGE_HZ`): OOK chip rate 20000 Hz (1000..50000, PROTOCOL.md section 2), S2-PSK clock
  200 Hz (10..2000; the thesis uses 200 and 125 Hz), tone frequency 2000 Hz (100..25000).
* `symclk`: S2-PSK clock periods per symbol, default 16, 1..64; kept in every mode.
* While running, a configuration change takes effect at once, restarting at a packet start.
  While stopped, all pins are low (LED off).
"""

from firmware_tx.schedule import MAX_LEVELS, MAX_SYMCLK, MODES, schedule_into

ID_MAX = {"ook": 0xFFFF, "s2psk": 0xFF, "tone": 0xFFFF}
DEFAULT_RATE_HZ = {"ook": 20000, "s2psk": 200, "tone": 2000}
RATE_RANGE_HZ = {"ook": (1000, 50000), "s2psk": (10, 2000), "tone": (100, 25000)}
DEFAULT_SYMCLK = 16
SYMCLK_RANGE = (1, MAX_SYMCLK)


class ConflictError(ValueError):
    """A value that is valid on its own but not with the rest of the configuration."""


class Driver:
    """LED driver: configuration + schedule + injected pin backend (`start(schedule)`, `stop()`)."""

    def __init__(self, backend):
        self.backend = backend
        self.mode = "ook"
        self.led_id = 0          # ids[mode], kept in step
        self.ids = {}
        self.rates = {}
        for m in MODES:
            self.ids[m] = 0
            self.rates[m] = DEFAULT_RATE_HZ[m]
        self.symclk = DEFAULT_SYMCLK
        self.running = False
        self._buf = bytearray(MAX_LEVELS)
        self.schedule = self._build()

    def rate_hz(self):
        """Rate of the current mode: OOK chip rate, S2-PSK clock or tone frequency (Hz)."""
        return self.rates[self.mode]

    def _build(self):
        return schedule_into(self.mode, self.led_id, self.rates[self.mode], self.symclk,
                             self._buf)

    def _apply(self):
        # The timer backend reads the level buffer while running: stop it before rewriting.
        if self.running:
            self.backend.stop()
        self.schedule = self._build()
        if self.running:
            self.backend.start(self.schedule)

    def set_mode(self, mode):
        if mode not in MODES:
            raise ValueError("unknown mode")
        self.mode = mode
        self.led_id = self.ids[mode]
        self._apply()

    def set_id(self, led_id):
        if not 0 <= led_id <= ID_MAX[self.mode]:
            raise ValueError("id must be 0..%d in %s" % (ID_MAX[self.mode], self.mode))
        self.ids[self.mode] = led_id
        self.led_id = led_id
        self._apply()

    def set_rate(self, rate_hz):
        lo, hi = RATE_RANGE_HZ[self.mode]
        if not lo <= rate_hz <= hi:
            raise ValueError("rate must be %d..%d Hz in %s" % (lo, hi, self.mode))
        self.rates[self.mode] = rate_hz
        self._apply()

    def set_symclk(self, symclk):
        if not SYMCLK_RANGE[0] <= symclk <= SYMCLK_RANGE[1]:
            raise ValueError("symclk must be %d..%d" % SYMCLK_RANGE)
        self.symclk = symclk
        self._apply()

    def start(self):
        """Start (or restart from a packet start) the waveform."""
        self.running = True
        self.backend.start(self.schedule)

    def stop(self):
        self.running = False
        self.backend.stop()

    def dump(self, n):
        """First `n` chips / symbols / half-periods of the stream from a packet start."""
        return self.schedule.dump(n)
