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
