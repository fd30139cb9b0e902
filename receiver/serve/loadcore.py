"""The load generator's parts (datagrams, sockets, the open-loop sender, server start/stop,
medians), shared by `python -m receiver.serve.loadgen` and its figure suite
(receiver.serve.loadsuite); the generator's method is described in receiver.serve.loadgen.
"""

from __future__ import annotations

import json
import os
import re
import selectors
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from receiver.serve.server import DEFAULT_MAX_DEVICES_PER_SOURCE
from receiver.serve.wire import encode, make_request
ROOT = Path(__file__).resolve().parents[2]
DEFAULT_MAP = ROOT / "recordings" / "indoor-walk" / "map.json"
SIGMA_UV = 3e-4
SIGMA_M = 0.002
# Longest wait for a warm-up datagram's reply (s), and the warm-up's datagrams awaiting a reply
# at once (the server's batch: receiver.serve.server.MAX_BATCH).
WARMUP_WAIT_S = 5.0
WARMUP_WINDOW = 16


def four_led_datagrams(led_map, n: int, devices: int, seed: int = 0, n_leds: int = 4,
                       prefix: str = "load-") -> list[tuple[str, int, bytes]]:
    """n encoded requests of `n_leds` LEDs each (4: a 2 x 2 block of panels; more: the nearest
    ones), round robin over `devices` devices named `prefix` + index: (device, seq, datagram)."""
    from receiver.locate.pose import ypr_to_rotation
    rng = np.random.default_rng(seed)
    leds = list(led_map.leds.values())
    xyz = np.array([led.xyz for led in leds])
    R = ypr_to_rotation(10.0, 88.0, 2.0)
    # the map's distinct x and y values (in set order: ties in distance go as a sort of the set would)
    grid = [np.array(list(set(xyz[:, a]))) for a in (0, 1)]
    mean_xy = xyz[:, 0].mean(), xyz[:, 1].mean()
    out = []
    for k in range(n):
        dev, seq = k % devices, k // devices
        C = np.array([mean_xy[0] + 0.3 * np.sin(0.01 * seq + dev), mean_xy[1] + 0.3 * np.cos(0.01 * seq + dev), 1.0])
        if n_leds == 4:
            # the two nearest grid columns and rows (a stable sort: the first of equal distances)
            cols = [g[np.argsort(np.abs(g - C[a]), kind="stable")[:2]] for a, g in enumerate(grid)]
            near = np.flatnonzero(((xyz[:, 0] == cols[0][0]) | (xyz[:, 0] == cols[0][1]))
                                  & ((xyz[:, 1] == cols[1][0]) | (xyz[:, 1] == cols[1][1])))[:4]
        else:
            near = np.argsort(np.linalg.norm(xyz[:, :2] - C[:2], axis=1))[:n_leds]
        L = xyz[near]
        Xc = (L - C) @ R.T
        uv = Xc[:, :2] / Xc[:, 2:] + rng.normal(0, 1e-4, (len(L), 2))
        d = np.linalg.norm(L - C, axis=1) + rng.normal(0, 1e-3, len(L))
        name = f"{prefix}{dev}"
        req = make_request(name, seq, seq / 30.0, SIGMA_UV, [leds[i].id for i in near], uv, d,
                           np.full(len(L), SIGMA_M))
        out.append((name, seq, encode(req)))
    return out


def open_socket(address: tuple[str, int], source: str | None = None) -> socket.socket:
    """A UDP socket connected to `address` (bound to `source` when given). One socket per
    generator: the server binds an unkeyed device's name to its first (host, port)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    if source is not None:
        sock.bind((source, 0))
    sock.connect(address)
    return sock


# A position reply's head as the server writes it (`LightingServer._reply_json`, `wire.encode`):
# device, seq, and the first byte of the position (n: null). Other replies are read as JSON.
_REPLY_HEAD = re.compile(rb'\{"v":\d+,"device":"([^"\\]*)","seq":(\d+),"position":(.)')


def read_reply(data: bytes) -> tuple[str, object, object]:
    """(kind, device, seq) of a reply: kind "position", "no_position", an error's reason, or
    "unreadable". Position replies are recognised by their head (`_REPLY_HEAD`) without a full
    JSON parse: the generator shares the machine with the server it measures."""
    m = _REPLY_HEAD.match(data)
    if m is not None:
        return ("no_position" if m[3] == b"n" else "position"), m[1].decode(), int(m[2])
    try:
        rep = json.loads(data)
    except ValueError:
        return "unreadable", None, None
    if not isinstance(rep, dict):
        return "unreadable", None, None
    if "error" in rep:
        return str(rep["error"]), rep.get("device"), rep.get("seq")
    return ("no_position" if rep.get("position") is None else "position"), rep.get("device"), rep.get("seq")


def run_load(address: tuple[str, int], datagrams, rate: float, drain_s: float = 1.0,
             source: str | None = None, sock: socket.socket | None = None, socks=None) -> dict:
    """Send `datagrams` ((device, seq, bytes)) to `address` at `rate` per second (from the
    address `source`, default any), then wait up to `drain_s` for the replies still missing; the
    report. Only replies with a position count as served (`replies`, the latencies); error
    replies are counted by reason (`errors`), replies without a position in `no_position`, and
    `lost` is every datagram without a position reply. `sock`: the socket to use (`open_socket`;
    closed at the end), else one of its own; `socks`: several (closed at the end), a device's
    datagrams all from one of them (round robin in the order devices first appear)."""
    if socks is None:
        socks = [open_socket(address, source) if sock is None else sock]
    sent_at: dict[tuple[str, int], float] = {}
    lat: list[float] = []
    errors: dict[str, int] = {}
    no_position = [0]
    done = threading.Event()
    last_reply = [0.0]
    sel = selectors.DefaultSelector()
    for s in socks:
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ)

    def receive():
        while not done.is_set():
            for key, _ in sel.select(0.05):
                while True:
                    try:
                        data = key.fileobj.recv(65536)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        break
                    now = time.monotonic()
                    kind, dev, seq = read_reply(data)
                    if kind == "position":
                        t0 = sent_at.get((dev, seq))
                        if t0 is not None:
                            lat.append(now - t0)
                            last_reply[0] = now
                    elif kind == "no_position":
                        no_position[0] += 1
                    else:
                        errors[kind] = errors.get(kind, 0) + 1
    rx = threading.Thread(target=receive, daemon=True)
    rx.start()
    owner: dict[str, socket.socket] = {}
    out = [owner.setdefault(dev, socks[len(owner) % len(socks)]) for dev, _, _ in datagrams]
    start = time.monotonic()
    k = 0
    while k < len(datagrams):
        due = min(len(datagrams), int((time.monotonic() - start) * rate) + 1)
        while k < due:
            dev, seq, data = datagrams[k]
            sent_at[(dev, seq)] = time.monotonic()
            try:
                out[k].send(data)
            except (BlockingIOError, ConnectionRefusedError):
                pass                                  # a full send buffer or no server: lost
            k += 1
        time.sleep(0.0005)
    send_s = time.monotonic() - start
    drain_end = time.monotonic() + drain_s      # wait for the last replies, at most drain_s
    while len(lat) + no_position[0] + sum(errors.values()) < len(datagrams) and time.monotonic() < drain_end:
        time.sleep(0.01)
    done.set()
    rx.join(5.0)
    sel.close()
    for s in socks:
        s.close()
    ms = np.array(lat) * 1e3
    span = (last_reply[0] - start) if len(lat) else float("nan")
    return {"sent": len(datagrams), "send_s": round(send_s, 3), "replies": len(lat),
            "lost": len(datagrams) - len(lat), "replies_per_s": round(len(lat) / span, 1) if len(lat) else 0.0,
            "p50_ms": round(float(np.percentile(ms, 50)), 3) if len(ms) else None,
            "p99_ms": round(float(np.percentile(ms, 99)), 3) if len(ms) else None,
            "max_ms": round(float(ms.max()), 3) if len(ms) else None,
            "errors": errors, "no_position": no_position[0]}


def warm_up(address: tuple[str, int], datagrams, sock: socket.socket | None = None, *, socks=None,
            window: int = 1, wait_s: float = WARMUP_WAIT_S) -> int:
    """Send `datagrams` ((device, seq, bytes)) with at most `window` of them awaiting their reply
    (a reply, or `wait_s` without any, frees the window); the position replies received.
    Before a timed load, the devices' first datagrams: a device's first datagram is solved from
    scratch (PnP, and both handednesses of a map that does not declare it: ~1.6 ms of CPU against
    ~0.1 ms warm), so 50 devices starting together put ~80 ms of backlog in front of the first
    timed replies. `sock` / `socks`: as `run_load`'s (the same assignment of devices to
    sockets when the datagrams name the devices in the same order; not closed here)."""
    own = sock is None and socks is None
    socks = socks if socks is not None else [sock if sock is not None else open_socket(address)]
    owner: dict[str, socket.socket] = {}
    sel = selectors.DefaultSelector()
    for s in socks:
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ)
    got = pending = k = 0
    try:
        while k < len(datagrams) or pending:
            while k < len(datagrams) and pending < window:
                dev, _, data = datagrams[k]
                try:
                    owner.setdefault(dev, socks[len(owner) % len(socks)]).send(data)
                except (BlockingIOError, ConnectionRefusedError):
                    pass
                pending, k = pending + 1, k + 1
            events = sel.select(wait_s)
            if not events:
                pending = 0                           # those are lost
                continue
            for key, _ in events:
                while pending:
                    try:
                        data = key.fileobj.recv(65536)
                    except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                        break
                    pending -= 1
                    got += read_reply(data)[0] == "position"
    finally:
        sel.close()
        if own:
            socks[0].close()
    return got


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process `pid` so far (Linux /proc), or None."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


# The server started here serves one source address at any rate (the load comes from one
# socket; the per-source limit is for the flood figure: `--flood-rate`).
SERVER_ARGS = ("--source-rate", "0")


def start_server(args=SERVER_ARGS, port: int = 0) -> tuple[subprocess.Popen, tuple[str, int]]:
    """`occloc serve --port PORT ARGS` as a subprocess, once ready: (process, (host, port))."""
    proc = subprocess.Popen([sys.executable, "-m", "receiver.cli", "serve", "--port", str(port), *args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    if "listening on udp://" not in line:
        proc.kill()
        proc.wait(10)
        raise RuntimeError(f"occloc serve did not start: {line.strip()}")
    proc.stderr.readline()                      # "occloc serve: ready"
    host, port = line.split("udp://")[1].strip().rsplit(":", 1)
    return proc, (host, int(port))


def stop_server(proc: subprocess.Popen) -> str:
    """SIGTERM `proc` (from `start_server`) and wait; its summary line (devices held, counters),
    or "" when it had to be killed."""
    proc.terminate()
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:         # still working through a backlog
        proc.kill()
        proc.communicate(timeout=10)
        return ""
    lines = [x for x in err.splitlines() if x.startswith("occloc serve: ") and "datagrams" in x]
    return lines[-1] if lines else ""


def source_socks(address: tuple[str, int], n: int) -> list[socket.socket]:
    """n sockets connected to `address`, each bound to a source address of its own (127.0.1.1,
    127.0.1.2, ... on the loopback network): a server holds at most --max-devices-per-source
    devices of one address."""
    if not 0 < n <= 250 * 250:
        raise ValueError(f"source addresses: 1..62500, not {n}")
    return [open_socket(address, f"127.0.{1 + k // 250}.{1 + k % 250}") for k in range(n)]


def one_run(address, datagrams, rate: float, warmup=()) -> dict:
    """`run_load` against `address`, or a server started for this run (then with its CPU time
    per reply); with the machine's 1-minute load average before and after (`os.getloadavg`) and
    its CPU count, which say whether other work competed for the cores. More devices than the
    server's default per-address quota come from several source addresses (`source_socks`);
    the warm-up keeps WARMUP_WINDOW datagrams awaiting their reply."""
    proc = None
    if not address:
        proc, address = start_server()
    try:
        devices = len({dev for dev, _, _ in (warmup or datagrams)})
        per_source = DEFAULT_MAX_DEVICES_PER_SOURCE
        socks = source_socks(address, -(-devices // per_source)) if devices > per_source else [open_socket(address)]
        warmed = warm_up(address, warmup, socks=socks, window=WARMUP_WINDOW)
        load0 = os.getloadavg()[0]
        cpu0 = None if proc is None else process_cpu_s(proc.pid)
        report = run_load(address, datagrams, rate, socks=socks)
        report.update(warmup=len(warmup), warmup_replies=warmed, sources=len(socks))
        cpu1 = None if proc is None else process_cpu_s(proc.pid)
        if cpu0 is not None and cpu1 is not None and report["replies"]:
            report["server_cpu_ms_per_reply"] = round((cpu1 - cpu0) * 1e3 / report["replies"], 3)
        report.update(loadavg_before=round(load0, 2), loadavg_after=round(os.getloadavg()[0], 2),
                      cpus=os.cpu_count())
        return report
    finally:
        if proc is not None:
            stop_server(proc)


def median_report(reports: list[dict]) -> dict:
    """The median of each number over the runs (`"median_of": runs`)."""
    out = {"median_of": len(reports)}
    for key, value in reports[0].items():
        values = [r.get(key) for r in reports]
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
            out[key] = float(np.median(values))
    return out
