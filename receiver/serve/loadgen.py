"""Load generator for the lighting server (datagrams/s per process and the reply
latency under that load), over UDP: `python -m receiver.serve.loadgen [udp://HOST:PORT]
--rate R --seconds S`. Without a URL it starts `occloc serve --port 0` as a subprocess (its own
process, so the generator does not share its interpreter).

Requests: `devices` devices, each walking slowly under a 2 x 2 block of the map's ceiling LEDs
(four LEDs per datagram, pinhole image points and ranges with small noise), sent open loop at
`rate` datagrams/s (paced in bursts of at most 1 ms). Replies are matched to their requests by
(device, seq); the latency is send -> reply on this machine's monotonic clock. Report: sent,
replies, achieved replies/s, lost (no reply within `drain_s` after the last send), latency
p50 / p99 / max in ms; with the server started here on Linux also the server process's CPU
time per reply (`server_cpu_ms_per_reply`, /proc: user + system while the load ran), which a
machine shared with other work inflates far less than the rates and latencies, and the 1-minute
load average before and after: a load above the CPU count means other processes competed for
the cores and the latencies say little. `--runs N`: N runs against fresh servers and a last
line of their medians.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from receiver.serve.wire import encode, make_request

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_MAP = ROOT / "recordings" / "indoor-walk" / "map.json"
SIGMA_UV = 3e-4
SIGMA_M = 0.002
# Longest wait for a warm-up datagram's reply (s).
WARMUP_WAIT_S = 5.0


def four_led_datagrams(led_map, n: int, devices: int, seed: int = 0, n_leds: int = 4,
                       prefix: str = "load-") -> list[tuple[str, int, bytes]]:
    """n encoded requests of `n_leds` LEDs each (4: a 2 x 2 block of panels; more: the nearest
    ones), round robin over `devices` devices named `prefix` + index: (device, seq, datagram)."""
    from receiver.locate.pose import ypr_to_rotation
    rng = np.random.default_rng(seed)
    leds = list(led_map.leds.values())
    xyz = np.array([led.xyz for led in leds])
    R = ypr_to_rotation(10.0, 88.0, 2.0)
    out = []
    for k in range(n):
        dev, seq = k % devices, k // devices
        C = np.array([xyz[:, 0].mean() + 0.3 * np.sin(0.01 * seq + dev),
                      xyz[:, 1].mean() + 0.3 * np.cos(0.01 * seq + dev), 1.0])
        if n_leds == 4:
            cols = [sorted(set(xyz[:, a]), key=lambda c: abs(c - C[a]))[:2] for a in (0, 1)]
            near = np.flatnonzero(np.isin(xyz[:, 0], cols[0]) & np.isin(xyz[:, 1], cols[1]))[:4]
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


def run_load(address: tuple[str, int], datagrams, rate: float, drain_s: float = 1.0,
             source: str | None = None, sock: socket.socket | None = None) -> dict:
    """Send `datagrams` ((device, seq, bytes)) to `address` at `rate` per second (from the
    address `source`, default any), then wait up to `drain_s` for the replies still missing; the
    report. Only replies with a position count as served (`replies`, the latencies); error
    replies are counted by reason (`errors`), replies without a position in `no_position`, and
    `lost` is every datagram without a position reply. `sock`: the socket to use (`open_socket`;
    closed at the end), else one of its own."""
    sock = open_socket(address, source) if sock is None else sock
    sock.settimeout(0.05)
    sent_at: dict[tuple[str, int], float] = {}
    lat: list[float] = []
    errors: dict[str, int] = {}
    no_position = [0]
    done = threading.Event()
    last_reply = [0.0]

    def receive():
        while True:
            try:
                data = sock.recv(65536)
            except socket.timeout:
                if done.is_set():
                    return
                continue
            except OSError:
                return
            now = time.monotonic()
            try:
                rep = json.loads(data)
            except ValueError:
                errors["unreadable"] = errors.get("unreadable", 0) + 1
                continue
            if "error" in rep:
                errors[str(rep["error"])] = errors.get(str(rep["error"]), 0) + 1
                continue
            if rep.get("position") is None:
                no_position[0] += 1
                continue
            t0 = sent_at.get((rep.get("device"), rep.get("seq")))
            if t0 is not None:
                lat.append(now - t0)
                last_reply[0] = now
    rx = threading.Thread(target=receive, daemon=True)
    rx.start()
    start = time.monotonic()
    k = 0
    while k < len(datagrams):
        due = min(len(datagrams), int((time.monotonic() - start) * rate) + 1)
        while k < due:
            dev, seq, data = datagrams[k]
            sent_at[(dev, seq)] = time.monotonic()
            sock.send(data)
            k += 1
        time.sleep(0.0005)
    send_s = time.monotonic() - start
    drain_end = time.monotonic() + drain_s      # wait for the last replies, at most drain_s
    while len(lat) + no_position[0] + sum(errors.values()) < len(datagrams) and time.monotonic() < drain_end:
        time.sleep(0.01)
    done.set()
    rx.join(5.0)
    sock.close()
    ms = np.array(lat) * 1e3
    span = (last_reply[0] - start) if len(lat) else float("nan")
    return {"sent": len(datagrams), "send_s": round(send_s, 3), "replies": len(lat),
            "lost": len(datagrams) - len(lat), "replies_per_s": round(len(lat) / span, 1) if len(lat) else 0.0,
            "p50_ms": round(float(np.percentile(ms, 50)), 3) if len(ms) else None,
            "p99_ms": round(float(np.percentile(ms, 99)), 3) if len(ms) else None,
            "max_ms": round(float(ms.max()), 3) if len(ms) else None,
            "errors": errors, "no_position": no_position[0]}


def warm_up(address: tuple[str, int], datagrams, sock: socket.socket | None = None) -> int:
    """Send `datagrams` ((device, seq, bytes)) one at a time, each after the previous one's reply
    (at most WARMUP_WAIT_S each); the replies received. Before a timed load, the devices' first
    datagrams: a device's first datagram is solved from scratch (PnP, and both handednesses of a
    map that does not declare it: ~1.6 ms of CPU against ~0.1 ms warm), so 50 devices starting
    together put ~80 ms of backlog in front of the first timed replies."""
    got = 0
    own = sock is None
    sock = open_socket(address) if own else sock
    try:
        sock.settimeout(WARMUP_WAIT_S)
        for _, _, data in datagrams:
            sock.send(data)
            try:
                sock.recv(65536)
                got += 1
            except socket.timeout:
                pass
    finally:
        if own:
            sock.close()
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


def start_server(args=SERVER_ARGS) -> tuple[subprocess.Popen, tuple[str, int]]:
    """`occloc serve --port 0 ARGS` as a subprocess, once ready: (process, (host, port))."""
    proc = subprocess.Popen([sys.executable, "-m", "receiver.cli", "serve", "--port", "0", *args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    if "listening on udp://" not in line:
        proc.kill()
        raise RuntimeError(f"occloc serve did not start: {line.strip()}")
    proc.stderr.readline()                      # "occloc serve: ready"
    host, port = line.split("udp://")[1].strip().rsplit(":", 1)
    return proc, (host, int(port))


def main(argv=None) -> int:
    from receiver.io.ledmap import load_map
    from receiver.serve.client import parse_udp_url
    p = argparse.ArgumentParser(prog="python -m receiver.serve.loadgen", description=__doc__.split("\n\n")[0])
    p.add_argument("url", nargs="?", help="udp://HOST:PORT of a running occloc serve (default: start one)")
    p.add_argument("--rate", type=float, default=3000.0, help="datagrams per second (3000)")
    p.add_argument("--seconds", type=float, default=3.0, help="how long to send (3)")
    p.add_argument("--devices", type=int, default=50, help="devices the datagrams come from (50)")
    p.add_argument("--map", default=str(DEFAULT_MAP), help="LED map (the bundled walk's)")
    p.add_argument("--runs", type=int, default=1,
                   help="runs, each against a fresh server (1); with more, a last line of medians")
    p.add_argument("--no-warmup", dest="warmup", action="store_false",
                   help="time each device's first datagram too (default: sent before the timed load, "
                        "one at a time, not counted: run_load)")
    p.add_argument("--flood-rate", type=float, default=0.0,
                   help="the honest-device figure: valid datagrams per second from --flood-sources other "
                        "addresses (127.0.0.2 ...) while --rate / --devices measure the honest ones; the "
                        "server started here then keeps its default per-source rate limit")
    p.add_argument("--flood-total", type=int, default=50000, help="flood datagrams in all (50000)")
    p.add_argument("--flood-sources", type=int, default=4, help="flood source addresses (4)")
    p.add_argument("--flood-leds", type=int, default=64, help="LEDs per flood datagram (64)")
    a = p.parse_args(argv)
    if a.flood_rate:
        return flood_main(a)
    if a.rate <= 0 or a.seconds <= 0 or a.devices <= 0 or a.runs <= 0:
        print("loadgen: --rate, --seconds, --devices and --runs must be positive", file=sys.stderr)
        return 2
    if a.url and a.runs > 1:
        print("loadgen: --runs needs a server of its own (no URL): the devices' seqs restart", file=sys.stderr)
        return 2
    dg = four_led_datagrams(load_map(a.map), int(a.rate * a.seconds) + a.devices, a.devices)
    warmup, timed = (dg[:a.devices], dg[a.devices:]) if a.warmup else ((), dg[:int(a.rate * a.seconds)])
    reports = []
    for _ in range(a.runs):
        reports.append(one_run(a.url and parse_udp_url(a.url), timed, a.rate, warmup))
        print(json.dumps(reports[-1]))
    if a.runs > 1:
        print(json.dumps(median_report(reports)))
    return 0


def one_run(address, datagrams, rate: float, warmup=()) -> dict:
    """`run_load` against `address`, or a server started for this run (then with its CPU time
    per reply); with the machine's 1-minute load average before and after (`os.getloadavg`) and
    its CPU count, which say whether other work competed for the cores."""
    proc = None
    if not address:
        proc, address = start_server()
    try:
        sock = open_socket(address)
        warmed = warm_up(address, warmup, sock)
        load0 = os.getloadavg()[0]
        cpu0 = None if proc is None else process_cpu_s(proc.pid)
        report = run_load(address, datagrams, rate, sock=sock)
        report.update(warmup=len(warmup), warmup_replies=warmed)
        cpu1 = None if proc is None else process_cpu_s(proc.pid)
        if cpu0 is not None and cpu1 is not None and report["replies"]:
            report["server_cpu_ms_per_reply"] = round((cpu1 - cpu0) * 1e3 / report["replies"], 3)
        report.update(loadavg_before=round(load0, 2), loadavg_after=round(os.getloadavg()[0], 2),
                      cpus=os.cpu_count())
        return report
    finally:
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:     # still working through a backlog
                proc.kill()
                proc.wait(10)


def flood_main(a) -> int:
    """An honest device's reply latency while other sources flood the server with valid
    datagrams: the flood's own report and the honest device's, as one JSON line."""
    from receiver.io.ledmap import load_map
    from receiver.serve.client import parse_udp_url

    led_map = load_map(a.map)
    if a.url:
        proc, address = None, parse_udp_url(a.url)
    else:
        proc, address = start_server(())        # the default per-source limits
    try:
        per_source = a.flood_total // a.flood_sources
        floods = [four_led_datagrams(led_map, per_source, 64, seed=1 + k, n_leds=a.flood_leds,
                                     prefix=f"flood{k}-") for k in range(a.flood_sources)]
        n_honest = max(1, int(a.rate * a.flood_total / a.flood_rate))
        honest = four_led_datagrams(led_map, n_honest + a.devices, a.devices, prefix="honest-")
        honest_sock = open_socket(address)
        warm_up(address, honest[:a.devices], honest_sock)
        results: dict = {}
        cpu0 = None if proc is None else process_cpu_s(proc.pid)
        threads = [threading.Thread(target=lambda k=k: results.__setitem__(
            k, run_load(address, floods[k], a.flood_rate / a.flood_sources, source=f"127.0.0.{2 + k}")))
            for k in range(a.flood_sources)]
        for t in threads:
            t.start()
        results["honest"] = run_load(address, honest[a.devices:], a.rate, sock=honest_sock)
        for t in threads:
            t.join()
        cpu1 = None if proc is None else process_cpu_s(proc.pid)
        flood = [results[k] for k in range(a.flood_sources)]
        report = {"honest": results["honest"],
                  "flood": {"sent": sum(r["sent"] for r in flood), "position_replies": sum(r["replies"] for r in flood),
                            "error_replies": sum(sum(r["errors"].values()) for r in flood),
                            "send_s": max(r["send_s"] for r in flood)},
                  "server_cpu_s": None if cpu0 is None or cpu1 is None else round(cpu1 - cpu0, 2),
                  "loadavg_after": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()}
        print(json.dumps(report))
        return 0
    finally:
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)


def median_report(reports: list[dict]) -> dict:
    """The median of each number over the runs (`"median_of": runs`)."""
    out = {"median_of": len(reports)}
    for key, value in reports[0].items():
        values = [r.get(key) for r in reports]
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
            out[key] = float(np.median(values))
    return out


if __name__ == "__main__":
    raise SystemExit(main())
