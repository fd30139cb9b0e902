"""Row readout time from tone and OOK stripes (receiver.calibrate.rows, `occloc calibrate rows`)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from receiver.calibrate.rows import crossings, exposure_warning, measure_row_time
from receiver.cli import main as occloc
from receiver.core.errors import InputError
from receiver.core.records import Frame
from receiver.io.camera import load_camera
from receiver.io.sources import open_source

ROOT = Path(__file__).resolve().parents[2]
REC = ROOT / "recordings"
TOL = 0.003  # 0.3 %
WRONG_PRIOR_US = 20.0  # the camera file's guess: the measurement must not lean on it


def _synth_frames(row_us: float, mode: str, rate: float, n: int = 10):
    from tools.synth import make_scene, render_frames
    kw = {"rate_hz": rate} if mode == "ook" else {"tone_hz": rate}
    scene = make_scene("indoor-static", seed=3, n_frames=n, row_readout_us=row_us, **kw)
    return [Frame(t["frame"], t["t"], img) for img, t in render_frames(scene, seed=5)]


@pytest.mark.parametrize("row_us", [12.0, 25.0, 38.0])
@pytest.mark.parametrize("mode,rate", [("tone", 2000.0), ("ook", 5000.0)])
def test_synthetic_row_time(row_us, mode, rate):
    res = measure_row_time(_synth_frames(row_us, mode, rate), mode=mode, rate_hz=rate,
                           prior_row_us=WRONG_PRIOR_US)
    assert abs(res.t_row_us / row_us - 1) < TOL, res.to_json()
    assert 0 < res.stderr_us < 0.01 * row_us
    assert res.exposure_us is not None and 8.0 < res.exposure_us < 35.0  # true 20 us


def test_without_prior():
    res = measure_row_time(_synth_frames(25.0, "ook", 5000.0, n=6), mode="ook", rate_hz=5000.0)
    assert abs(res.t_row_us / 25.0 - 1) < TOL


def test_recording_static_tone_and_ook():
    frames = list(open_source(str(REC / "indoor-static")))
    tone = measure_row_time(frames, mode="tone", rate_hz=2000.0, prior_row_us=WRONG_PRIOR_US)
    ook = measure_row_time(frames, mode="ook", rate_hz=20000.0, prior_row_us=WRONG_PRIOR_US)
    assert abs(tone.t_row_us / 15.0 - 1) < TOL, tone.to_json()
    assert abs(ook.t_row_us / 15.0 - 1) < TOL, ook.to_json()


def test_cli_walk_writes_out(tmp_path, capsys):
    cam = tmp_path / "camera.yaml"
    text = (REC / "indoor-walk" / "camera.yaml").read_text().replace("row_readout_us: 15.", "row_readout_us: 20.")
    cam.write_text(text)
    out = tmp_path / "out.yaml"
    rc = occloc(["calibrate", "rows", str(REC / "indoor-walk"), "--camera", str(cam), "--ook-rate", "20000",
                 "--out", str(out), "--max-frames", "20", "--map", str(REC / "indoor-walk" / "map.json")])
    assert rc == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert abs(line["row_readout_us"] / 15.0 - 1) < TOL
    assert abs(load_camera(str(out)).row_readout_us / 15.0 - 1) < TOL
    assert load_camera(str(cam)).row_readout_us == 20.0  # the input is untouched
    assert load_camera(str(out)).fx == load_camera(str(cam)).fx


def test_cli_updates_camera_in_place(tmp_path, capsys):
    rec = tmp_path / "rec"
    shutil.copytree(REC / "indoor-static", rec)
    cam = rec / "camera.yaml"
    cam.write_text(cam.read_text().replace("row_readout_us: 15.", "row_readout_us: 18."))
    assert occloc(["calibrate", "rows", str(rec), "--camera", str(cam), "--freq-hz", "2000",
                   "--max-frames", "30"]) == 0
    assert abs(load_camera(str(cam)).row_readout_us / 15.0 - 1) < TOL
    assert not [p for p in rec.iterdir() if p.name.startswith(".camera-")]  # no temp file left


def test_a_read_only_camera_file_is_not_updated_in_place(tmp_path, capsys):
    """A camera file without write permission is left alone (even by root, whom the system lets
    replace it): one-line error naming --out, the file unchanged; with --out the result goes there."""
    import os
    rec = tmp_path / "rec"
    shutil.copytree(REC / "indoor-static", rec)
    cam = rec / "camera.yaml"
    before = cam.read_text()
    os.chmod(cam, 0o444)
    argv = ["calibrate", "rows", str(rec), "--camera", str(cam), "--freq-hz", "2000", "--max-frames", "10"]
    assert occloc(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"occloc: {cam} is read-only: give --out FILE2 for the calibrated camera file"
    assert cam.read_text() == before and (os.stat(cam).st_mode & 0o777) == 0o444
    assert occloc(argv + ["--out", str(tmp_path / "new.yaml")]) == 0
    assert load_camera(str(tmp_path / "new.yaml")).row_readout_us > 0


def test_no_stripes_is_one_line_error(tmp_path, capsys):
    import cv2
    import numpy as np
    folder = tmp_path / "dark"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), np.zeros((120, 160), np.uint8))
    with pytest.raises(InputError):
        measure_row_time(open_source(str(folder)), mode="ook", rate_hz=20000.0)
    cam = tmp_path / "c.yaml"
    cam.write_text((REC / "indoor-static" / "camera.yaml").read_text())
    assert occloc(["calibrate", "rows", str(folder), "--camera", str(cam), "--ook-rate", "20000"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("occloc: ") and len(err[-1]) < 300


def test_crossings_and_warning():
    import numpy as np
    x = np.tile(np.r_[np.zeros(5), np.full(5, 100.0)], 4)
    pos, d = crossings(x)
    assert np.allclose(np.diff(pos), 5.0) and set(d.tolist()) == {-1, 1}
    # the limits the decoders read to: 1.8 chips of 20 kHz OOK (90 us), a 4 kHz tone's half period
    assert exposure_warning(95.0, [20000.0]) is not None and "limit 90 us" in exposure_warning(95.0, [20000.0])
    assert exposure_warning(79.0, [20000.0]) is None
    assert exposure_warning(130.0, (), [4000.0]) is not None and exposure_warning(60.0, (), [4000.0]) is None
    assert exposure_warning(60.0, [20000.0], [5000.0]) is None and exposure_warning(None, [20000.0]) is None


def test_no_stripes_with_an_exposure_longer_than_a_chip_says_why(tmp_path, capsys):
    import cv2
    import numpy as np
    folder = tmp_path / "dark"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), np.zeros((90, 160), np.uint8))
    text = (REC / "indoor-static" / "camera.yaml").read_text()
    for exposure, hint in (("20.", False), ("87.", True)):
        cam = tmp_path / f"c{exposure}yaml"
        cam.write_text("\n".join(f"exposure_us: {exposure}" if l.startswith("exposure_us:") else l
                                 for l in text.splitlines()) + "\n")
        assert occloc(["calibrate", "rows", str(folder), "--camera", str(cam), "--ook-rate", "20000"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("occloc: no OOK stripes found at 20000 Hz")
        assert ("exposure 87 us is longer than one chip (50 us)" in err[-1]) == hint, err[-1]


def test_exposure_warning_counts_a_map_light_without_rate_at_the_protocol_rate(tmp_path, capsys):
    """A map's OOK light without `rate_hz` is decoded at the protocol's 20 kHz chips: an exposure
    a 2 kHz tone allows (110 us, under its 250 us half period) but those chips do not (90 us)
    is warned about when the row time is measured on the tone."""
    import cv2
    from tools.synth import make_scene, render_frames
    folder = tmp_path / "frames"
    folder.mkdir()
    scene = make_scene("indoor-static", seed=3, n_frames=10, exposure_us=110.0)
    for img, t in render_frames(scene, seed=5):
        cv2.imwrite(str(folder / f"{t['frame']:03d}.png"), img)
    m = json.loads((REC / "indoor-static" / "map.json").read_text())
    for led in m["leds"]:
        led.pop("rate_hz", None)
    assert {led["mode"] for led in m["leds"]} == {"ook", "tone"}
    (tmp_path / "map.json").write_text(json.dumps(m))
    rc = occloc(["calibrate", "rows", str(folder), "--camera", str(REC / "indoor-static" / "camera.yaml"),
                 "--freq-hz", "2000", "--out", str(tmp_path / "out.yaml"), "--map", str(tmp_path / "map.json")])
    assert rc == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert 95.0 < line["exposure_us"] < 250.0, line
    assert line["warning"] and "limit 90 us" in line["warning"], line


@pytest.mark.parametrize("exposure_us", [30.0, 130.0])
def test_rows_says_when_the_exposure_is_longer_than_the_chips_it_measures(exposure_us, tmp_path, capsys):
    """OOK at 20 kHz (50 us chips), the camera file fresh from `calibrate intrinsics` (no row
    time, no exposure): at 30 us the exposure is measured and nothing is warned; at 130 us (2.6
    chips) the exposure read from the edges is past the decoders' limit (90 us) and the warning
    says that the stripes are smeared, with the numbers."""
    import cv2
    from tools.synth import make_scene, render_frames
    folder = tmp_path / "frames"
    folder.mkdir()
    scene = make_scene("indoor-static", seed=3, n_frames=10, exposure_us=exposure_us)
    for img, t in render_frames(scene, seed=5):
        cv2.imwrite(str(folder / f"{t['frame']:03d}.png"), img)
    text = (REC / "indoor-static" / "camera.yaml").read_text()
    cam = tmp_path / "cam.yaml"
    cam.write_text("\n".join("row_readout_us: 0." if ln.startswith("row_readout_us:") else
                             "exposure_us: 0." if ln.startswith("exposure_us:") else ln for ln in text.splitlines()))
    assert occloc(["calibrate", "rows", str(folder), "--camera", str(cam), "--ook-rate", "20000",
                   "--out", str(tmp_path / "out.yaml")]) == 0
    cap = capsys.readouterr()
    line = json.loads(cap.out.strip().splitlines()[-1])
    assert abs(line["row_readout_us"] / 15.0 - 1) < TOL, line   # the scene's row time
    if exposure_us < 50:
        assert 0.6 * exposure_us < line["exposure_us"] < 1.4 * exposure_us and line["warning"] is None, line
    else:
        assert 100.0 < line["exposure_us"] < 160.0 and line["exposure_from"] == "chip sequence fit", line
        assert "limit 90 us" in line["warning"] and "chips (50 us) the row time is measured on" in line["warning"]
        assert "occloc: warning: the exposure (at least ~" in cap.err
