"""tools.position_nees: an honest covariance gives a Mahalanobis^2 median near chi^2 (3 dof)'s
2.37; one claiming ten times too small a sigma gives about a hundred times more; bad input is a
one-line error."""

import json

import numpy as np

from tools import position_nees


def _files(tmp_path, claimed_sigma_m, true_sigma_m=0.01, n=400):
    rng = np.random.default_rng(3)
    truth, run = [], []
    for k in range(n):
        c = rng.normal(0, 1, 3)
        truth.append({"frame": k, "t": k / 30, "camera": dict(zip("xyz", c.tolist())), "leds": []})
        est = c + rng.normal(0, true_sigma_m, 3)
        raw = c + rng.normal(0, true_sigma_m, 3)
        pos = dict(zip("xyz", est.tolist()), cov=(np.eye(3) * claimed_sigma_m ** 2).tolist(),
                   raw=dict(zip("xyz", raw.tolist())), raw_std_m=[claimed_sigma_m] * 3)
        run.append({"frame": k, "t": k / 30, "leds": [], "position": pos})
    (tmp_path / "truth.jsonl").write_text("".join(json.dumps(o) + "\n" for o in truth))
    (tmp_path / "run.jsonl").write_text("".join(json.dumps(o) + "\n" for o in run))
    return str(tmp_path / "run.jsonl"), str(tmp_path / "truth.jsonl")


def test_an_honest_covariance_gives_chi2_3dof(tmp_path, capsys):
    assert position_nees.main(list(_files(tmp_path, 0.01))) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 400 and out["raw_fixes"] == 400
    assert 1.9 < out["nees_p50"] < 2.9 and out["nees_below_95pct"] > 0.92
    assert 0.55 < out["raw_z_p50"] < 0.8


def test_an_overconfident_covariance_shows(tmp_path, capsys):
    assert position_nees.main(list(_files(tmp_path, 0.001))) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["nees_p50"] > 100 and out["raw_z_p50"] > 5


def test_bad_input_is_a_one_line_error(tmp_path, capsys):
    run, truth = _files(tmp_path, 0.01, n=3)
    assert position_nees.main([run, str(tmp_path / "missing.jsonl")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("position_nees:") and "\n" not in err
    (tmp_path / "run.jsonl").write_text('{"frame": 0, "position": {"x": 1, "cov": [[1.0]]}}\n')
    assert position_nees.main([run, truth]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("position_nees:") and "\n" not in err
