"""Files a user writes by hand and outputs that are not files: a key given twice in a map or
settings file is refused (JSON keeps the last silently); `occloc export --out` writes a FIFO or
device by its name (no extension needed, never replaced)."""

from __future__ import annotations

import json
import os
import stat
import threading
from pathlib import Path

from receiver.cli import main as cli

STATIC = Path(__file__).resolve().parents[2] / "recordings" / "indoor-static"


def test_a_key_given_twice_in_a_map_is_refused(tmp_path, capsys):
    text = (STATIC / "map.json").read_text()
    m = tmp_path / "map.json"
    m.write_text(text.replace('"leds":', '"leds": [], "leds":', 1))
    assert cli(["run", str(STATIC), "--max-frames", "1", "--map", str(m)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"occloc: {m}: key 'leds' given twice in one object", err


def test_a_key_given_twice_in_a_settings_file_is_refused(tmp_path, capsys):
    s = tmp_path / "s.json"
    s.write_text('{"receiver": {"envelope_frames": 3, "envelope_frames": 0}}')
    assert cli(["run", str(STATIC), "--max-frames", "1", "--settings", str(s)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("key 'envelope_frames' given twice in one object")


def test_export_writes_a_fifo_by_its_name(tmp_path, capsys):
    run = tmp_path / "run.jsonl"
    assert cli(["run", str(STATIC), "--max-frames", "3", "--out", str(run)]) == 0
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()))
    reader.start()
    assert cli(["export", str(run), "--format", "csv", "--out", str(fifo)]) == 0
    reader.join(30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    rows = got[0].decode().splitlines()
    assert len(rows) == 4 and rows[0].startswith("frame"), rows
    capsys.readouterr()
    # an extension of another format is still refused
    assert cli(["export", str(run), "--format", "csv", "--out", str(tmp_path / "x.tum")]) == 2
    assert "a csv file ends in .csv" in capsys.readouterr().err
    # and an input is never an output
    assert cli(["export", str(run), "--format", "csv", "--out", str(run)]) == 2
    assert json.loads(run.read_text().splitlines()[0])["frame"] == 0


def test_a_fifo_or_folder_given_as_camera_or_map_is_named_as_such(tmp_path, capsys):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    for flag, what in (("--camera", "camera file"), ("--map", "map file")):
        for path, kind in ((fifo, "a FIFO"), (tmp_path, "a folder")):
            assert cli(["run", str(STATIC), "--max-frames", "1", flag, str(path)]) == 2
            assert capsys.readouterr().err.strip().splitlines()[-1] == \
                f"occloc: {path}: {what} is {kind}, not a regular file"
    assert cli(["run", str(STATIC), "--camera", str(tmp_path / "none.yaml")]) == 2
    assert capsys.readouterr().err.strip() == f"occloc: camera file not found: {tmp_path / 'none.yaml'}"
