"""tools.locator_replay: the vehicle locator fed pairs built from a recording's truth (the
bundled vehicle recording: the host placed from the first decoded lights on, within 0.1 m;
every car entry matched, none with a wrong ID)."""

from __future__ import annotations

from pathlib import Path

from tools.locator_replay import main, replay

REC = Path(__file__).resolve().parents[2] / "recordings" / "vehicle"


def test_replay_of_the_bundled_vehicle_recording(capsys):
    import argparse
    args = argparse.Namespace(centroid_px=0.2, bloom=2.5, sl_saturated_within_m=60.0, fv_saturated_within_m=40.0,
                              packet_s=2.4, seed=1)
    r = replay(str(REC), args)
    assert r["frames"] == 150 and r["hv_placed"] >= 70
    assert r["hv_2d_median_m"] <= 0.1
    assert r["fv_entries"] >= 250 and r["fv_unmatched"] == 0 and r["fv_wrong_id"] == 0
    assert r["fv_distance_median_pct"] <= 1.0 and r["fv_bearing_median_deg"] <= 0.1


def test_a_missing_folder_is_a_one_line_error(tmp_path, capsys):
    assert main([str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "camera" in err


def test_truth_shift_is_the_truth_cameras_turn_times_the_focal_length():
    """tools.truth_shift_run: the frame's shift (px) is the truth camera's yaw and pitch change
    since the previous frame times the focal length; none for the first frame."""
    import json
    import math
    from types import SimpleNamespace

    from receiver.io.camera import load_camera
    from tools.truth_shift_run import truth_shift

    shift = truth_shift(str(REC))
    with open(REC / "truth.jsonl") as f:
        cams = [json.loads(line)["camera"] for line in f][:3]
    fx = load_camera(str(REC / "camera.yaml")).fx
    assert shift(SimpleNamespace(frames=0), []) is None
    dx, dy = shift(SimpleNamespace(frames=2), [])
    assert dx == fx * math.radians(cams[2]["yaw"] - cams[1]["yaw"])
    assert dy == fx * math.radians(cams[2]["pitch"] - cams[1]["pitch"])


def test_scoring_tools_refuse_a_folder_without_truth_in_one_line(tmp_path, capsys):
    from tools.truth_shift_run import main as run_main
    from tools.vehicle_score import main as score_main
    assert run_main([str(tmp_path), str(tmp_path / "out.jsonl")]) == 2
    assert score_main([str(tmp_path), "--runs", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and not (tmp_path / "out.jsonl").exists()
