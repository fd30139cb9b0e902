"""`occloc eval`: score a run's JSON Lines against truth.jsonl (metrics in
`receiver.evaluate.metrics`, PNG with `--plot`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


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
    parser.add_argument("--gate-px", type=float, default=DEFAULT_GATE_PX,
                        help=f"LED match gate in pixels (default {DEFAULT_GATE_PX:g})")
    parser.add_argument("--fv-gate-deg", type=float, default=DEFAULT_FV_GATE_DEG,
                        help="bearing gate for matching forward vehicles without a decoded ID, degrees "
                             f"(default {DEFAULT_FV_GATE_DEG:g})")
    parser.add_argument("--map", help="the recording's map.json, for each S2-PSK light's packet duration "
                                      "(default: map.json beside the truth file if there is one, else "
                                      f"{DEFAULT_S2PSK_PACKET_S:g} s)")


def _write_plot(series, path: str, plot_eval) -> None:
    """The PNG goes to a temporary sibling renamed into place: a failed plot leaves no half file."""
    import os
    import tempfile

    folder = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".plot-", suffix=".png", dir=folder)
    except OSError as e:
        raise InputError(f"cannot write {path}: {e.strerror or e}") from None
    os.close(fd)
    try:
        plot_eval(series, tmp, area_bins_px=DEFAULT_AREA_BINS_PX)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def main(args) -> int:
    if not (args.gate_px > 0):
        raise InputError(f"--gate-px must be positive, got {args.gate_px}")
    if not (args.fv_gate_deg > 0):
        raise InputError(f"--fv-gate-deg must be positive, got {args.fv_gate_deg}")
    from receiver.io.files import refuse_overwrite

    refuse_overwrite(args.plot, [args.run, args.truth], "--plot")
    truth = load_truth(args.truth)
    run = load_run(args.run, truth)
    map_path = args.map
    if map_path is None:
        beside = Path(args.truth).with_name("map.json")
        map_path = str(beside) if beside.is_file() else None
    packet_s = DEFAULT_S2PSK_PACKET_S
    if map_path is not None:
        from receiver.io.ledmap import load_map

        packet_s = s2psk_packet_s(load_map(map_path)) or DEFAULT_S2PSK_PACKET_S
    metrics, series = evaluate(run, truth, gate_px=args.gate_px, fv_gate_deg=args.fv_gate_deg,
                               s2psk_packet_s=packet_s)
    if args.json:
        print(json.dumps(json_safe(metrics), allow_nan=False))
    else:
        print(format_table(metrics))
    if args.plot:
        from receiver.evaluate.plots import plot_eval

        _write_plot(series, args.plot, plot_eval)
        print(f"occloc: wrote {args.plot}", file=sys.stderr)
    return 0
