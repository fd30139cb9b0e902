"""`occloc bench` and the whole-frame budget benchmark (pytest-benchmark)."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest

from receiver.cli.bench import callgrind_total, count_instructions, load_case, whole_receiver
from receiver.cli.benchscene import bench_frames, bench_ids, bench_scene
from receiver.core.budget import one_core
from receiver.cli import main as cli
from receiver.pipeline import Receiver


def test_bench_command_prints_stage_table(capsys):
    assert cli(["bench", "--frames", "4"]) == 0
    out = capsys.readouterr().out
    assert "4 frames 1280x720" in out and "frames/s" in out
    for stage in ("detect", "track", "decode", "output", "total"):
        assert any(line.startswith(stage) for line in out.splitlines())


def test_one_core_sets_opencv_to_one_thread_and_restores_it():
    before = cv2.getNumThreads()
    with one_core():
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before


def test_bench_command_on_a_photo(luxapose, capsys):
    assert cli(["bench", str(luxapose / "small_blob.jpg"), "--camera", str(luxapose / "camera_lumia1020.yaml"),
                "--map", str(luxapose / "map_test_rig.json"), "--repeat", "2"]) == 0
    assert "2 frames 7712x4352" in capsys.readouterr().out


def test_bench_scene_is_what_it_claims():
    leds = bench_scene()
    assert len(leds) == 16 and len(set(bench_ids())) == 16
    xy = np.array([(led.cx, led.cy) for led in leds])
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) + np.eye(16) * 1e9
    assert d.min() > 2.5 * leds[0].radius_px  # separate lights


def test_bench_whole_frame_budget(benchmark):
    """Budget case: 1280x720, 16 LEDs, steady state (IDs decoded), one frame, one core."""
    cam, led_map, frames = bench_frames(12)
    rx = Receiver(cam, led_map)
    for f in frames[:-1]:
        rx.process(f)
    with one_core():
        res = benchmark(rx.process, frames[-1])
    assert len(res.leds) == 16 and sum(o.id is not None for o in res.leds) >= 14


# ---------------------------------------------------------------- the whole pipeline

def _whole_cases():
    from receiver.cli.bench import SCENE, bundled_recordings
    return bundled_recordings() + [SCENE]


@pytest.mark.parametrize("spec", _whole_cases(), ids=lambda s: os.path.basename(s))
def test_whole_frame_of_each_case(benchmark, spec):
    """One steady-state frame of the whole pipeline (`occloc run`'s receiver: positioning and the
    vehicle stage included) of each bundled recording and of the synthetic scene, one core,
    frames decoded beforehand; benchmark rounds walk through the recording's frames."""
    cam, led_map, frames, still = load_case(spec, 300)
    warm = min(10, len(frames) // 3)
    rx = whole_receiver(cam, led_map, still=still)
    for f in frames[:warm]:
        rx.process(f)
    rest = iter(frames[warm:])
    with one_core():
        res = benchmark.pedantic(rx.process, setup=lambda: ((next(rest),), {}), rounds=len(frames) - warm,
                                 iterations=1)
    assert res.leds and res.frame == frames[warm + (len(frames) - warm - 1 if benchmark.enabled else 0)].index


def test_bench_json_runs_the_whole_pipeline_on_the_scene(capsys):
    assert cli(["bench", "--scene-only", "--frames", "12", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["one_core"] and out["frames_predecoded"] and out["clock"] == "cpu"
    (case,) = out["cases"]
    assert case["case"] == "synthetic" and case["frames"] == 12 and case["size"] == [1280, 720]
    assert {"detect", "track", "decode", "report", "locate", "output"} <= set(case["stages"])
    assert case["total"]["median_ms"] >= case["stages"]["locate"]["median_ms"] > 0


def test_bench_scene_map_has_the_rendered_geometry():
    """The scene's map is the camera's view: the whole pipeline places the camera where the
    rendered drift puts it (0.7, 0.3 px/frame at 3 m and f = 1000 px)."""
    cam, led_map, frames, _ = load_case("synthetic", 16)
    rx = whole_receiver(cam, led_map)
    errs = []
    for f in frames:
        res = rx.process(f)
        if res.position is not None:
            truth = np.array([-0.7, -0.3, 0.0]) * 3.0 / 1000.0 * f.index
            errs.append(np.linalg.norm([res.position[k] for k in "xyz"] - truth))
    assert len(errs) >= 6 and max(errs) < 0.003, errs


@pytest.mark.slow
def test_bench_recording_case_is_the_run_pipeline(tmp_path):
    """A recording's bench case processes the frames `occloc run` does, with the same receiver:
    the same JSON lines (without latency)."""
    from receiver.io.output import frame_line
    rec = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "recordings", "indoor-static")
    out = tmp_path / "o.jsonl"
    assert cli(["run", rec, "--out", str(out)]) == 0
    cam, led_map, frames, still = load_case(rec, 300)
    rx = whole_receiver(cam, led_map, still=still)

    def strip(line):
        d = json.loads(line)
        d.pop("latency_ms")
        d.pop("no_fix", None)  # the command's note on a frame without a position
        return d

    assert [strip(frame_line(rx.process(f))) for f in frames] == [strip(x) for x in out.read_text().splitlines()]


def test_instructions_are_skipped_with_a_note_without_valgrind(monkeypatch, capsys):
    monkeypatch.setattr("shutil.which", lambda name: None)
    c = count_instructions("synthetic", 2)
    assert c["instructions_per_frame"] is None and "valgrind not installed" in c["note"]
    assert cli(["bench", "--scene-only", "--frames", "3", "--instructions"]) == 0
    assert "instructions/frame: - (valgrind not installed" in capsys.readouterr().out


def test_instruction_count_child_processes_the_counted_frames(capsys):
    # what runs under callgrind: W warm frames, then K inside functools.reduce
    assert cli(["bench", "--_count", "synthetic", "2", "3"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == {"frames": 3}


def test_callgrind_total_reads_the_summary_line(tmp_path):
    p = tmp_path / "cg.out"
    p.write_text("version: 1\ncreator: callgrind\nevents: Ir\nfn=x\n1 5\nsummary: 123456\ntotals: 123456\n")
    assert callgrind_total(str(p)) == 123456


def test_bench_scale_renders_the_requested_size_and_reports_per_megapixel(capsys):
    assert cli(["bench", "--scale", "1920x1080", "--frames", "3", "--json"]) == 0
    (case,) = json.loads(capsys.readouterr().out)["cases"]
    assert case["case"] == "synthetic@1920x1080" and case["size"] == [1920, 1080] and case["frames"] == 3
    assert case["mp"] == pytest.approx(1920 * 1080 / 1e6)
    assert case["ms_per_mp"] == pytest.approx(case["total"]["median_ms"] / case["mp"])


def test_bench_scaled_scene_is_the_same_scene():
    """At twice the size the built-in scene's discs are twice as big and as many, the camera's
    focal length doubles and its rows take half the time, and the map is the same."""
    from receiver.cli.bench import scaled_scene
    cam1, map1, f1, _ = load_case("synthetic", 1)
    cam2, map2, f2, _ = scaled_scene("synthetic", (2560, 1440), 1)
    assert f2[0].gray.shape == (1440, 2560) and (cam2.width, cam2.height) == (2560, 1440)
    assert cam2.K[0, 0] == 2 * cam1.K[0, 0] and cam2.row_readout_us == cam1.row_readout_us / 2
    assert sorted(map2.leds) == sorted(map1.leds)
    xyz1 = np.array([map1.leds[i].xyz for i in sorted(map1.leds)])
    xyz2 = np.array([map2.leds[i].xyz for i in sorted(map1.leds)])
    assert np.abs(xyz2 - xyz1).max() < 1e-3  # up to the half pixel of the principal point
    lit1 = (f1[0].gray > 100).sum()
    lit2 = (f2[0].gray > 100).sum()
    assert 3.5 < lit2 / lit1 < 4.5


def test_bench_scale_indoor_walk_renders_the_synth_scene(capsys):
    assert cli(["bench", "--scale", "640x360", "--scale-scene", "indoor-walk", "--frames", "2", "--json"]) == 0
    (case,) = json.loads(capsys.readouterr().out)["cases"]
    assert case["case"] == "indoor-walk@640x360" and case["size"] == [640, 360] and case["mp"] > 0


@pytest.mark.parametrize("bad", [["--scale", "1920"], ["--scale", "axb"], ["--scale", "10x10"],
                                 ["--scale", "1920x1080", "recordings/vehicle"]])
def test_bench_scale_rejects_bad_sizes(bad, capsys):
    assert cli(["bench", *bad]) != 0
    err = capsys.readouterr().err
    assert "scale" in err and "Traceback" not in err
