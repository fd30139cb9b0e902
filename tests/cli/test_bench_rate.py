"""`occloc bench`: frames/s counts the timed frames only, never the receivers' set-up."""

from __future__ import annotations

import types

import pytest

import receiver.cli.bench as bench
from receiver.cli.benchscene import bench_frames


class FakeClock:
    """Advances 1 ms per reading."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        self.t += 0.001
        return self.t


def test_run_bench_time_excludes_receiver_setup(monkeypatch):
    cam, led_map, frames = bench_frames(3)
    clock = FakeClock()
    real = bench.whole_receiver

    def slow_setup(*a, **k):
        clock.t += 100.0  # a receiver whose set-up takes 100 s of the clock
        return real(*a, **k)
    monkeypatch.setattr(bench, "whole_receiver", slow_setup)
    stats, seconds = bench.run_bench(cam, led_map, frames, repeat=2, whole=True, elapsed=clock)
    assert stats.summary()["frames"] == 6
    assert 0 < seconds < 1.0  # the 200 s of set-up are not in it


def test_bench_case_rate_is_frames_over_timed_seconds(monkeypatch):
    cam, led_map, frames = bench_frames(4)
    monkeypatch.setattr(bench, "load_case", lambda *a: (cam, led_map, frames, False))
    real = bench.run_bench

    def fixed(*a, **k):
        stats, _ = real(*a, **k)
        return stats, 2.0
    monkeypatch.setattr(bench, "run_bench", fixed)
    args = types.SimpleNamespace(frames=4, camera=None, map=None, repeat=1, clock="cpu")
    row = bench.bench_case("synthetic", args)
    assert row["frames"] == 4 and row["frames_per_s"] == pytest.approx(2.0)
