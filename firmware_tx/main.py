"""Board entry point (MicroPython): the serial protocol on the USB serial port (stdin/stdout).

Copy the `firmware_tx/` package to the board and add a root `main.py` containing
`from firmware_tx.main import main; main()`. Input is polled without blocking
(`select.poll` on `sys.stdin`), one byte at a time, so a host that sends garbage or half a line never stalls the board; the
waveform itself is played by the backend (PIO + DMA on RP2040/RP2350, a hardware timer
elsewhere), not by this loop.

Pins: pin A is GPIO `PIN_A`; S2-PSK's pin B is `PIN_A + 1` (the PIO backend needs consecutive
pins). Change `PIN_A` for your wiring.
"""

import sys

from firmware_tx.driver import Driver
from firmware_tx.protocol import Protocol

PIN_A = 15
TIMER_ID = -1  # soft timer on rp2/stm32/...; ESP32 has only hardware timers 0..3: use 0
POLL_TIMEOUT_MS = 10
POLLIN = 1  # select.POLLIN on every port; a constant so `serve` runs without `select`


def make_backend(pin_a=PIN_A):
    """PIO backend on rp2 boards (jitter-free), else the machine.Timer backend."""
    try:
        from firmware_tx.rp2_pio import PioBackend

        return PioBackend(pin_a)
    except OSError:
        import machine

        from firmware_tx.pins import TimerBackend

        pins = [machine.Pin(pin_a + k, machine.Pin.OUT, value=0) for k in range(2)]
        return TimerBackend(pins, timer_id=TIMER_ID)


def serve(proto, stdin, write, poller, timeout_ms=POLL_TIMEOUT_MS, max_polls=None):
    """Poll `stdin` (registered in `poller`) and answer lines with `write(str)` forever.

    `max_polls` bounds the loop for tests (None = forever).
    """
    polls = 0
    while max_polls is None or polls < max_polls:
        polls += 1
        for _obj, event in poller.poll(timeout_ms):
            if not event & POLLIN:  # anything but POLLIN (e.g. POLLHUP): nothing to read
                continue
            data = stdin.read(1)
            if data:
                for reply in proto.feed(data):
                    write(reply + "\n")


def main(pin_a=PIN_A, ignore_ctrl_c=False):
    """Run the driver forever. `ignore_ctrl_c=True` stops byte 0x03 from raising
    KeyboardInterrupt (a host sending binary garbage can then never stop the board, but
    neither can mpremote break in: reset the board to get the REPL back)."""
    import select

    if ignore_ctrl_c:
        import micropython

        micropython.kbd_intr(-1)
    stdin = getattr(sys.stdin, "buffer", sys.stdin)
    poller = select.poll()
    poller.register(sys.stdin, select.POLLIN)
    proto = Protocol(Driver(make_backend(pin_a)))
    serve(proto, stdin, sys.stdout.write, poller)

