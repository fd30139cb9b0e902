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
import sys

from receiver.serve.loadcore import DEFAULT_MAP, four_led_datagrams, median_report, one_run


def main(argv=None) -> int:
    """The command; a bad input (an unreadable --map, a bad URL) is one line and exit 2."""
    from receiver.core.errors import InputError
    try:
        return _main(argv)
    except InputError as e:
        print(f"loadgen: {e}", file=sys.stderr)
        return 2


def _main(argv=None) -> int:
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
    p.add_argument("--suite", action="store_true",
                   help="every load figure, each against servers of its own (receiver.serve.loadsuite; "
                        "with --runs N, alternating, then each figure's medians)")
    p.add_argument("--figures", metavar="A,B", help="with --suite: only these figures "
                   "(rate_10k, p99_5k, devices_10k, scale, flood, v2)")
    a = p.parse_args(argv)
    if a.suite:
        from receiver.serve.loadsuite import suite_main
        return suite_main(a)
    if a.flood_rate:
        return flood_main(a)
    if a.rate <= 0 or a.seconds <= 0 or a.devices <= 0 or a.runs <= 0:
        print("loadgen: --rate, --seconds, --devices and --runs must be positive", file=sys.stderr)
        return 2
    if a.devices > 1000000 or a.rate * a.seconds > 1e7:
        print("loadgen: at most 1,000,000 --devices and 10,000,000 datagrams (--rate x --seconds)", file=sys.stderr)
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


def flood_main(a) -> int:
    """An honest device's reply latency while other sources flood the server with valid
    datagrams (`receiver.serve.loadsuite.fig_flood`): the flood's own counts and the honest
    device's report, as one JSON line."""
    from receiver.io.ledmap import load_map
    from receiver.serve.client import parse_udp_url
    from receiver.serve.loadsuite import fig_flood

    if min(a.rate, a.flood_rate, a.flood_total, a.flood_sources, a.flood_leds, a.devices) <= 0:
        print("loadgen: --rate, --devices and the --flood-* values must be positive", file=sys.stderr)
        return 2
    if a.flood_leds > 64 or a.flood_sources > 250:
        print("loadgen: --flood-leds must be at most 64 and --flood-sources at most 250", file=sys.stderr)
        return 2
    report = fig_flood(load_map(a.map), a.flood_total, a.flood_rate, sources=a.flood_sources, leds=a.flood_leds,
                       honest_rate=a.rate, honest_devices=a.devices, address=a.url and parse_udp_url(a.url))
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
