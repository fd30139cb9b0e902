"""Where a run loses its IDs: `python -m tools.id_loss RUN.jsonl TRUTH.jsonl`.

Every LED-frame of the run matched to a visible truth LED (as `occloc eval` matches them) is one
of: right (the true ID), wrong (another ID), or missing (no ID). The missing ones of each truth
LED are split by when they happen:

- before: before the first frame in which the LED had its right ID (packet assembly, the
  proposal's confirmation: the decoder's latency);
- never: the LED never had its right ID while it was matched (not decoded at all);
- after: after its first right ID (the track or its ID was lost and had to be found again).

One line per truth LED follows, in order of first appearance, with its matched frames, the
first right one and a strip of its frames (`.` right, `x` missing, `!` wrong, `b` missing on a
light the run marks as cut by the image border).

    .venv/bin/occloc run ../shared/independent/indoor-grid-s31 --out /tmp/run.jsonl
    .venv/bin/python -m tools.id_loss /tmp/run.jsonl ../shared/independent/indoor-grid-s31/truth.jsonl
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import defaultdict

import numpy as np


def id_loss(run: list[dict], truth: dict[int, dict]) -> dict:
    """{"matched", "right", "wrong", "before", "never", "after", "leds"}: LED-frame counts (module
    docstring) and per truth LED id (first seen first) its list of (frame, state, border) with
    state "right", "wrong" or "missing"."""
    from receiver.evaluate.metrics import DEFAULT_GATE_PX, match_leds

    per: dict[int, list] = defaultdict(list)
    for fr in run:
        targets = truth[fr["frame"]]["targets"]
        m = match_leds(np.array([(o["cx"], o["cy"]) for o in fr["leds"]], float).reshape(-1, 2),
                       np.array([t[:2] for t in targets], float).reshape(-1, 2), gate_px=DEFAULT_GATE_PX)
        for o, j in zip(fr["leds"], m):
            if j is None:
                continue
            true_id = targets[j][2]
            state = "missing" if o["id"] is None else "right" if o["id"] == true_id else "wrong"
            per[true_id].append((fr["frame"], state, bool(o.get("border"))))
    out = {"matched": 0, "right": 0, "wrong": 0, "before": 0, "never": 0, "after": 0, "leds": {}}
    for led_id, rows in sorted(per.items(), key=lambda kv: kv[1][0][0]):
        states = [s for _, s, _ in rows]
        first = states.index("right") if "right" in states else None
        out["matched"] += len(rows)
        out["right"] += states.count("right")
        out["wrong"] += states.count("wrong")
        if first is None:
            out["never"] += states.count("missing")
        else:
            out["before"] += states[:first].count("missing")
            out["after"] += states[first:].count("missing")
        out["leds"][led_id] = rows
    return out


def _strip(rows) -> str:
    return "".join("." if s == "right" else "!" if s == "wrong" else "b" if border else "x"
                   for _, s, border in rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.id_loss", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="the run's JSON lines (occloc run --out)")
    p.add_argument("truth", help="the recording's truth.jsonl")
    a = p.parse_args(argv)
    from receiver.core.errors import InputError
    from receiver.io.truth import load_run, load_truth

    try:
        truth = load_truth(a.truth)
        run = load_run(a.run, truth)
    except InputError as e:
        print(f"id_loss: {e}", file=sys.stderr)
        return 1
    r = id_loss(run, truth)
    n = r["matched"]
    if not n:
        print("id_loss: no LED-frame of the run matches a visible truth LED", file=sys.stderr)
        return 1
    print(f"matched LED-frames {n}: right {r['right']} ({100.0 * r['right'] / n:.1f} %), wrong {r['wrong']}, "
          f"missing before the first right ID {r['before']}, never decoded {r['never']}, after it {r['after']}")
    for led_id, rows in r["leds"].items():
        states = [s for _, s, _ in rows]
        first = states.index("right") if "right" in states else None
        print(f"  id {led_id:5d}  frames {rows[0][0]:4d}-{rows[-1][0]:4d}  matched {len(rows):3d}  right {states.count('right'):3d}"
              f"  first right {'-' if first is None else first:>3}  {_strip(rows)}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except BrokenPipeError:  # a reader that stopped early (| head): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(0)
