"""A recording whose exposure is longer than its OOK chips allow decodes nothing: `occloc run`
and `occloc check` say so, with the exposure, the limit and the chip rate or exposure that
would work, whether the camera file states the exposure or not."""

from __future__ import annotations

import re

import pytest

from receiver.cli import main as cli


@pytest.fixture(scope="module")
def long_exposure(tmp_path_factory):
    """indoor-static (20 kHz OOK: 50 us chips) recorded at 130 us, and its camera file without
    the exposure (0: unknown)."""
    rec = tmp_path_factory.mktemp("exp") / "rec"
    assert cli(["synth", "indoor-static", "--frames", "12", "--set", "exposure_us=130", "--out", str(rec)]) == 0
    text = (rec / "camera.yaml").read_text()
    assert re.search(r"(?m)^exposure_us: 130", text)
    unknown = rec.parent / "unknown.yaml"
    unknown.write_text(re.sub(r"(?m)^exposure_us:.*$", "exposure_us: 0.", text))
    return rec, unknown


def _exposure_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if "chips of the 20 kHz OOK chips" in ln]
    assert len(lines) == 1, err
    return lines[0]


def test_run_says_the_stated_exposure_is_too_long(long_exposure, capsys):
    rec, _ = long_exposure
    assert cli(["run", str(rec)]) == 0
    line = _exposure_line(capsys.readouterr().err)
    assert line.startswith("occloc: warning: exposure 130 us is 2.60 chips of the 20 kHz OOK chips (50 us)"), line
    assert "use an exposure <= 90 us or chips at <= 13.8 kHz (camera file)" in line, line


def test_run_says_a_learned_exposure_is_too_long(long_exposure, capsys):
    rec, unknown = long_exposure
    assert cli(["run", str(rec), "--camera", str(unknown)]) == 0
    line = _exposure_line(capsys.readouterr().err)
    m = re.match(r"occloc: warning: exposure (\d+) us is ([\d.]+) chips of the 20 kHz OOK chips", line)
    assert m and 100 <= int(m.group(1)) <= 160, line
    assert "use an exposure <= 90 us" in line and line.endswith("(from the stripes' edges)"), line


def test_check_measures_it_without_the_camera_files_value(long_exposure, capsys):
    rec, unknown = long_exposure
    assert cli(["check", str(rec), "--camera", str(unknown)]) == 1
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("FAIL exposure"))
    m = re.search(r"exposure (\d+) us is ([\d.]+) chips of the 20 kHz OOK chips", line)
    assert m and 100 <= int(m.group(1)) <= 160 and "use an exposure <= 90 us" in line, line
