"""Golden per-stage data of the bundled recordings (tests/golden/NAME.json, written by
`python -m tools.golden`): each recording run through `occloc run` and `occloc eval --json` must
give the stored per-frame LED hashes (detection and tracking: track, centroid to 0.01 px, area to
0.1 px^2), the stored first decode of every track (ID and frame) exactly, and the stored eval
metrics (ID rate, wrong IDs, distance and position errors) to a relative 1e-6.

A change meant to alter the receiver's output: regenerate with `python -m tools.golden` and
review the diff of tests/golden/ (one frame / track / metric per line)."""

from __future__ import annotations

import pytest

from tools import golden


@pytest.fixture(scope="module", params=golden.NAMES)
def record(request):
    name = request.param
    path = golden.golden_path(name)
    assert path.is_file(), f"missing {path}: run `{golden.REGENERATE}` to write it"
    return name, golden.load(name), golden.compute(name)


def _fail(name: str, what: str, diff: list[str]) -> str:
    return (f"recordings/{name}: {what} differ from tests/golden/{name}.json:\n  " + "\n  ".join(diff)
            + f"\nIf the change is intended, regenerate with `{golden.REGENERATE}` and review the diff.")


def test_golden_blob_hashes_per_frame(record):
    name, stored, now = record
    diff = [d for d in golden.differences(stored, now, limit=10 ** 6) if d.startswith(("frame", "frames"))]
    assert not diff, _fail(name, "detected LEDs (per-frame hashes)", diff[:10])


def test_golden_first_decode_per_track(record):
    name, stored, now = record
    diff = [d for d in golden.differences(stored, now, limit=10 ** 6) if d.startswith("track")]
    assert not diff, _fail(name, "decoded IDs per track", diff[:10])


def test_golden_eval_metrics(record):
    name, stored, now = record
    diff = [d for d in golden.differences(stored, now, limit=10 ** 6) if d.startswith("metric")]
    assert not diff, _fail(name, "eval metrics", diff[:10])


def test_golden_differences_name_the_frame_and_track():
    """The comparison itself: a changed blob, track and metric are each reported by name."""
    stored = {"frames": [{"frame": 0, "n": 1, "hash": "a"}, {"frame": 1, "n": 1, "hash": "b"}],
              "blobs": [[[0, 1.0, 2.0, 3.0]], [[0, 1.5, 2.0, 3.0]]],
              "tracks": {"0": {"id": 7, "frame": 1}}, "metrics": {"id_rate": 0.5, "wrong_ids": 0}}
    now = {"frames": [{"frame": 0, "n": 1, "hash": "a"}, {"frame": 1, "n": 1, "hash": "c"}],
           "blobs": [[[0, 1.0, 2.0, 3.0]], [[0, 1.51, 2.0, 3.0]]],
           "tracks": {"0": {"id": 8, "frame": 1}}, "metrics": {"id_rate": 0.5 + 1e-12, "wrong_ids": 1}}
    diff = golden.differences(stored, now)
    assert len(diff) == 3, diff
    assert diff[0].startswith("frame 1:") and "[0, 1.51, 2.0, 3.0]" in diff[0]
    assert diff[1].startswith("track 0:") and "'id': 8" in diff[1]
    assert diff[2] == "metric wrong_ids: stored 0, now 1"
