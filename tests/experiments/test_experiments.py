"""`occloc experiments --quick` end to end on a subset small enough for CI: the files exist and
parse, and the physical trends hold (never speeds)."""

from __future__ import annotations

import csv
import math
import os
import re
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
    """The whole `occloc experiments --quick`: every experiment, a few points, one seed."""
    out = tmp_path_factory.mktemp("exp")
    r = _occloc("experiments", "--quick", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out, r


def _by(out: Path, name: str, param: str) -> dict:
    return {float(x[param]): x for x in _rows(out / f"{name}.csv")}


def test_files_exist_and_parse(quick_run):
    from tools.experiments.registry import all_experiments

    out, r = quick_run
    exps = all_experiments()
    assert len(exps) == 13
    summary = (out / "summary.md").read_text()
    n_tasks = sum(len(e.quick_points) for e in exps.values())
    for name, exp in exps.items():
        rows = _rows(out / f"{name}.csv")
        assert sorted(float(x[exp.param]) for x in rows) == pytest.approx(sorted(exp.quick_points), rel=1e-5), name
        assert {x["seed"] for x in rows} == {"0"}
        for row in rows:
            for k, v in row.items():
                assert v == "" or float(v) == float(v), (name, k, v)  # numbers, never NaN
        assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"| {exp.figure} | [{name}]({name}.png) |" in summary
    assert not re.search(r"\bnan\b", summary, re.IGNORECASE)
    assert f"[{n_tasks}/{n_tasks}]" in r.stderr  # progress on stderr
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
    # Farther, fewer frames are ranged, and the error never improves on the near one (a point
    # never ranged counts as an unbounded error).
    assert _num(far["ranged_frac"]) < _num(near["ranged_frac"])
    far_err = _num(far["mean_err_pct"]) if _num(far["ranged_frac"]) else math.inf
    assert far_err >= 0.5 * _num(near["mean_err_pct"])


def test_rerun_uses_the_cache(quick_run, tmp_path):
    out, _ = quick_run
    r = _occloc("experiments", "fig41", "--quick", "--out", str(tmp_path), "--cache", str(out / ".cache"))
    assert r.returncode == 0, r.stderr
    assert "renders cached 3, made 0" in r.stderr  # fig41's three points
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


def test_ber_falls_with_snir(quick_run):
    out, _ = quick_run
    rows = _by(out, "fig29", "snir_db")
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


def test_s2psk_symbols_and_id_with_snir_and_power(quick_run):
    out, _ = quick_run
    rows = _by(out, "fig34", "snir_db")
    for var in ("0.1", "1"):
        assert _num(rows[30.0][f"ser_var{var}"]) == 0.0  # no symbol error at 30 dB per pixel
        assert _num(rows[30.0][f"theory_var{var}"]) <= _num(rows[5.0][f"theory_var{var}"])
        assert _num(rows[30.0][f"id_frac_var{var}"]) > 0.5 >= _num(rows[5.0][f"id_frac_var{var}"])
    power = _by(out, "fig35", "power_dn")
    assert _num(power[32.0]["id_frac_12.5bps"]) > _num(power[4.0]["id_frac_12.5bps"])


def test_tracking_fixes_every_frame_well_below_the_thesis_error(quick_run):
    out, _ = quick_run
    row = _rows(out / "tracking.csv")[0]
    assert _num(row["kalman_fix_frac"]) > 0.9 and _num(row["raw_fix_frac"]) > 0.9
    assert _num(row["kalman_mean_err_m"]) < 0.09  # the thesis: 9-10 cm with the filter


def test_panel_area_and_chips_fall_with_height(quick_run):
    out, _ = quick_run
    rows = _by(out, "fig32", "ceiling_m")
    heights = sorted(rows)
    for cm in ("10cm", "30cm"):
        area = [_num(rows[h]["area_px_" + cm]) for h in heights]
        chips = [_num(rows[h]["chips_per_frame_" + cm]) for h in heights]
        assert area == sorted(area, reverse=True) and chips == sorted(chips, reverse=True)
        assert _num(rows[40.0]["id_frac_" + cm]) == 0.0  # a few chips a frame: no packet
    for h in heights:  # area grows as the panel's side squared
        assert 7.0 < _num(rows[h]["area_px_30cm"]) / _num(rows[h]["area_px_10cm"]) < 11.0
    assert _num(rows[3.0]["id_frac_30cm"]) > 0.5 and _num(rows[3.0]["fix_frac_30cm"]) > 0.5


def test_resolution_exposure_and_vehicle_trends(quick_run):
    out, _ = quick_run
    res = _by(out, "fig36", "megapixels")
    assert _num(res[4.0]["decoded_frac"]) > _num(res[1.0]["decoded_frac"])
    assert _num(res[4.0]["focal_px"]) == pytest.approx(2 * _num(res[1.0]["focal_px"]), rel=0.01)  # same FOV
    assert _num(res[4.0]["mean_err_pct"]) < 1.0
    exp = _by(out, "fig37", "exposure_s")
    short, long_ = exp[min(exp)], exp[max(exp)]
    assert _num(short["ranged_frac"]) > 0.5 and _num(short["mean_err_pct"]) < 1.0
    assert _num(long_["ranged_frac"]) < _num(short["ranged_frac"])  # a frame-long exposure blurs the pair
    fv = _by(out, "fig38", "fv_kmh")
    assert _num(fv[110.0]["true_distance_max_m"]) > _num(fv[0.0]["true_distance_max_m"]) + 20.0
    assert _num(fv[110.0]["ranged_frac"]) > 0.0
    assert _num(fv[0.0]["ranged_frac"]) > 0.0
    assert _num(fv[110.0]["mean_err_m"]) > _num(fv[0.0]["mean_err_m"])  # farther and faster: worse
    sl = _by(out, "fig39", "spacing_m")
    assert _num(sl[25.0]["sl_in_view"]) > 3 * _num(sl[150.0]["sl_in_view"])
    assert _num(sl[25.0]["sl_decoded"]) >= _num(sl[150.0]["sl_decoded"])


def test_availability_vs_frame_rate_ambient_and_distortion(quick_run):
    out, _ = quick_run
    for row in _rows(out / "fps.csv"):
        assert _num(row["id_frac"]) > 0.8 and _num(row["fix_frac"]) > 0.8, row
    amb = _by(out, "ambient", "ambient_dn")
    assert _num(amb[0.0]["fix_frac"]) > 0.8
    assert _num(amb[220.0]["id_frac"]) < 0.5 * _num(amb[0.0]["id_frac"])  # 35 DN of stripe contrast left
    dist = _by(out, "distortion", "k1")
    assert _num(dist[-0.2]["mean_err_m"]) > _num(dist[0.0]["mean_err_m"])
    assert _num(dist[-0.2]["range_mean_err_pct"]) > 2 * _num(dist[0.0]["range_mean_err_pct"])


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
