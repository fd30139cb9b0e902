"""Start-up: what the command line imports before it does its work, and `--threads`.

The import graph is checked, not timed: a fresh interpreter in a subprocess builds the parser
(or runs a command) and reports `sys.modules`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from receiver.cli import main as cli
from receiver.core.budget import BLAS_THREAD_VARS, limit_blas_threads, threads

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "recordings" / "indoor-static"

# Never needed to parse arguments, and never by `occloc run`.
NOT_FOR_RUN = ("matplotlib", "receiver.serve", "receiver.evaluate", "receiver.calibrate", "tools")
# Not needed to build the parser (the command's implementation).
NOT_FOR_PARSER = ("numpy", "cv2", "scipy", "filterpy", "receiver.pipeline", "receiver.io.sources") + NOT_FOR_RUN


def _modules_after(code: str) -> set[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys, json\nprint(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, env=env, cwd=str(ROOT), timeout=600)
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def _loaded(mods: set[str], names) -> list[str]:
    return sorted(m for m in mods for n in names if m == n or m.startswith(n + "."))


@pytest.mark.parametrize("command", [None, "run", "bench", "tx", "calibrate", "check"])
def test_building_the_parser_imports_no_implementation(command):
    mods = _modules_after(f"import receiver.cli as c\nc.build_parser(c._available(), {command!r})")
    assert f"receiver.cli.{command}" in mods or command is None  # the set-up did run
    assert not _loaded(mods, NOT_FOR_PARSER), _loaded(mods, NOT_FOR_PARSER)


def test_top_level_help_lists_the_developer_commands_without_importing_them():
    mods = _modules_after("import receiver.cli as c\nassert {'synth', 'hil'} <= set(c._available())\n"
                          "assert 'synthetic scene' in c._help_line('tools.synth.cli')\n"
                          "assert c._help_line('receiver.cli.eval').endswith('vehicle scenes)')")
    assert not _loaded(mods, ("tools.synth", "tools.hil", "numpy", "cv2")), _loaded(mods, ("tools.synth", "numpy"))


@pytest.mark.slow
def test_run_imports_no_plotting_server_evaluation_or_tools(tmp_path):
    out = tmp_path / "o.jsonl"
    mods = _modules_after(f"from receiver.cli import main\nassert main(['run', {str(STATIC)!r}, '--max-frames', '2', "
                          f"'--out', {str(out)!r}]) == 0")
    assert len(out.read_text().splitlines()) == 2
    assert "receiver.pipeline" in mods  # it did run the receiver
    assert not _loaded(mods, NOT_FOR_RUN), _loaded(mods, NOT_FOR_RUN)


def test_limit_blas_threads_only_before_numpy_loads():
    env = {}
    assert limit_blas_threads(3, environ=env, modules={}) is True
    assert env == {name: "3" for name in BLAS_THREAD_VARS}
    env = {}
    assert limit_blas_threads(3, environ=env, modules={"numpy": object()}) is False and env == {}


def test_threads_sets_opencv_and_restores_it():
    before = cv2.getNumThreads()
    with threads(3):
        assert cv2.getNumThreads() == 3
    assert cv2.getNumThreads() == before


def test_run_threads_reach_opencv_the_video_decoder_and_the_summary(monkeypatch, tmp_path, capsys):
    import receiver.io.sources as sources
    seen = {}
    real_open = sources.VideoFileSource._open

    def spy_open(self, convert):
        seen["decoder"] = self.threads
        seen["opencv"] = cv2.getNumThreads()
        return real_open(self, convert)

    monkeypatch.setattr(sources.VideoFileSource, "_open", spy_open)
    before = cv2.getNumThreads()
    out = tmp_path / "o.jsonl"
    assert cli(["run", str(STATIC), "--max-frames", "2", "--threads", "3", "--out", str(out)]) == 0
    assert seen == {"decoder": 3, "opencv": 3}
    assert cv2.getNumThreads() == before
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("; threads: 3")
    assert cli(["run", str(STATIC), "--max-frames", "1", "--out", str(out)]) == 0
    assert seen["decoder"] == 1 and seen["opencv"] == 1  # the default: one core
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("; threads: 1")


def test_video_source_asks_ffmpeg_for_its_decoding_threads():
    from receiver.io.sources import VideoFileSource
    calls = []

    def factory(*a):
        calls.append(a[2:])
        return cv2.VideoCapture(*a)

    VideoFileSource(str(STATIC / "video.avi"), capture_factory=factory, threads=2).close()
    VideoFileSource(str(STATIC / "video.avi"), capture_factory=factory).close()
    assert calls == [([cv2.CAP_PROP_N_THREADS, 2],), ()]


@pytest.mark.parametrize("bad", ["0", "-1", "two", "100000"])
def test_run_threads_must_be_a_sensible_count(bad, capsys):
    with pytest.raises(SystemExit) as e:
        cli(["run", str(STATIC), "--threads", bad])
    assert e.value.code == 2 and "--threads" in capsys.readouterr().err


@pytest.mark.parametrize("still", [False, True])
def test_scipy_is_imported_before_a_stream_and_never_for_a_photo_and_filterpy_never(still):
    """scipy.optimize (~0.8 s) is imported when a stream's receiver is built, before its first
    frame: lazily inside the second frame it cost that frame ~0.7 s of latency. A still photo's
    receiver never imports it. filterpy (whose package imports scipy.stats, ~1.5 s) is the Kalman
    filter's test reference only: no receiver imports it."""
    mods = _modules_after(
        "from receiver.io.camera import load_camera\n"
        "from receiver.io.ledmap import load_map\n"
        "from receiver.locate.indoor import Positioner\n"
        "from receiver.pipeline import Receiver\n"
        f"cam = load_camera({str(STATIC / 'camera.yaml')!r})\n"
        f"m = load_map({str(STATIC / 'map.json')!r})\n"
        f"Receiver(cam, m, positioner=Positioner(cam, m), still={still})\n")
    assert not _loaded(mods, ("filterpy",))
    # the tracker's assignment and the solvers' fallbacks import scipy where they need it, which
    # a photo never does (0.8 s of a 1.0 s photo command); a stream preloads it.
    assert bool(_loaded(mods, ("scipy.optimize",))) is (not still)
    assert still is not bool(_loaded(mods, ("scipy",)))


def test_a_photo_run_imports_only_what_a_photo_uses(luxapose, tmp_path):
    """`occloc run PHOTO` (the real 33 MP photo): no scipy, no filterpy, nothing of NOT_FOR_RUN,
    and no numpy.ma (np.percentile's np.unique imported it for the summary line alone)."""
    out = tmp_path / "o.jsonl"
    mods = _modules_after(
        f"from receiver.cli import main\nassert main(['run', {str(luxapose / 'x_0_y_1.27.jpg')!r}, "
        f"'--camera', {str(luxapose / 'camera_lumia1020.yaml')!r}, '--map', {str(luxapose / 'map_test_rig.json')!r}, "
        f"'--out', {str(out)!r}]) == 0")
    assert json.loads(out.read_text())["position"]["n_leds"] == 5  # it did place the phone
    unused = ("scipy", "filterpy", "numpy.ma") + NOT_FOR_RUN
    assert not _loaded(mods, unused), _loaded(mods, unused)


def test_top_level_help_imports_no_ast_and_reads_each_help_line_once():
    mods = _modules_after("import builtins, receiver.cli as c\nopened = []\nreal = builtins.open\n"
                          "builtins.open = lambda f, *a, **k: (opened.append(str(f)), real(f, *a, **k))[1]\n"
                          "c.build_parser(c._available()).format_help()\nc._help_line('receiver.cli.run')\n"
                          "assert len(opened) == len(set(opened)) == len(c._available()), opened")
    assert not _loaded(mods, ("ast",)), "ast (9 M instructions) is not needed to read a HELP line"


@pytest.mark.parametrize("text", ['"one line"', "('a long'\n 'one, in two')", "'it''s'", '"tab\\there \\u00e9"',
                                  '(\n "x"\n)', "r'raw\\n'", "'''triple'''"])
def test_help_string_literal_is_what_ast_reads(text):
    import ast
    import receiver.cli as c
    assert c._string_literal(text) == ast.literal_eval(text)


@pytest.mark.parametrize("text", ["42", "-'a'", "'a' * 10_000", "__import__('os')", "x", "('a', 'b')", "f'{x}'",
                                  "(lambda: 'a')()", "'a'.upper()", "'unterminated", "'a' if x else 'b'"])
def test_help_string_literal_refuses_anything_else(text):
    import receiver.cli as c
    with pytest.raises((ValueError, SyntaxError)):
        c._string_literal(text)


def test_every_command_has_its_help_line():
    import ast
    import receiver.cli as c
    for name, module in c._available().items():
        tree = ast.parse(Path(c._find_spec(module).origin).read_text(encoding="utf-8"))
        want = next(ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
                    and [getattr(t, "id", None) for t in n.targets] == ["HELP"])
        assert want and c._help_line(module) == want, name


@pytest.mark.parametrize("argv,every", [(["run", "x"], False), (["--help"], True), ([], True),
                                        (["--he", "run"], True), (["-h", "run"], True),
                                        (["run", "--help"], False), (["--version", "run"], False),
                                        (["nosuch"], True)])
def test_other_commands_help_lines_are_read_only_when_the_top_level_help_can_show_them(argv, every):
    import receiver.cli as c
    selected = next((a for a in argv if not a.startswith("-")), None)
    selected = selected if selected in c._available() else None
    assert c._needs_every_help(argv, selected) is every


def test_top_level_help_after_a_command_name_still_lists_every_help_line(capsys):
    import receiver.cli as c
    with pytest.raises(SystemExit):
        cli(["-h", "run"])
    out = " ".join(capsys.readouterr().out.split())
    for module in c._available().values():
        assert " ".join(c._help_line(module).split()[:3]) in out
