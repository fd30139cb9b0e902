"""`occloc experiments --quick` end to end on a subset small enough for CI: the files exist and
parse, and the physical trends hold (never speeds)."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _occloc(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "receiver.cli", *args], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=900)


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _num(v):
    return None if v in ("", None) else float(v)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp")
    r = _occloc("experiments", "fig41", "--quick", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out, r


def test_files_exist_and_parse(quick_run):
    out, r = quick_run
    rows = _rows(out / "fig41.csv")
    assert [float(x["distance_m"]) for x in rows] == [0.6, 1.5, 2.55]
    for row in rows:
        for k, v in row.items():
            assert v == "" or float(v) == float(v), (k, v)  # numbers, never NaN
    assert (out / "fig41.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = (out / "summary.md").read_text()
    assert "| Fig. 41 |" in summary and "fig41.png" in summary
    assert "[3/3] fig41" in r.stderr  # progress on stderr
    assert any(f.suffix == ".npz" for f in (out / ".cache").iterdir())


def test_distance_error_grows_as_the_led_shrinks(quick_run):
    out, _ = quick_run
    rows = {float(x["distance_m"]): x for x in _rows(out / "fig41.csv")}
    areas = [_num(rows[d]["area_px"]) for d in sorted(rows)]
    assert areas == sorted(areas, reverse=True) and areas[-1] < areas[0] / 10
    near, far = rows[0.6], rows[2.55]
    # The near LED (22000 px, 50 chips a frame) is decoded and ranged within 1 %.
    assert _num(near["ranged_frac"]) > 0.5
    assert _num(near["mean_err_pct"]) < 1.0
    # Farther, the error (or the failure to range) never improves on the near one.
    if _num(far["ranged_frac"]):
        assert _num(far["mean_err_pct"]) >= 0.5 * _num(near["mean_err_pct"])
    else:
        assert _num(far["ranged_frac"]) == 0.0


def test_rerun_uses_the_cache(quick_run, tmp_path):
    out, _ = quick_run
    r = _occloc("experiments", "fig41", "--quick", "--out", str(tmp_path), "--cache", str(out / ".cache"))
    assert r.returncode == 0, r.stderr
    assert "renders cached 3, made 0" in r.stderr
    assert _rows(tmp_path / "fig41.csv") == _rows(out / "fig41.csv")
    (tmp_path / "summary.md").unlink()
    r = _occloc("experiments", "--report", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "| Fig. 41 |" in (tmp_path / "summary.md").read_text()


def test_bad_names_and_numbers_are_one_line_errors(tmp_path):
    r = _occloc("experiments", "fig99", "--out", str(tmp_path))
    assert r.returncode == 2 and r.stderr.startswith("occloc: unknown experiment fig99")
    assert "Traceback" not in r.stderr
    r = _occloc("experiments", "fig41", "--seeds", "0", "--out", str(tmp_path))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    f = tmp_path / "file"
    f.write_text("x")
    r = _occloc("experiments", "fig41", "--out", str(f))
    assert r.returncode == 2 and "not a folder" in r.stderr and f.read_text() == "x"


def test_ber_falls_with_snir(tmp_path):
    r = _occloc("experiments", "fig29", "--quick", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    rows = {float(x["snir_db"]): x for x in _rows(tmp_path / "fig29.csv")}
    assert sorted(rows) == [-6.0, 6.0, 24.0]
    rates = [_num(rows[s]["chip_error_rate"]) for s in sorted(rows)]
    theory = [_num(rows[s]["theory_pixel"]) for s in sorted(rows)]
    assert theory == sorted(theory, reverse=True)
    measured = [(s, v) for s, v in zip(sorted(rows), rates) if v is not None]
    assert len(measured) >= 2  # chips are found at least at the two higher SNIRs
    assert [v for _, v in measured] == sorted((v for _, v in measured), reverse=True)
    assert measured[-1][1] < 0.01
    ids = [_num(rows[s]["id_frac"]) for s in sorted(rows)]
    assert ids[-1] >= ids[0] and ids[-1] > 0.5  # the whole receiver reads the ID at 24 dB


def test_report_reads_a_cut_csv(tmp_path):
    """A CSV whose last row was cut short, or has more cells than the header, is read (missing
    cells None, extra ones dropped) rather than a traceback."""
    from tools.experiments.report import read_csv
    p = tmp_path / "fig41.csv"
    p.write_text("distance_m,error_pct,note\n1.0,0.5,ok\n2.0\n3.0,0.7,x,extra\n")
    rows = read_csv(str(p))
    assert rows[0] == {"distance_m": 1.0, "error_pct": 0.5, "note": "ok"}
    assert rows[1] == {"distance_m": 2.0, "error_pct": None, "note": None}
    assert rows[2] == {"distance_m": 3.0, "error_pct": 0.7, "note": "x"}
