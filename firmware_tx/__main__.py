"""`python -m firmware_tx`: the LED driver on the host, serial protocol on stdin/stdout.

The pins are `VirtualPin`s on a `VirtualBackend` whose clock is the host's monotonic clock, so
a running waveform is simulated (bounded work per line) exactly as a board would drive it.
Input is read as raw bytes (binary-safe: garbage gets `ERR`, never a crash), each reply is
written and flushed at once. Exits 0 at end of input (EOF, or EIO from a pty whose other
side closed). CPython only; the board entry point is `firmware_tx/main.py`.
"""

import errno
import os
import sys
import time

from firmware_tx.driver import Driver
from firmware_tx.pins import VirtualBackend, VirtualPin
from firmware_tx.protocol import Protocol

READ_CHUNK = 4096


def make_virtual_driver(clock_us=None):
    """A Driver on two VirtualPins (A, B); returns (driver, backend)."""
    if clock_us is None:
        t0 = time.monotonic_ns()

        def clock_us():
            return (time.monotonic_ns() - t0) // 1000

    backend = VirtualBackend([VirtualPin(), VirtualPin()], clock_us=clock_us)
    return Driver(backend), backend


def serve(fd_in=0, out=None):
    """Serve the protocol on file descriptor `fd_in`, replies to binary stream `out`."""
    out = sys.stdout.buffer if out is None else out
    driver, backend = make_virtual_driver()
    proto = Protocol(driver)
    while True:
        try:
            data = os.read(fd_in, READ_CHUNK)
        except OSError as e:
            if e.errno != errno.EIO:  # EIO: the pty's other side is gone, i.e. end of input
                raise
            data = b""
        replies = proto.feed(data) if data else proto.finish()
        backend.advance()
        for r in replies:
            out.write(r.encode() + b"\n")
            out.flush()
        if not data:
            return 0


def main():
    try:
        return serve()
    except (BrokenPipeError, KeyboardInterrupt):
        return 0


if __name__ == "__main__":
    sys.exit(main())
