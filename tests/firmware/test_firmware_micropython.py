"""The firmware runs unchanged on real MicroPython (1.27, WebAssembly under Node.js) and produces
byte-identical packets, schedules, PIO words, virtual edges and protocol replies to CPython,
on the PROTOCOL.md test vectors and on seeded random IDs. One MicroPython process per session."""

import numpy as np
import pytest

from micropython_harness import (MicroPythonError, probe_script, run_cpython,
                                 run_micropython)
from tests.firmware.test_framing import VECTORS  # the PROTOCOL.md table, kept in one place

SESSION = (b"PING\nSTATUS\nID 0xBEEF\nMODE S2PSK\nID 0x2a\r\nmode s2psk\nDUMP 30\n"
           b"RATE 125\nSYMCLK 0x8\nID 256\nSTART\nMODE TONE\n\tdump\t5 \n\n  \nFLY\nID -1\n"
           b"\xff\xfe\nID \xc3\xa9\n" + b"X" * 100 + b"\nMODE OOK\rSTATUS\r\nPI")
SESSION_REPLIES = [
    "OK PONG 1.0.0",
    "OK STATUS mode=OOK id=0 rate=20000 symclk=16 running=0",
    "OK ID 48879",
    "OK MODE S2PSK",  # each mode keeps its own ID
    "OK ID 42",
    "OK MODE S2PSK",
    "OK DUMP 30 111000010110011001100101101010",
    "OK RATE 125",
    "OK SYMCLK 8",
    "ERR 3 id must be 0..255 in s2psk",
    "OK START",
    "OK MODE TONE",
    "OK DUMP 5 10101",
    "ERR 1 unknown command",
    "ERR 2 not a number",
    "ERR 5 non-ASCII or control characters",
    "ERR 5 non-ASCII or control characters",
    "ERR 4 line longer than 64 characters",
    "OK MODE OOK",
    "OK STATUS mode=OOK id=48879 rate=20000 symclk=8 running=1",  # after a CR-only line end
    "ERR 1 unknown command",  # "PI", ended by the newline before the garbage
]


def _inputs():
    rng = np.random.default_rng(271828)
    ook_ids = [v[1] for v in VECTORS if v[0] == "ook"] + [int(x) for x in
                                                         rng.integers(0, 65536, 200)]
    s2_ids = list(range(256))  # all of them: cheap even in MicroPython
    configs = [("ook", 0xBEEF, 20000, 16), ("ook", int(rng.integers(0, 65536)), 3000, 16),
               ("ook", 42, 7000, 16), ("s2psk", 0x2A, 200, 16), ("s2psk", 0x81, 125, 3),
               ("s2psk", int(rng.integers(0, 256)), 333, 1), ("tone", 0, 2000, 16),
               ("tone", 0, 137, 16)]
    # The scripted session, plus seeded garbage, cut into random pieces.
    garbage = bytes(rng.integers(0, 256, 3000, dtype=np.uint8))
    data = SESSION + b"\n" + garbage + b"\nPING\n"
    cuts = np.sort(rng.choice(len(data), size=60, replace=False))
    chunks = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)])]
    return ook_ids, s2_ids, configs, chunks


@pytest.fixture(scope="module")
def outputs():
    script = probe_script(*_inputs())
    return run_micropython(script).splitlines(), run_cpython(script).splitlines()


def test_micropython_output_is_byte_identical_to_cpython(outputs):
    mpy, cpy = outputs
    assert mpy[-1] == "done"
    assert len(mpy) == len(cpy)
    for i, (a, b) in enumerate(zip(mpy, cpy)):
        assert a == b, "line %d differs:\nMicroPython %s\nCPython     %s" % (i, a[:200], b[:200])


def test_micropython_vectors_and_crc_check_values(outputs):
    mpy, _ = outputs
    assert "crc 244 14" in mpy  # 0xF4, 0xE over "123456789"
    for mode, led_id, crc, packet in VECTORS:
        assert "%s %d %d %s" % (mode, led_id, crc, packet) in mpy


def test_micropython_schedules_are_the_true_waveform(outputs):
    mpy, _ = outputs
    sched = [line.split() for line in mpy if line.startswith("sched ")]
    assert len(sched) == 8
    for _, mode, led_id, rate, symclk, tick_hz, npins, levels, levels_into, dump in sched:
        assert levels == levels_into
        if mode == "s2psk":
            sym = VECTORS[4][3] if int(led_id) == 0x2A else None
            assert tick_hz == str(2 * int(rate)) and npins == "2"
            k = 2 * int(symclk)
            # Pin A is the clock (1 then 0 per period); A XOR B is the symbol held k ticks.
            a = [int(c) & 1 for c in levels]
            xor = [(int(c) & 1) ^ (int(c) >> 1) for c in levels]
            assert a == [1, 0] * (len(levels) // 2)
            syms = "".join(str(xor[j]) for j in range(0, len(levels), k))
            assert all(len(set(xor[j:j + k])) == 1 for j in range(0, len(levels), k))
            assert dump.startswith(syms)
            if sym:
                assert syms == sym
        elif mode == "ook":
            assert tick_hz == rate and levels == dump[:54]
        else:
            assert levels == "10" and dump == "10" * 35


def test_micropython_protocol_session(outputs):
    mpy, _ = outputs
    replies = [line[len("reply "):] for line in mpy if line.startswith("reply ")]
    assert replies[:len(SESSION_REPLIES)] == SESSION_REPLIES
    assert replies[-1] == "OK PONG 1.0.0"  # still serving after 3000 random bytes
    for r in replies:
        assert r.startswith("OK ") or r[:6] in ("ERR 1 ", "ERR 2 ", "ERR 3 ", "ERR 4 ",
                                                "ERR 5 ", "ERR 6 ")


def test_micropython_board_serve_loop(outputs):
    mpy, _ = outputs
    assert [line for line in mpy if line.startswith("board ")] == [
        "board OK PONG 1.0.0", "board ERR 5 non-ASCII or control characters",
        "board OK MODE TONE", "board ERR 3 rate must be 100..25000 Hz in tone",
        "board OK RATE 1000", "board OK STATUS mode=TONE id=0 rate=1000 symclk=16 running=0"]


def test_harness_fails_when_micropython_raises():
    # The package's own CLI exits 0 on an exception; ours must not.
    with pytest.raises(MicroPythonError, match="ZeroDivisionError"):
        run_micropython("import sys\nprint(sys.implementation.name)\n1 // 0\n")
    assert run_micropython("import sys\nprint(sys.implementation.name)\n") == "micropython\n"
