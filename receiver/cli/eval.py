"""`occloc eval`: score a run's JSON Lines against truth.jsonl (metrics in
`receiver.evaluate.metrics`, PNG with `--plot`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


from receiver.cli.args import number_in
from receiver.core.errors import InputError
from receiver.evaluate.metrics import (DEFAULT_AREA_BINS_PX, DEFAULT_FV_GATE_DEG, DEFAULT_GATE_PX,
                                      DEFAULT_S2PSK_PACKET_S, evaluate, format_table, json_safe, s2psk_packet_s)
from receiver.io.truth import load_run, load_truth

HELP = ("score a run's JSON Lines output against truth.jsonl (ID rate, distance/position error, latency; "
        "HV/FV errors in vehicle scenes)")


def add_arguments(parser) -> None:
    parser.add_argument("run", metavar="RUN.jsonl", help="output of `occloc run --out`")
    parser.add_argument("--truth", required=True, help="the recording's truth.jsonl")
    parser.add_argument("--plot", metavar="OUT.png", help="write trajectory/error plots (PNG)")
    parser.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    parser.add_argument("--gate-px", type=number_in(0.0, 100_000.0, "px", low_open=True), default=DEFAULT_GATE_PX,
                        help=f"LED match gate in pixels (default {DEFAULT_GATE_PX:g})")
    parser.add_argument("--fv-gate-deg", type=number_in(0.0, 180.0, "degrees", low_open=True), default=DEFAULT_FV_GATE_DEG,
                        help="bearing gate for matching forward vehicles without a decoded ID, degrees "
                             f"(default {DEFAULT_FV_GATE_DEG:g})")
    parser.add_argument("--map", help="the recording's map.json, for each S2-PSK light's packet duration "
                                      "(default: map.json beside the truth file if there is one, else "
                                      f"{DEFAULT_S2PSK_PACKET_S:g} s)")


def _write_plot(series, output, plot_eval) -> None:
    """The PNG is drawn into memory and written through `output` (receiver.io.files.Output):
    a failed plot leaves no half file."""
    import io

    buf = io.BytesIO()
    plot_eval(series, buf, area_bins_px=DEFAULT_AREA_BINS_PX)
    output.write_bytes(buf.getvalue())


def main(args) -> int:
    if not (args.gate_px > 0):
        raise InputError(f"--gate-px must be positive, got {args.gate_px}")
    if not (args.fv_gate_deg > 0):
        raise InputError(f"--fv-gate-deg must be positive, got {args.fv_gate_deg}")
    from receiver.io.files import StdoutOutput, claim_output

    map_path = args.map
    if map_path is None:
        beside = Path(args.truth).with_name("map.json")
        map_path = str(beside) if beside.is_file() else None
    plot_file = claim_output(args.plot, [args.run, args.truth, map_path], "--plot")
    truth = load_truth(args.truth)
    run = load_run(args.run, truth)
    packet_s = DEFAULT_S2PSK_PACKET_S
    if map_path is not None:
        from receiver.io.ledmap import load_map

        packet_s = s2psk_packet_s(load_map(map_path)) or DEFAULT_S2PSK_PACKET_S
    metrics, series = evaluate(run, truth, gate_px=args.gate_px, fv_gate_deg=args.fv_gate_deg,
                               s2psk_packet_s=packet_s)
    if plot_file is not None:
        from receiver.evaluate.plots import plot_eval

        _write_plot(series, plot_file, plot_eval)
    out = StdoutOutput()
    out.write((json.dumps(json_safe(metrics), allow_nan=False) if args.json else format_table(metrics)) + "\n")
    out.flush()
    if plot_file is not None:
        print(f"occloc: wrote {args.plot}", file=sys.stderr)
    return 0
