"""Run the same Python code in real MicroPython (WebAssembly, via tools/mpy/run.mjs) and in
CPython, with the `firmware_tx` package importable in both, and return their stdout."""

import pathlib
import shutil
import subprocess
import sys

REPO = pathlib.Path(__file__).resolve().parents[1]
RUNNER = REPO / "tools" / "mpy" / "run.mjs"
PACKAGE = REPO / "firmware_tx"
TIMEOUT_S = 120


class MicroPythonError(AssertionError):
    """The MicroPython run raised or the harness failed; message holds its stderr."""


def node_binary():
    node = shutil.which("node")
    if node is None:
        raise MicroPythonError("node is not installed: the MicroPython proof cannot run")
    return node


def run_micropython(code, timeout_s=TIMEOUT_S):
    """stdout of `code` run by MicroPython; MicroPythonError when it raises."""
    proc = subprocess.run([node_binary(), str(RUNNER), "--pkg", str(PACKAGE), "-"],
                          input=code.encode(), capture_output=True, timeout=timeout_s)
    if proc.returncode != 0:
        raise MicroPythonError("MicroPython run failed (exit %d): %s"
                               % (proc.returncode, proc.stderr.decode(errors="replace")))
    return proc.stdout.decode()


def run_cpython(code, timeout_s=TIMEOUT_S):
    """stdout of `code` run by this CPython in a fresh process, repo on the path."""
    proc = subprocess.run([sys.executable, "-"], input=code.encode(), capture_output=True,
                          timeout=timeout_s, cwd=REPO)
    if proc.returncode != 0:
        raise AssertionError("CPython run failed: " + proc.stderr.decode(errors="replace"))
    return proc.stdout.decode()


def probe_script(ook_ids, s2psk_ids, configs, chunks, edge_window_us=20000):
    """Python source (MicroPython-compatible) printing packets, schedules, PIO words, virtual
    pin edges and protocol replies, one fact per line, for byte-wise comparison."""
    return PROBE_TEMPLATE % dict(ook=list(ook_ids), s2=list(s2psk_ids), configs=list(configs),
                                 chunks=list(chunks), window=edge_window_us)


PROBE_TEMPLATE = '''
from firmware_tx.crc import crc4, crc8, crc_bytes
from firmware_tx.framing import ook_packet, s2psk_packet, to_str
from firmware_tx.schedule import MAX_LEVELS, make_schedule, schedule_into
from firmware_tx.rp2_pio import pack_levels, pio_plan
from firmware_tx.pins import VirtualBackend, VirtualPin, run_virtual
from firmware_tx.driver import Driver
from firmware_tx.protocol import Protocol


def lv(b):
    return "".join("%%d" %% x for x in b)


print("crc", crc_bytes(b"123456789", 0x07, 8), crc_bytes(b"123456789", 0x3, 4))
for i in %(ook)r:
    print("ook", i, crc8(i), to_str(ook_packet(i)))
for i in %(s2)r:
    print("s2psk", i, crc4(i), to_str(s2psk_packet(i)))
buf = bytearray(MAX_LEVELS)
for mode, i, rate, symclk in %(configs)r:
    s = make_schedule(mode, i, rate, symclk)
    t = schedule_into(mode, i, rate, symclk, buf)
    print("sched", mode, i, rate, symclk, s.tick_hz, s.npins, lv(s.levels), lv(t.levels),
          to_str(s.dump(70)))
    r, c, f = pio_plan(s.tick_hz)
    w = pack_levels(s.levels, s.npins, r)
    print("pio", r, c, f, " ".join("%%08x" %% x for x in w))
    pins = [VirtualPin(), VirtualPin()]
    run_virtual(s, pins, 777, 777 + %(window)d)
    for k in range(s.npins):
        print("edges", k, ",".join("%%d:%%d" %% e for e in pins[k].edges))
proto = Protocol(Driver(VirtualBackend([VirtualPin(), VirtualPin()])))
for chunk in %(chunks)r:
    for r in proto.feed(chunk):
        print("reply", r)
for r in proto.finish():
    print("reply", r)


class FakeStdin:
    def __init__(self, data):
        self.data = data

    def read(self, n):
        out = self.data[:n]
        self.data = self.data[n:]
        return out


class FakePoller:
    def __init__(self, stdin):
        self.stdin = stdin

    def poll(self, timeout_ms):
        return [(self.stdin, 1)] if self.stdin.data else []


from firmware_tx import main as board

stdin = FakeStdin(b"PING\\n\\xff\\nMODE TONE\\nRATE 0x10\\nRATE 1000\\nSTATUS\\n")
board.serve(Protocol(Driver(VirtualBackend([VirtualPin()]))), stdin,
            lambda s: print("board", s.rstrip("\\n")), FakePoller(stdin), max_polls=500)
print("done")
'''
