"""Serial control protocol (INTERFACES.md, "LED driver serial protocol"), without any I/O.

`Protocol(driver).feed(data)` takes whatever bytes arrived (any split, any garbage) and
returns the reply lines (str, no newline) for the lines it completed. The board's `main.py`
and the host's `python -m firmware_tx` only move bytes; everything here runs on MicroPython.

Lines (`LineReader`):

* A line ends in `\\n`, `\\r` or `\\r\\n`, all alike (a `\\n` right after a `\\r` is part of
  that line end, not an empty line). Empty or blank lines get no reply.
* At most `MAX_LINE` = 64 characters (without the line end). A longer line gets one
  `ERR 4` when its `\\n` arrives; its bytes are not stored, so the buffer stays bounded.
* Only printable ASCII (0x20-0x7E) and tab; anything else (non-ASCII, non-UTF-8, control
  bytes) makes the whole line `ERR 5`.
* A partial line waits for the rest; `finish()` (end of input) treats it as a last line.

Commands (`Protocol.handle`): keywords and mode names are case-insensitive; arguments are
separated by spaces or tabs; numbers are decimal or `0x` hex (no sign, no underscores).
Replies name modes in upper case (`OK MODE S2PSK`, `STATUS mode=S2PSK`) and give numbers in
decimal. `DUMP n` takes 1..`DUMP_MAX` (1024); its reply may exceed 64 characters.
For ranges, defaults and the MODE/ID rule see `driver.py`.

Error codes (`ERR <code> <reason>`; a bad line changes nothing):

| code | meaning |
|---|---|
| 1 | unknown command |
| 2 | syntax: wrong number of arguments, or not a number / not a mode name |
| 3 | value out of range for the current mode |
| 4 | line longer than 64 characters |
| 5 | bad characters: non-ASCII, non-UTF-8 or control bytes |
| 6 | conflict (reserved; no command gives it since each mode keeps its own ID) |
"""

from firmware_tx import VERSION
from firmware_tx.framing import to_str

MAX_LINE = 64
DUMP_MAX = 1024

ERR_UNKNOWN = 1
ERR_SYNTAX = 2
ERR_RANGE = 3
ERR_TOO_LONG = 4
ERR_BAD_CHARS = 5
ERR_CONFLICT = 6

_NL = 10
_CR = 13
_TAB = 9

MODE_NAMES = {"OOK": "ook", "S2PSK": "s2psk", "TONE": "tone"}
MODE_LABELS = {"ook": "OOK", "s2psk": "S2PSK", "tone": "TONE"}


def err(code, reason):
    return "ERR %d %s" % (code, reason)


class LineReader:
    """Bounded line assembler: `feed(bytes)` -> list of complete lines.

    Each item is a `str` (a clean line, `\\r\\n` stripped) or an `int` error code
    (`ERR_TOO_LONG`, `ERR_BAD_CHARS`) standing for a rejected line.
    """

    def __init__(self, max_line=MAX_LINE):
        self.max_line = max_line
        self._buf = bytearray(max_line)
        self._n = 0
        self._too_long = False
        self._bad = False
        self._cr = False

    def _reset(self):
        self._n = 0
        self._too_long = False
        self._bad = False

    def _end(self):
        if self._too_long:
            out = ERR_TOO_LONG
        elif self._bad:
            out = ERR_BAD_CHARS
        else:
            out = bytes(self._buf[:self._n]).decode()
        self._reset()
        return out

    def _put(self, b):
        if not (0x20 <= b <= 0x7E or b == _TAB):
            self._bad = True
        if self._n >= self.max_line:
            self._too_long = True
        elif not self._too_long:
            self._buf[self._n] = b
            self._n += 1

    def feed(self, data):
        out = []
        for b in data:
            if b == _NL or b == _CR:
                after_cr = self._cr
                self._cr = b == _CR
                if b == _NL and after_cr:
                    continue  # the "\n" of a "\r\n": one line end
                out.append(self._end())
            else:
                self._cr = False
                self._put(b)
        return out

    def finish(self):
        """End of input: the pending partial line, if any, as a list of 0 or 1 items."""
        self._cr = False
        if self._n or self._too_long or self._bad:
            return [self._end()]
        return []


def parse_number(text):
    """Non-negative int from decimal or `0x` hex text; None when it is not one."""
    t = text.lower()
    if t.startswith("0x"):
        digits = t[2:]
        base = 16
        ok = "0123456789abcdef"
    else:
        digits = t
        base = 10
        ok = "0123456789"
    if not digits:
        return None
    for c in digits:
        if c not in ok:
            return None
    return int(digits, base)


class Protocol:
    """Serial command handler around a `Driver`."""

    def __init__(self, driver, max_line=MAX_LINE):
        self.driver = driver
        self.reader = LineReader(max_line)

    def feed(self, data):
        """Bytes in -> reply lines out (one per completed non-empty line)."""
        return self._replies(self.reader.feed(data))

    def finish(self):
        """End of input: reply to a last unterminated line, if any."""
        return self._replies(self.reader.finish())

    def _replies(self, items):
        out = []
        for item in items:
            if item == ERR_TOO_LONG:
                out.append(err(ERR_TOO_LONG,
                               "line longer than %d characters" % self.reader.max_line))
            elif item == ERR_BAD_CHARS:
                out.append(err(ERR_BAD_CHARS, "non-ASCII or control characters"))
            else:
                reply = self.handle(item)
                if reply is not None:
                    out.append(reply)
        return out

    def status(self):
        d = self.driver
        return "OK STATUS mode=%s id=%d rate=%d symclk=%d running=%d" % (
            MODE_LABELS[d.mode], d.led_id, d.rate_hz(), d.symclk, 1 if d.running else 0)

    def handle(self, line):
        """One clean line -> one reply line, or None for a blank line."""
        words = line.split()
        if not words:
            return None
        cmd = words[0].upper()
        args = words[1:]
        d = self.driver
        if cmd in ("PING", "START", "STOP", "STATUS"):
            if args:
                return err(ERR_SYNTAX, "%s takes no argument" % cmd)
            if cmd == "PING":
                return "OK PONG " + VERSION
            if cmd == "START":
                d.start()
                return "OK START"
            if cmd == "STOP":
                d.stop()
                return "OK STOP"
            return self.status()
        if cmd not in ("MODE", "ID", "RATE", "SYMCLK", "DUMP"):
            return err(ERR_UNKNOWN, "unknown command")
        if len(args) != 1:
            return err(ERR_SYNTAX, "%s takes one argument" % cmd)
        if cmd == "MODE":
            mode = MODE_NAMES.get(args[0].upper())
            if mode is None:
                return err(ERR_SYNTAX, "mode must be OOK, S2PSK or TONE")
            d.set_mode(mode)
            return "OK MODE " + MODE_LABELS[mode]
        n = parse_number(args[0])
        if n is None:
            return err(ERR_SYNTAX, "not a number")
        try:
            if cmd == "ID":
                d.set_id(n)
                return "OK ID %d" % n
            if cmd == "RATE":
                d.set_rate(n)
                return "OK RATE %d" % n
            if cmd == "SYMCLK":
                d.set_symclk(n)
                return "OK SYMCLK %d" % n
        except ValueError as e:
            return err(ERR_RANGE, str(e))
        if not 1 <= n <= DUMP_MAX:
            return err(ERR_RANGE, "dump length must be 1..%d" % DUMP_MAX)
        return "OK DUMP %d %s" % (n, to_str(d.dump(n)))
