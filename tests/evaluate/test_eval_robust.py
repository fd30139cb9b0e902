"""`occloc eval` of a vehicle recording: plot axes robust to one wild locator, and a text report
with the rows of the recording's kind only."""

from __future__ import annotations

import json

import numpy as np

from receiver.evaluate.metrics import format_table
from receiver.evaluate.plots import _clipped, robust_upper


def test_axis_ignores_a_wild_series_outlier():
    filtered = np.full(100, 0.05)
    extra = np.full(100, 2.0)
    extra[7] = 260.0          # one wild fix of eqs. 44-47
    top = robust_upper([filtered], [extra])
    assert 2.0 < top < 5.0    # not 260 m
    clipped, n = _clipped(extra, 0.0, top)
    assert n == 1 and clipped.max() == top
    assert robust_upper([np.array([np.nan])], []) == 0.0


def test_vehicle_report_has_no_indoor_position_rows(tmp_path, capsys):
    from pathlib import Path
    from receiver.cli import main as occloc
    rec = Path(__file__).resolve().parents[2] / "recordings" / "vehicle"
    run = tmp_path / "run.jsonl"
    assert occloc(["run", str(rec), "--max-frames", "60", "--out", str(run)]) == 0
    capsys.readouterr()
    assert occloc(["eval", str(run), "--truth", str(rec / "truth.jsonl"), "--plot", str(tmp_path / "p.png")]) == 0
    text = capsys.readouterr().out
    assert "with a position" not in text and "position filtered" not in text and "position raw" not in text
    assert "HV frames" in text and (tmp_path / "p.png").stat().st_size > 1000
    # the plot's series carry each forward vehicle's time to collision and zone over time
    from receiver.evaluate.metrics import FV_ZONES, evaluate
    from receiver.io.truth import load_run, load_truth
    truth = load_truth(str(rec / "truth.jsonl"))
    _, series = evaluate(load_run(str(run), truth), truth)
    fvs = series["vehicle"]["fv"]
    assert any(np.isfinite(fv["zone"]).any() for fv in fvs.values())
    zones = np.concatenate([fv["zone"][np.isfinite(fv["zone"])] for fv in fvs.values()])
    assert set(zones.astype(int)) <= set(range(len(FV_ZONES)))
    lines = [json.loads(l) for l in run.read_text().splitlines()]
    ttcs = [f["ttc_s"] for l in lines if l["vehicle"] for f in l["vehicle"]["fv"] if f["ttc_s"] is not None]
    got = np.concatenate([fv["ttc_s"][np.isfinite(fv["ttc_s"])] for fv in fvs.values()])
    assert got.size <= len(ttcs) and (got.size > 0) == (len(ttcs) > 0)


