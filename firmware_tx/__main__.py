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
            try:
                out.write(r.encode() + b"\n")
                out.flush()
            except BrokenPipeError:
                raise
            except OSError as e:
                raise OSError(e.errno, f"cannot write standard output: {e.strerror or e}") from None
        if not data:
            return 0


def main():
    try:
        return serve()
    except (BrokenPipeError, KeyboardInterrupt):
        return 0
    except OSError as e:  # replies cannot be written (a full disk) or input cannot be read
        _quiet_stdout()
        print("firmware_tx: " + (e.strerror or str(e)), file=sys.stderr)
        return 1


def _quiet_stdout():
    """Point fd 1 at /dev/null so that the interpreter's last flush of what could not be
    written does not raise again at exit."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 1)
        os.close(fd)
    except OSError:
        pass


if __name__ == "__main__":
    sys.exit(main())
