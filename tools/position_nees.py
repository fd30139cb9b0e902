"""Do the positions' covariances say how well? `python -m tools.position_nees RUN.jsonl TRUTH.jsonl`

For every frame of an `occloc run` output with a position and a truth camera position: the
filtered position's Mahalanobis^2 against the truth under its `position.cov`, and each raw fix's
error per axis in units of its `position.raw_std_m`. Where the covariances are honest, the
Mahalanobis^2 follows chi^2 with 3 dof (median 2.37, 95 % below 7.81) and |error| / std has a
median of 0.67; much larger values mean the positioner claims more than it delivers (and its
filter then throws good fixes out). Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from receiver.core.errors import InputError
from receiver.io.files import read_jsonl
from receiver.io.truth import load_truth

CHI2_3DOF_95 = 7.81


def position_nees(run: list[dict], truth: dict[int, dict]) -> dict:
    """The figures of the module docstring from run objects (`occloc run` lines) and
    `load_truth` records: frames, nees_p50, nees_p95, nees_below_95pct (fraction below
    `CHI2_3DOF_95`), raw_fixes, raw_z_p50 (None where no frame has one)."""
    nees, z = [], []
    for obj in run:
        pos, rec = obj.get("position"), truth.get(obj.get("frame"))
        if not pos or rec is None:
            continue
        t = rec["xyz"]
        try:
            if pos.get("cov") is not None:
                e = np.array([pos[k] for k in "xyz"], float) - t
                P = np.array(pos["cov"], float).reshape(3, 3)
                nees.append(float(e @ np.linalg.lstsq(P, e, rcond=None)[0]))
            if pos.get("raw") is not None and pos.get("raw_std_m") is not None:
                e = np.array([pos["raw"][k] for k in "xyz"], float) - t
                z.extend((np.abs(e) / np.maximum(np.array(pos["raw_std_m"], float).reshape(3), 1e-9)).tolist())
        except (KeyError, TypeError, ValueError, AttributeError):
            raise InputError(f"run frame {obj.get('frame')}: a position needs numbers x, y, z with a 3 x 3 cov "
                             "(and raw x, y, z with three raw_std_m)") from None
    n = np.array(nees)
    return {"frames": len(nees),
            "nees_p50": float(np.median(n)) if len(n) else None,
            "nees_p95": float(np.percentile(n, 95)) if len(n) else None,
            "nees_below_95pct": float(np.mean(n < CHI2_3DOF_95)) if len(n) else None,
            "raw_fixes": len(z) // 3,
            "raw_z_p50": float(np.median(z)) if z else None}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.position_nees", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="occloc run output (JSON Lines)")
    p.add_argument("truth", help="the recording's truth.jsonl")
    args = p.parse_args(argv)
    try:
        truth = load_truth(args.truth)
        run = [obj for _, obj in read_jsonl(args.run, "run")]
        out = position_nees(run, truth)
    except InputError as e:
        print(f"position_nees: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
