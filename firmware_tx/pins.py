"""Pin backends: play a `Schedule`'s periodic `levels` buffer out on one pin or a pin pair.

Every backend has the same two-call interface, so the driver never knows what it drives:

    backend.start(schedule)   # (re)start the waveform from tick 0 of a packet
    backend.stop()            # stop; all pins low (LED off)

* `VirtualBackend` + `VirtualPin`: CPython and MicroPython; pins record `(t_us, level)` edges
  against a virtual microsecond clock that the caller advances (tests, `python -m firmware_tx`).
* `TimerBackend`: MicroPython `machine.Pin` stepped from a periodic `machine.Timer` at
  `tick_hz`. The callback is one `pin.value()` write per pin and an index increment, no
  allocation. Its timing is only as good as the port's timer interrupt: usable for tone
  mode and S2-PSK (a 200 Hz clock is 400 ticks/s) and for OOK at a few kHz at most; soft
  timers (rp2, esp32) add tens of microseconds of jitter, and ports that round the period
  to whole microseconds drift at rates that do not divide 1 MHz. Use `rp2_pio.PioBackend`
  for OOK at the default 20 kHz: it is jitter-free.
* `run_virtual(schedule, pins, t0_us, t1_us)`: the thin stepping loop on its own.

Tick `i` of a waveform started at `t_start_us` begins at `t_start_us + i*1e6//tick_hz`
(exact integers, `Schedule.tick_start_us`), so virtual edges never drift.
"""


class VirtualPin:
    """A pin that records its level changes as `(t_us, level)` pairs.

    `max_edges` bounds the memory (the oldest edges are dropped, `dropped` counts them), so a
    virtual driver can run for hours. The first write is always recorded (the initial level).
    """

    def __init__(self, max_edges=100000):
        self.level = None
        self.edges = []
        self.max_edges = max_edges
        self.dropped = 0

    def write(self, t_us, level):
        """Set the level at virtual time `t_us` (non-decreasing); records only changes."""
        if level != self.level:
            self.level = level
            self.edges.append((t_us, level))
            if len(self.edges) > self.max_edges:
                # Drop a chunk at once: popping the head one by one is O(n) per edge.
                k = len(self.edges) - self.max_edges // 2
                self.dropped += k
                self.edges = self.edges[k:]

    def clear(self):
        """Forget the recorded edges (the current level is kept)."""
        self.edges = []
        self.dropped = 0


def run_virtual(schedule, pins, t0_us, t1_us, t_start_us=0):
    """Write every tick of `schedule` that starts in `[t0_us, t1_us)` to `pins`.

    `pins` is a list of VirtualPin, pin k gets bit k of each level. The waveform started at
    `t_start_us`; the first written tick is the one in progress at `t0_us` (written at t0_us).
    Returns the index of the first tick not written (absolute, from the waveform start).
    """
    lv = schedule.levels
    n = len(lv)
    hz = schedule.tick_hz
    i = (t0_us - t_start_us) * hz // 1000000
    # Tick starts are floored to whole microseconds, so the tick in progress may be one later.
    while t_start_us + (i + 1) * 1000000 // hz <= t0_us:
        i += 1
    t = t0_us
    while t < t1_us:
        level = lv[i % n]
        for k in range(len(pins)):
            pins[k].write(t, (level >> k) & 1)
        i += 1
        t = t_start_us + i * 1000000 // hz
    return i


class VirtualBackend:
    """Pin backend over VirtualPins and a virtual clock (microseconds, advanced by the caller).

    `clock_us` is a callable returning the current time in microseconds; by default the
    backend's own counter, moved by `advance(t_us)`. `max_catchup_ticks` (default 20000, one
    second of OOK at 20 kHz) bounds the work of one `advance`: when the clock jumped further,
    only the last ticks are simulated (the edges in between are not recorded), so a host
    driver that idles for hours costs nothing.
    """

    def __init__(self, pins, clock_us=None, max_catchup_ticks=20000):
        self.pins = pins
        self._clock = clock_us
        self._now_us = 0
        self.max_catchup_ticks = max_catchup_ticks
        self.schedule = None
        self._t_start_us = 0
        self._done_us = 0

    def now_us(self):
        return self._clock() if self._clock is not None else self._now_us

    def advance(self, t_us=None):
        """Simulate the running waveform up to `t_us` (default: the clock's now)."""
        if t_us is None:
            t_us = self.now_us()
        if self._clock is None:
            self._now_us = max(self._now_us, t_us)
        s = self.schedule
        if s is None or t_us <= self._done_us:
            return
        t0 = self._done_us
        # Skip ahead when too far behind; the tick grid stays anchored at t_start (no drift).
        skip_to = t_us - self.max_catchup_ticks * 1000000 // s.tick_hz
        if skip_to > t0:
            t0 = skip_to
        run_virtual(s, self.pins, t0, t_us, self._t_start_us)
        self._done_us = t_us

    def start(self, schedule):
        self.advance()
        self.schedule = schedule
        self._t_start_us = self.now_us()
        self._done_us = self._t_start_us

    def stop(self):
        self.advance()
        self.schedule = None
        t = self.now_us()
        for p in self.pins:
            p.write(t, 0)

    def running(self):
        return self.schedule is not None


class TimerBackend:
    """MicroPython backend: `machine.Pin` outputs stepped by a periodic `machine.Timer`.

    `pins`: one or two `machine.Pin` objects already configured as outputs (A, then B).
    `timer_id`: the hardware timer to use (-1 = a virtual/soft timer where the port has one).
    See the module docstring for the rates it manages.
    """

    def __init__(self, pins, timer_id=-1):
        self.pins = pins
        self.timer_id = timer_id
        self._timer = None
        self._levels = b"\x00"
        self._n = 1
        self._i = 0
        # Bind once: creating the bound method inside the IRQ would allocate.
        self._cb = self._tick

    def _tick(self, _timer):
        lv = self._levels[self._i]
        self.pins[0].value(lv & 1)
        if len(self.pins) > 1:
            self.pins[1].value((lv >> 1) & 1)
        i = self._i + 1
        self._i = 0 if i >= self._n else i

    def start(self, schedule):
        import machine

        self.stop()
        self._levels = schedule.levels
        self._n = len(schedule.levels)
        # Tick 0 now; the first timer interrupt, one tick later, writes tick 1.
        self._i = 0
        self._tick(None)
        self._timer = machine.Timer(self.timer_id)
        self._timer.init(freq=schedule.tick_hz, mode=machine.Timer.PERIODIC, callback=self._cb)

    def stop(self):
        if self._timer is not None:
            self._timer.deinit()
            self._timer = None
        for p in self.pins:
            p.value(0)
