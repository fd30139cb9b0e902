"""`occloc export`: TUM (checked with the real `evo` package when installed), CSV and GeoJSON
of a run and of the truth; `occloc run --out` refuses an extension it does not write."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from receiver.cli import main as cli
from receiver.evaluate.export import local_to_wgs84

WALK = Path(__file__).resolve().parents[2] / "recordings" / "indoor-walk"
FRAMES = 30


@pytest.fixture(scope="module")
def walk_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "run.jsonl"
    assert cli(["run", str(WALK), "--out", str(out), "--max-frames", str(FRAMES)]) == 0
    return out


def _tum(path):
    return np.loadtxt(path, ndmin=2)


def test_tum_of_run_and_truth(walk_run, tmp_path, capsys):
    run_tum, truth_tum = tmp_path / "run.tum", tmp_path / "truth.tum"
    assert cli(["export", str(walk_run), "--format", "tum", "--out", str(run_tum)]) == 0
    assert cli(["export", str(WALK / "truth.jsonl"), "--format", "tum", "--out", str(truth_tum)]) == 0
    err = capsys.readouterr().err
    assert f"{FRAMES} positions of {FRAMES} lines written" in err
    est, ref = _tum(run_tum), _tum(truth_tum)
    assert est.shape == (FRAMES, 8) and ref.shape[1] == 8
    lines = [json.loads(l) for l in walk_run.read_text().splitlines()]
    for row, rec in zip(est, lines):
        p = rec["position"]
        assert row[0] == pytest.approx(rec["t"], abs=1e-6)
        assert row[1:4] == pytest.approx([p["x"], p["y"], p["z"]], abs=1e-6)
        # the quaternion is the line's camera-to-world rotation
        R = Rotation.from_quat(row[4:]).as_matrix()
        assert np.abs(R - np.array(p["R_wc"])).max() < 1e-5
    # against the truth's export, frame by frame: position within 5 cm, orientation within 2 deg
    ref = ref[:FRAMES]
    assert np.abs(est[:, 0] - ref[:, 0]).max() < 1e-3
    assert np.linalg.norm(est[:, 1:4] - ref[:, 1:4], axis=1).max() < 0.05
    ang = (Rotation.from_quat(est[:, 4:]).inv() * Rotation.from_quat(ref[:, 4:])).magnitude()
    assert np.degrees(ang).max() < 2.0


def test_evo_reads_the_export_and_scores_it(walk_run, tmp_path):
    """The real evo package (evo_ape's API) on the run's TUM export against the truth's."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    run_tum, truth_tum = tmp_path / "run.tum", tmp_path / "truth.tum"
    assert cli(["export", str(walk_run), "--format", "tum", "--out", str(run_tum)]) == 0
    assert cli(["export", str(WALK / "truth.jsonl"), "--format", "tum", "--out", str(truth_tum)]) == 0
    ref = file_interface.read_tum_trajectory_file(str(truth_tum))
    est = file_interface.read_tum_trajectory_file(str(run_tum))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.005)
    assert est.num_poses == FRAMES
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rmse = ape.get_statistic(metrics.StatisticsType.rmse)
    own = math.sqrt(np.mean(np.sum((est.positions_xyz - ref.positions_xyz) ** 2, axis=1)))
    assert rmse == pytest.approx(own, rel=1e-9) and rmse < 0.05
    rot = metrics.APE(metrics.PoseRelation.rotation_angle_deg)
    rot.process_data((ref, est))
    assert rot.get_statistic(metrics.StatisticsType.max) < 2.0


def test_csv_and_geojson(walk_run, tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert cli(["export", str(walk_run), "--format", "csv", "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    lines = [json.loads(l) for l in walk_run.read_text().splitlines()]
    assert len(rows) == FRAMES
    assert float(rows[7]["x"]) == lines[7]["position"]["x"] and rows[7]["method"] == lines[7]["position"]["method"]
    assert rows[7]["hv_x"] == "" and rows[7]["no_fix"] == ""
    gj = tmp_path / "run.geojson"
    assert cli(["export", str(walk_run), "--format", "geojson", "--out", str(gj)]) == 2
    assert "--origin" in capsys.readouterr().err and not gj.exists()
    assert cli(["export", str(walk_run), "--format", "geojson", "--origin", "45.0,7.0", "--out", str(gj)]) == 0
    obj = json.loads(gj.read_text())
    pts = [f for f in obj["features"] if f["geometry"]["type"] == "Point"]
    assert len(pts) == FRAMES and obj["features"][-1]["geometry"]["type"] == "LineString"
    lon, lat = pts[0]["geometry"]["coordinates"]
    # 1 m north is 1 / 111132 deg of latitude at 45 deg; 1 m east 1 / 78847 deg of longitude
    p = lines[0]["position"]
    assert lat - 45.0 == pytest.approx(p["y"] / 111132.0, rel=2e-3)
    assert lon - 7.0 == pytest.approx(p["x"] / 78847.0, rel=2e-3)
    assert local_to_wgs84(0.0, 0.0, (45.0, 7.0)) == (7.0, 45.0)


@pytest.mark.parametrize("argv,msg", [
    (["--format", "csv", "--out", "x.tum"], "a csv file ends in .csv"),
    (["--format", "tum", "--out", "x.csv"], "a tum file ends in .tum or .txt"),
    (["--format", "geojson", "--origin", "91,0"], "latitude"),
])
def test_export_refuses_bad_requests(walk_run, tmp_path, capsys, argv, msg):
    argv = [a if not a.startswith("x.") else str(tmp_path / a) for a in argv]
    assert cli(["export", str(walk_run), *argv]) == 2
    assert msg in capsys.readouterr().err


def test_run_out_refuses_an_extension_it_does_not_write(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert cli(["run", str(WALK), "--out", str(out), "--max-frames", "1"]) == 2
    err = capsys.readouterr().err
    assert "writes JSON Lines" in err and "occloc export run.jsonl --format csv" in err
    assert not out.exists()


def test_tum_of_photos_numbers_them_and_evo_reads_it(tmp_path, capsys):
    """Photos all have t = 0: their TUM time is the frame number (increasing, as evo needs), and
    the note says so; a photo run given --fps keeps its own times."""
    lines = [{"frame": i, "t": 0.0, "file": f"p{i}.jpg", "leds": [],
              "position": {"x": 0.1 * i, "y": 0.0, "z": 0.0, "R_wc": np.eye(3).tolist()}} for i in range(3)]
    run = tmp_path / "photos.jsonl"
    run.write_text("".join(json.dumps(o) + "\n" for o in lines))
    out = tmp_path / "photos.tum"
    assert cli(["export", str(run), "--format", "tum", "--out", str(out)]) == 0
    assert "t is the frame number" in capsys.readouterr().err
    assert _tum(out)[:, 0].tolist() == [0.0, 1.0, 2.0]
    from evo.tools import file_interface   # a test dependency (pyproject.toml): never skipped
    traj = file_interface.read_tum_trajectory_file(str(out))
    assert traj.num_poses == 3 and traj.check()[0]
    timed = [dict(o, t=o["frame"] / 10.0) for o in lines]
    run.write_text("".join(json.dumps(o) + "\n" for o in timed))
    out2 = tmp_path / "timed.tum"
    assert cli(["export", str(run), "--format", "tum", "--out", str(out2)]) == 0
    assert "frame number" not in capsys.readouterr().err
    assert _tum(out2)[:, 0].tolist() == [0.0, 0.1, 0.2]
