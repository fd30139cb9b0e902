"""Every load figure of the lighting server in one command: `python -m receiver.serve.loadgen
--suite [--runs N]`. One JSON line per figure and run, then (with several runs) one line of
each figure's medians; the runs alternate the figures (A B C D A B C D ...), so a stretch of
other work on a shared machine does not fall on one figure alone. Each figure starts its own
servers; only position replies count as served (`receiver.serve.loadgen.run_load`).

  rate_10k     4-LED datagrams of 50 devices at 10,000/s for 3 s to one process (one core);
  p99_5k       the same at 5,000/s: the reply latency percentiles;
  devices_10k  10,000 devices at 1 datagram/s each (10,000/s), from 157 source addresses
               (127.0.1.x ...: at most 64 devices per address, the server's default quota), with
               the server's default per-source limits; `held` is the devices the server holds at
               the end (its summary). The devices' first datagrams (cold solves, ~1.6 ms each)
               go first, 16 awaiting their reply at a time, which takes longer than the default
               `--forget-s`: the server gets `--forget-s 60`;
  scale        `occloc serve --state redis://... --reuse-port` on one port, one process then
               two, offered `SCALE_RATE`/s from 16 source ports (SO_REUSEPORT spreads them):
               position replies/s of each and their ratio; also one process without Redis at
               the same offer. The generator and redis-server run on the same cores;
  flood        one honest device at 30 frames/s while four other addresses (127.0.0.2-5) send
               50,000 valid 64-LED datagrams at 10,000/s (from a process of their own), to a
               server with its default limits: the honest device's reply latency;
  v2           the server's CPU time per v2 datagram (outlines and edge points) of the walk
               recording, as `occloc run recordings/indoor-walk --server` sends them.

Each line carries the machine's CPU count and 1-minute load average before and after: a load
above the CPU count means other processes competed for the cores, and rates and latencies then
say little (the servers' CPU time per reply says more).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from receiver.serve.loadcore import (DEFAULT_MAP, ROOT, SERVER_ARGS, WARMUP_WINDOW, four_led_datagrams, median_report,
                                    one_run, open_socket, process_cpu_s, run_load, source_socks, start_server,
                                    stop_server, warm_up)
from receiver.serve.server import DEFAULT_MAX_DEVICES_PER_SOURCE

# devices_10k: devices, datagrams/s, s, devices per source address (the server's default quota),
# reply window of the warm-up, the server's --forget-s.
DEVICES = 10000
DEVICES_RATE = 10000.0
DEVICES_S = 3.0
DEVICES_PER_SOURCE = DEFAULT_MAX_DEVICES_PER_SOURCE
DEVICES_FORGET_S = 60.0
# scale: offered datagrams/s (above what one process serves), s, devices, source ports.
SCALE_RATE = 24000.0
SCALE_S = 3.0
SCALE_DEVICES = 64
SCALE_SOCKETS = 16
# flood: the honest device's frames/s; the flood's datagrams, rate, sources, LEDs per datagram.
HONEST_RATE = 30.0
FLOOD_TOTAL = 50000
FLOOD_RATE = 10000.0
FLOOD_SOURCES = 4
FLOOD_LEDS = 64
FIGURES = ("rate_10k", "p99_5k", "devices_10k", "scale", "flood", "v2")


def _machine(report: dict, load0: float) -> dict:
    report.update(cpus=os.cpu_count(), loadavg_before=round(load0, 2), loadavg_after=round(os.getloadavg()[0], 2))
    return report


def fig_rate(led_map, rate: float, seconds: float = 3.0, devices: int = 50) -> dict:
    """`rate` datagrams/s of `devices` devices to one fresh server (`loadgen.one_run`)."""
    dg = four_led_datagrams(led_map, int(rate * seconds) + devices, devices)
    return one_run(None, dg[devices:], rate, dg[:devices])


def fig_devices(led_map, devices: int = DEVICES, rate: float = DEVICES_RATE, seconds: float = DEVICES_S) -> dict:
    """`devices` devices held at once: their first datagrams (windowed warm-up), then `rate`/s
    for `seconds`; the server's count of devices held at the end."""
    load0 = os.getloadavg()[0]
    dg = four_led_datagrams(led_map, int(rate * seconds) + devices, devices)
    proc, address = start_server(("--forget-s", f"{DEVICES_FORGET_S:g}"))
    summary = ""
    try:
        socks = source_socks(address, -(-devices // DEVICES_PER_SOURCE))
        t0 = time.monotonic()
        warmed = warm_up(address, dg[:devices], socks=socks, window=WARMUP_WINDOW)
        warm_s = time.monotonic() - t0
        cpu0 = process_cpu_s(proc.pid)
        report = run_load(address, dg[devices:], rate, socks=socks)
        cpu1 = process_cpu_s(proc.pid)
    finally:
        summary = stop_server(proc)
    held = summary.split(" forgotten, ")[1].split(" held")[0] if " held" in summary else None
    report.update(devices=devices, sources=len(socks), warmup_replies=warmed, warmup_s=round(warm_s, 1),
                  held=None if held is None else int(held), server_summary=summary)
    if cpu0 is not None and cpu1 is not None and report["replies"]:
        report["server_cpu_ms_per_reply"] = round((cpu1 - cpu0) * 1e3 / report["replies"], 3)
    return _machine(report, load0)


class _Redis:
    """redis-server on a free loopback port, in a temporary folder, for one figure."""

    def __init__(self):
        exe = shutil.which("redis-server")
        if exe is None:
            raise RuntimeError("no redis-server on PATH (tools/dev installs it)")
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.dir = tempfile.TemporaryDirectory()
        self.proc = subprocess.Popen([exe, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
                                      "--appendonly", "no", "--dir", self.dir.name],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while True:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1) as c:
                    c.sendall(b"PING\r\n")
                    if c.recv(16).startswith(b"+PONG"):
                        break
            except OSError:
                pass
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.close()
                raise RuntimeError("redis-server did not start")
            time.sleep(0.05)
        self.url = f"redis://127.0.0.1:{self.port}/0"

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        self.dir.cleanup()


def _scale_one(led_map, n_procs: int, redis_url: str | None, rate: float, seconds: float) -> dict:
    """`n_procs` servers on one port (with Redis: `--state --reuse-port`), offered `rate`/s of
    SCALE_DEVICES devices from SCALE_SOCKETS source ports; the servers' CPU per reply."""
    devices = SCALE_DEVICES
    dg = four_led_datagrams(led_map, int(rate * seconds) + devices, devices)
    args = SERVER_ARGS + (("--state", redis_url, "--reuse-port") if redis_url else ())
    procs = []
    try:
        proc, address = start_server(args)
        procs.append(proc)
        for _ in range(n_procs - 1):
            procs.append(start_server(args, port=address[1])[0])
        socks = [open_socket(address) for _ in range(SCALE_SOCKETS)]
        warm_up(address, dg[:devices], socks=socks, window=WARMUP_WINDOW)
        cpu0 = [process_cpu_s(p.pid) for p in procs]
        report = run_load(address, dg[devices:], rate, socks=socks)
        cpu1 = [process_cpu_s(p.pid) for p in procs]
    finally:
        summaries = [stop_server(p) for p in procs]
    report["processes"] = n_procs
    report["redis"] = bool(redis_url)
    report["datagrams_per_process"] = [int(s.split()[2]) if s else None for s in summaries]
    if None not in cpu0 and None not in cpu1 and report["replies"]:
        report["server_cpu_ms_per_reply"] = round(sum(b - a for a, b in zip(cpu0, cpu1)) * 1e3 / report["replies"], 3)
    return report


def fig_scale(led_map, rate: float = SCALE_RATE, seconds: float = SCALE_S) -> dict:
    """Two processes against one on one port (Redis-shared state, SO_REUSEPORT), and one
    process without Redis, all offered `rate`/s: position replies/s and the two-to-one ratio."""
    load0 = os.getloadavg()[0]
    redis = _Redis()
    try:
        one = _scale_one(led_map, 1, redis.url, rate, seconds)
        two = _scale_one(led_map, 2, redis.url, rate, seconds)
    finally:
        redis.close()
    embedded = _scale_one(led_map, 1, None, rate, seconds)
    keep = ("replies", "replies_per_s", "lost", "p50_ms", "p99_ms", "errors", "server_cpu_ms_per_reply",
            "datagrams_per_process")
    report = {"offered_per_s": rate, "seconds": seconds,
              "one_redis": {k: one.get(k) for k in keep}, "two_redis": {k: two.get(k) for k in keep},
              "one_embedded": {k: embedded.get(k) for k in keep},
              "two_over_one": round(two["replies_per_s"] / one["replies_per_s"], 2) if one["replies_per_s"] else None}
    return _machine(report, load0)


def _flood_sender(address, floods, rate: float, out) -> None:
    """A child process: `floods` (one datagram list per source, sent from 127.0.0.2, .3, ...)
    interleaved at `rate`/s in all; replies are only counted (position / other)."""
    socks = [open_socket(address, f"127.0.0.{2 + k}") for k in range(len(floods))]
    for s in socks:
        s.setblocking(False)
    order = [(k, data) for group in zip(*floods) for k, (_, _, data) in enumerate(group)]
    positions = others = 0

    def drain():
        nonlocal positions, others
        for s in socks:
            while True:
                try:
                    data = s.recv(65536)
                except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                    break
                if b'"position":{' in data:
                    positions += 1
                else:
                    others += 1
    start = time.monotonic()
    i = 0
    while i < len(order):
        due = min(len(order), int((time.monotonic() - start) * rate) + 1)
        while i < due:
            k, data = order[i]
            try:
                socks[k].send(data)
            except (BlockingIOError, ConnectionRefusedError):
                pass
            i += 1
        drain()
        time.sleep(0.0005)
    send_s = time.monotonic() - start
    time.sleep(0.5)
    drain()
    out.send({"sent": len(order), "send_s": round(send_s, 3), "position_replies": positions,
              "other_replies": others})
    out.close()


def fig_flood(led_map, total: int = FLOOD_TOTAL, rate: float = FLOOD_RATE, *, sources: int = FLOOD_SOURCES,
              leds: int = FLOOD_LEDS, honest_rate: float = HONEST_RATE, honest_devices: int = 1,
              address=None) -> dict:
    """An honest device's reply latency while `sources` other addresses send `total` valid
    `leds`-LED datagrams at `rate`/s, to a server with its default limits (started here unless
    `address` is given): `honest_devices` devices at `honest_rate` datagrams/s in all."""
    load0 = os.getloadavg()[0]
    per_source = total // sources
    floods = [four_led_datagrams(led_map, per_source, 64, seed=1 + k, n_leds=leds, prefix=f"flood{k}-")
              for k in range(sources)]
    n_honest = max(1, int(honest_rate * total / rate))
    honest = four_led_datagrams(led_map, n_honest + honest_devices, honest_devices, prefix="honest-")
    proc = None
    if address is None:
        proc, address = start_server(())
    cpu0 = cpu1 = None
    summary = ""
    try:
        sock = open_socket(address)
        warm_up(address, honest[:honest_devices], sock)
        cpu0 = None if proc is None else process_cpu_s(proc.pid)
        ctx = multiprocessing.get_context("fork")
        recv_end, send_end = ctx.Pipe(duplex=False)
        child = ctx.Process(target=_flood_sender, args=(address, floods, rate, send_end), daemon=True)
        child.start()
        send_end.close()
        report = run_load(address, honest[honest_devices:], honest_rate, sock=sock)
        flood = recv_end.recv() if recv_end.poll(120) else None
        child.join(30)
        cpu1 = None if proc is None else process_cpu_s(proc.pid)
    finally:
        if proc is not None:
            summary = stop_server(proc)
    out = {"honest": report, "flood": flood, "server_summary": summary,
           "server_cpu_s": None if cpu0 is None or cpu1 is None else round(cpu1 - cpu0, 2)}
    return _machine(out, load0)


def fig_v2(recording=None, passes: int = 5) -> dict:
    """Server CPU per v2 datagram (outlines and edge points): the datagrams `occloc run
    RECORDING --server` sends (the bundled walk by default; captured by a server in this
    process), handled in order by a fresh warmed-up server, `passes` times: the median over
    passes of the CPU ms per datagram, whole and the parse alone (`wire_v2.parse_any`)."""
    from receiver.io.ledmap import load_map
    from receiver.serve.server import BackgroundServer, LightingServer
    from receiver.serve.wire_v2 import parse_any

    load0 = os.getloadavg()[0]
    rec = Path(recording) if recording is not None else DEFAULT_MAP.parent
    led_map = load_map(str(rec / "map.json"))
    captured: list[bytes] = []

    class Capture(LightingServer):
        def handle_datagrams(self, datagrams):
            captured.extend(data for data, _ in datagrams)
            return super().handle_datagrams(datagrams)

    with BackgroundServer(Capture(led_map)) as bg, tempfile.TemporaryDirectory() as tmp:
        run = subprocess.run([sys.executable, "-m", "receiver.cli", "run", str(rec), "--server", bg.url,
                              "--server-timeout", "30", "--out", str(Path(tmp) / "run.jsonl")],
                             cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if run.returncode != 0 or not captured:
        raise RuntimeError(f"occloc run --server failed: {run.stderr.strip().splitlines()[-1:]}")
    whole, parse = [], []
    for _ in range(passes):
        srv = LightingServer(led_map, source_rate=0)
        srv.warm_up()
        t0 = time.thread_time()
        for data in captured:
            srv.handle_datagram(data, ("127.0.0.1", 1))
        whole.append((time.thread_time() - t0) * 1e3 / len(captured))
        t0 = time.thread_time()
        for data in captured:
            parse_any(data)
        parse.append((time.thread_time() - t0) * 1e3 / len(captured))
    return _machine({"recording": rec.name, "datagrams": len(captured), "bytes_max": max(map(len, captured)),
                     "positions": srv.counters["positions"], "cpu_ms_per_datagram": round(float(np.median(whole)), 3),
                     "parse_ms_per_datagram": round(float(np.median(parse)), 3), "passes": passes}, load0)


def _flat(report: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in report.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def run_suite(led_map, runs: int = 1, figures=FIGURES, emit=print) -> dict:
    """Each figure `runs` times, alternating; `emit` gets each run's JSON line and, with several
    runs, each figure's medians; returns {figure: [reports]}."""
    makers = {"rate_10k": lambda: fig_rate(led_map, 10000.0), "p99_5k": lambda: fig_rate(led_map, 5000.0),
              "devices_10k": lambda: fig_devices(led_map), "scale": lambda: fig_scale(led_map),
              "flood": lambda: fig_flood(led_map), "v2": lambda: fig_v2()}
    out: dict = {f: [] for f in figures}
    for r in range(runs):
        for f in figures:
            try:
                report = makers[f]()
            except (RuntimeError, OSError) as e:
                report = {"error": str(e)}
            out[f].append(report)
            emit(json.dumps({"figure": f, "run": r + 1, **report}))
    if runs > 1:
        for f in figures:
            emit(json.dumps({"figure": f, **median_report([_flat(x) for x in out[f]])}))
    return out


def suite_main(a) -> int:
    from receiver.io.ledmap import load_map

    if a.runs <= 0:
        print("loadgen: --runs must be positive", file=sys.stderr)
        return 2
    figures = tuple(a.figures.split(",")) if a.figures else FIGURES
    unknown = [f for f in figures if f not in FIGURES]
    if unknown:
        print(f"loadgen: unknown figure {unknown[0]!r} (one of {', '.join(FIGURES)})", file=sys.stderr)
        return 2
    run_suite(load_map(a.map), a.runs, figures)
    return 0

