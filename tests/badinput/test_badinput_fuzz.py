"""Seeded mutation fuzz of every input-file parser of receiver.io: camera.yaml, map.json,
truth.jsonl, run JSON Lines and odometry. Each mutation of a valid file must either load or
raise InputError (one line); any other exception, or a crash, fails. Bounded: N_MUTATIONS per
format, each parser call on a small file."""

from __future__ import annotations

import json
import os
import random

import pytest

from receiver.core.errors import InputError
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.io.odometry import load_odometry
from receiver.io.truth import load_run, load_truth

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STATIC = os.path.join(ROOT, "recordings", "indoor-static")
VEHICLE = os.path.join(ROOT, "recordings", "vehicle")
N_MUTATIONS = 200

TOKENS = [b"[", b"]", b"{", b"}", b"nan", b"NaN", b".nan", b"-.inf", b"Infinity", b"1e400", b"-1", b"0",
          b"1e-300", b"1e300", b"\"x\"", b"null", b"true", b"\x00", b"\xff", b"9" * 5000, b",", b":", b"\n",
          b"[" * 3000, b"{\"a\":" * 500, b"!!opencv-matrix", b"  ", b"- ", b"%YAML 1.0"]


def mutate(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(6)
        i = rng.randrange(len(b) + 1)
        if op == 0 and b:           # flip a byte
            b[min(i, len(b) - 1)] = rng.randrange(256)
        elif op == 1:               # insert a token
            b[i:i] = rng.choice(TOKENS)
        elif op == 2 and b:         # delete a span
            del b[i:i + rng.randint(1, 40)]
        elif op == 3:               # truncate
            del b[i:]
        elif op == 4 and b:         # duplicate a span
            j = rng.randrange(len(b))
            b[i:i] = b[j:j + rng.randint(1, 200)]
        else:                       # replace a number by a token
            nums = [k for k in range(len(b)) if chr(b[k]).isdigit()]
            if nums:
                k = rng.choice(nums)
                b[k:k + 1] = rng.choice(TOKENS)
    return bytes(b)


def _small_jsonl(path: str, n: int) -> bytes:
    with open(path, "rb") as f:
        return b"".join(f.readline() for _ in range(n))


def _odometry() -> bytes:
    return b"".join(json.dumps({"t": k * 0.1, "speed_mps": 10 + k}).encode() + b"\n" for k in range(5))


def _truth_for_run():
    return load_truth(os.path.join(STATIC, "truth.jsonl"))


def _run_lines() -> bytes:
    lines = [{"frame": k, "t": k / 30, "latency_ms": 5.0,
              "leds": [{"track": 1, "id": 1, "mode": "ook", "cx": 10.0, "cy": 20.0, "area_px": 30.0,
                        "distance_m": 2.0, "distance_estimator": "area"}],
              "position": {"x": 1.0, "y": 2.0, "z": 1.0, "raw": {"x": 1.0, "y": 2.0, "z": 1.0}},
              "vehicle": {"hv": {"x": 1.0, "y": 2.0, "std_m": 0.1}, "fv": [{"id": 3, "distance_m": 5.0}]}}
             for k in range(3)]
    return b"".join(json.dumps(o).encode() + b"\n" for o in lines)


FORMATS = {
    "camera": (lambda: open(os.path.join(STATIC, "camera.yaml"), "rb").read(), "camera.yaml", load_camera),
    "map": (lambda: open(os.path.join(VEHICLE, "map.json"), "rb").read(), "map.json", load_map),
    "truth": (lambda: _small_jsonl(os.path.join(VEHICLE, "truth.jsonl"), 2), "truth.jsonl", load_truth),
    "run": (_run_lines, "run.jsonl", None),
    "odometry": (_odometry, "odo.jsonl", load_odometry),
}


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_mutated_files_load_or_raise_input_error(tmp_path, fmt):
    make, name, load = FORMATS[fmt]
    valid = make()
    truth = _truth_for_run() if fmt == "run" else None
    if load is None:
        def load(p):
            return load_run(p, truth)
    p = tmp_path / name
    p.write_bytes(valid)
    load(str(p))  # the unmutated file loads
    rng = random.Random(f"occloc-{fmt}")
    outcomes = {"ok": 0, "InputError": 0}
    for k in range(N_MUTATIONS):
        data = mutate(valid, rng)
        p.write_bytes(data)
        try:
            load(str(p))
            outcomes["ok"] += 1
        except InputError as e:
            assert "\n" not in str(e), (k, str(e)[:200])
            outcomes["InputError"] += 1
        except Exception as e:  # noqa: BLE001 - the point of the test
            raise AssertionError(f"{fmt} mutation {k}: {type(e).__name__}: {e!s:.200} on {data[:300]!r}") from None
    assert sum(outcomes.values()) == N_MUTATIONS
    print(fmt, outcomes)
