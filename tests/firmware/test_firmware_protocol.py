"""Serial protocol: scripted sessions with known replies, every error code, state unchanged on
errors, and fuzz (random bytes, over-long lines, non-UTF-8, lines split across feeds)."""

import re

import numpy as np
import pytest

from firmware_tx import VERSION
from firmware_tx import main as board_main
from firmware_tx.driver import Driver
from firmware_tx.pins import VirtualBackend, VirtualPin
from firmware_tx.protocol import DUMP_MAX, MAX_LINE, LineReader, Protocol, parse_number

REPLY = re.compile(r"^(OK [ -~]+|ERR [1-6] [ -~]+)$")


def new_proto():
    backend = VirtualBackend([VirtualPin(), VirtualPin()])
    return Protocol(Driver(backend)), backend


def state(proto):
    d = proto.driver
    return (d.mode, d.led_id, dict(d.ids), dict(d.rates), d.symclk, d.running, bytes(d.schedule.levels),
            d.schedule.tick_hz)


def talk(proto, text):
    return proto.feed(text.encode() if isinstance(text, str) else text)


SESSION = [
    ("PING", "OK PONG " + VERSION),
    ("STATUS", "OK STATUS mode=OOK id=0 rate=20000 symclk=16 running=0"),
    ("id 0xBEEF", "OK ID 48879"),
    ("DUMP 54", "OK DUMP 54 111000100110101010100110101001101010100101011010011001"),
    ("MODE S2PSK", "OK MODE S2PSK"),      # each mode keeps its own ID: S2-PSK's is still 0
    ("STATUS", "OK STATUS mode=S2PSK id=0 rate=200 symclk=16 running=0"),
    ("ID 0x2a", "OK ID 42"),
    ("Mode s2psk", "OK MODE S2PSK"),
    ("DUMP 32", "OK DUMP 32 11100001011001100110010110101011"),
    ("STATUS", "OK STATUS mode=S2PSK id=42 rate=200 symclk=16 running=0"),
    ("RATE 125", "OK RATE 125"),
    ("SYMCLK 0x8", "OK SYMCLK 8"),
    ("ID 256", "ERR 3 id must be 0..255 in s2psk"),
    ("START", "OK START"),
    ("MODE TONE", "OK MODE TONE"),
    ("STATUS", "OK STATUS mode=TONE id=0 rate=2000 symclk=8 running=1"),
    ("DUMP 5", "OK DUMP 5 10101"),
    ("MODE OOK", "OK MODE OOK"),
    ("STATUS", "OK STATUS mode=OOK id=48879 rate=20000 symclk=8 running=1"),
    ("RATE 999", "ERR 3 rate must be 1000..50000 Hz in ook"),
    ("RATE 50001", "ERR 3 rate must be 1000..50000 Hz in ook"),
    ("RATE 3000", "OK RATE 3000"),
    ("SYMCLK 65", "ERR 3 symclk must be 1..64"),
    ("STOP", "OK STOP"),
    ("FLY", "ERR 1 unknown command"),
    ("PING 1", "ERR 2 PING takes no argument"),
    ("ID", "ERR 2 ID takes one argument"),
    ("ID 1 2", "ERR 2 ID takes one argument"),
    ("ID -1", "ERR 2 not a number"),
    ("ID 0x", "ERR 2 not a number"),
    ("ID 12a", "ERR 2 not a number"),
    ("MODE FSK", "ERR 2 mode must be OOK, S2PSK or TONE"),
    ("DUMP 0", "ERR 3 dump length must be 1..1024"),
    ("STATUS", "OK STATUS mode=OOK id=48879 rate=3000 symclk=8 running=0"),
    ("MODE S2PSK", "OK MODE S2PSK"),
    ("STATUS", "OK STATUS mode=S2PSK id=42 rate=125 symclk=8 running=0"),
    ("MODE OOK", "OK MODE OOK"),
]


def test_scripted_session():
    proto, _ = new_proto()
    for line, want in SESSION:
        assert talk(proto, line + "\n") == [want], line


def test_whole_session_in_one_feed_and_byte_by_byte_agree():
    text = "".join(line + "\r\n" for line, _ in SESSION).encode()
    want = [w for _, w in SESSION]
    p1, _ = new_proto()
    assert p1.feed(text) == want
    p2, _ = new_proto()
    got = []
    for i in range(len(text)):
        got += p2.feed(text[i:i + 1])
    assert got == want


def test_dump_bounds_and_long_reply():
    proto, _ = new_proto()
    r = talk(proto, "DUMP %d\n" % DUMP_MAX)[0]
    assert r.startswith("OK DUMP 1024 ") and len(r) == len("OK DUMP 1024 ") + 1024
    assert talk(proto, "DUMP %d\n" % (DUMP_MAX + 1)) == ["ERR 3 dump length must be 1..1024"]


def test_line_length_limit_exact():
    proto, _ = new_proto()
    line = "ID " + "0" * (MAX_LINE - 5) + "42"
    assert len(line) == MAX_LINE
    assert talk(proto, line + "\r\n") == ["OK ID 42"]  # the \r does not count
    assert talk(proto, "ID " + "0" * (MAX_LINE - 4) + "42\n")[0].startswith("ERR 4 ")


def test_overlong_line_one_error_bounded_buffer():
    proto, _ = new_proto()
    before = state(proto)
    assert talk(proto, "ID 7" + "7" * 10000) == []
    assert proto.reader._n <= MAX_LINE
    assert talk(proto, "\n") == ["ERR 4 line longer than 64 characters"]
    assert state(proto) == before
    assert talk(proto, "PING\n") == ["OK PONG " + VERSION]


@pytest.mark.parametrize("bad", [b"\xff\xfe\n", "ID \u00e9\n".encode(), b"ID\x00 5\n",
                                 b"PI\x1bNG\n", b"PI\x0bNG\r"])
def test_bad_characters(bad):
    proto, _ = new_proto()
    before = state(proto)
    assert proto.feed(bad) == ["ERR 5 non-ASCII or control characters"]
    assert state(proto) == before


def test_blank_lines_get_no_reply_and_tabs_separate():
    proto, _ = new_proto()
    assert proto.feed(b"\n\r\n   \n\t\n") == []
    assert proto.feed(b"\tid\t0x10 \n") == ["OK ID 16"]


def test_finish_answers_unterminated_last_line():
    proto, _ = new_proto()
    assert proto.feed(b"PI") == []
    assert proto.feed(b"NG") == []
    assert proto.finish() == ["OK PONG " + VERSION]
    assert proto.finish() == []


def test_parse_number():
    assert parse_number("0") == 0 and parse_number("007") == 7
    assert parse_number("0XfF") == 255 and parse_number("65535") == 65535
    for bad in ["", "0x", "+1", "-1", "1_0", "1.0", "x1", "0b1", " 1"]:
        assert parse_number(bad) is None, bad


def test_running_reconfiguration_restarts_backend_with_new_waveform():
    proto, backend = new_proto()
    talk(proto, "START\n")
    assert backend.running()
    talk(proto, "ID 0x2A\n")
    assert bytes(backend.schedule.levels) == bytes(proto.driver.schedule.levels)
    assert proto.driver.dump(54) == proto.driver.schedule.units
    talk(proto, "STOP\n")
    assert not backend.running()


def expected_reply_count(data):
    """Independent count of the lines that must get a reply: complete, not blank."""
    n = 0
    # CR, LF and CRLF end lines alike: normalise to LF (a CRLF is one end)
    for seg in data.replace(b"\r\n", b"\n").replace(b"\r", b"\n").split(b"\n")[:-1]:
        if seg.strip(b" \t") or any(not (0x20 <= b <= 0x7E or b == 9) for b in seg):
            n += 1
    return n


def test_fuzz_random_bytes_split_anywhere():
    rng = np.random.default_rng(2024)
    proto, _ = new_proto()
    ref, _ = new_proto()
    for trial in range(200):
        kind = trial % 4
        if kind == 0:  # arbitrary bytes, newlines sprinkled in
            data = rng.integers(0, 256, size=int(rng.integers(1, 400)), dtype=np.uint8)
            data[rng.random(data.size) < 0.05] = 10
            data = bytes(data)
        elif kind == 1:  # printable garbage, sometimes longer than a line
            data = bytes(rng.integers(32, 127, size=int(rng.integers(1, 200)), dtype=np.uint8))
            data += b"\n"
        elif kind == 2:  # almost-commands
            words = ["ID", "MODE", "RATE", "0x", "S2PSK", "ook", "-3", "99999999", "DUMP",
                     "\t", " ", "SYMCLK", "0xZZ", "\r", "\xff"]
            data = " ".join(rng.choice(words, size=int(rng.integers(1, 5)))).encode("latin-1")
            data += b"\n"
        else:  # non-UTF-8 sequences
            data = bytes([0xC3, 0x28, 0xA0, 0xA1, 0xE2, 0x82, 0x0A])
        before = state(proto)
        cuts = np.sort(rng.integers(0, len(data) + 1, size=3))
        replies = []
        for a, b in zip([0, *cuts], [*cuts, len(data)]):
            replies += proto.feed(data[a:b])
        ref_replies = ref.feed(data)
        assert replies == ref_replies  # split-invariant
        assert len(replies) == expected_reply_count(data)
        for r in replies:
            assert REPLY.match(r), r
        if all(r.startswith("ERR") for r in replies):
            assert state(proto) == before
        assert proto.reader._n <= MAX_LINE
    # Still serving, whatever came before.
    proto.feed(b"\n")
    assert proto.feed(b"PING\n") == ["OK PONG " + VERSION]


def test_every_error_leaves_state_unchanged():
    proto, _ = new_proto()
    talk(proto, "ID 300\nRATE 7000\nSTART\n")
    before = state(proto)
    bad = ["ID 65536", "ID 0x10000", "RATE 0", "RATE 60000", "SYMCLK 0",
           "SYMCLK 1000", "DUMP 5000", "XYZ", "MODE", "ID x", "START 1", "A" * 70]
    for line in bad:
        r = talk(proto, line + "\n")
        assert len(r) == 1 and r[0].startswith("ERR "), line
        assert state(proto) == before, line


def test_linereader_items():
    lr = LineReader(max_line=8)
    assert lr.feed(b"abc\r\ndefghijkl\n\xff\nok") == ["abc", 4, 5]
    assert lr.finish() == ["ok"]


def test_cr_lf_and_crlf_end_lines_alike():
    """Before: a line ended by CR alone got no reply until a LF came (and then ERR 5)."""
    for end in (b"\r", b"\n", b"\r\n"):
        proto, _ = new_proto()
        assert proto.feed(b"PING" + end) == ["OK PONG " + VERSION], end
        assert proto.feed(b"ID 5" + end + b"STATUS" + end) == [
            "OK ID 5", "OK STATUS mode=OOK id=5 rate=20000 symclk=16 running=0"], end
    proto, _ = new_proto()
    # CRLF split between feeds is still one line end; CR CR is an empty line (no reply)
    assert proto.feed(b"PING\r") == ["OK PONG " + VERSION]
    assert proto.feed(b"\nPING\r\r\n\n") == ["OK PONG " + VERSION]
    assert proto.feed(b"ID 5\rX\n") == ["OK ID 5", "ERR 1 unknown command"]
    assert proto.feed(b"Q" * 100 + b"\r\n") == ["ERR 4 line longer than 64 characters"]


def test_mode_always_succeeds_and_each_mode_keeps_its_id():
    """Before: with an OOK ID above 255, MODE S2PSK was refused (ERR 6), so `MODE S2PSK` then
    `ID 42` failed."""
    proto, _ = new_proto()
    assert talk(proto, "ID 4660\nMODE S2PSK\nID 42\nSTATUS\n") == [
        "OK ID 4660", "OK MODE S2PSK", "OK ID 42",
        "OK STATUS mode=S2PSK id=42 rate=200 symclk=16 running=0"]
    ref, _ = new_proto()
    talk(ref, "MODE S2PSK\nID 42\n")
    assert talk(proto, "DUMP 64\n") == talk(ref, "DUMP 64\n")      # the S2-PSK ID on air
    assert talk(proto, "MODE TONE\nSTATUS\nMODE OOK\nSTATUS\nDUMP 54\n")[1:4:2] == [
        "OK STATUS mode=TONE id=0 rate=2000 symclk=16 running=0",
        "OK STATUS mode=OOK id=4660 rate=20000 symclk=16 running=0"]


class _FakeStdin:
    def __init__(self, data):
        self.data = data

    def read(self, n):
        out, self.data = self.data[:n], self.data[n:]
        return out


class _FakePoller:
    def __init__(self, stdin):
        self.stdin = stdin

    def poll(self, timeout_ms):
        return [(self.stdin, 1)] if self.stdin.data else []


def test_board_serve_loop_with_fake_poll():
    proto, _ = new_proto()
    stdin = _FakeStdin(b"PING\n\xff\xffgarbage\nID 5\nSTATUS\n")
    out = []
    board_main.serve(proto, stdin, out.append, _FakePoller(stdin), max_polls=200)
    assert out == ["OK PONG %s\n" % VERSION, "ERR 5 non-ASCII or control characters\n",
                   "OK ID 5\n", "OK STATUS mode=OOK id=5 rate=20000 symclk=16 running=0\n"]
