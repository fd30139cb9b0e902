"""Golden per-stage data of the bundled recordings: `python -m tools.golden` rewrites
tests/golden/NAME.json for each of recordings/indoor-walk, indoor-static and vehicle;
tests/pipeline/test_golden.py recomputes them and compares.

Each recording is run once through `occloc run RECORDING --out FILE` (its own camera.yaml and
map.json, default settings) and scored by `occloc eval FILE --truth truth.jsonl --json`. Stored:

- `frames`: per frame, the number of reported LEDs and a compact hash of what detection and
  tracking gave (the LEDs sorted by track: track, cx and cy rounded to 0.01 px, area to
  0.1 px^2; the values `occloc run` writes) -- `blobs` lists the same values in the clear, so a
  difference can be shown, not only detected;
- `tracks`: per track, the first decoded ID and the frame of that decode (decode stage);
- `metrics`: `occloc eval --json`'s ID rate, right and wrong IDs, matched LED-frames, distance
  error medians and position error median/p95 where present (latency is left out: it is
  machine time).

    .venv/bin/python -m tools.golden                 # rewrite all three
    .venv/bin/python -m tools.golden indoor-static   # rewrite one
    .venv/bin/python -m tools.golden --check         # compare only (exit 1 on a difference)

Regenerate (and review the diff) after a change that is meant to alter the receiver's output.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = ROOT / "recordings"
GOLDEN = ROOT / "tests" / "golden"
NAMES = ("indoor-walk", "indoor-static", "vehicle")
REGENERATE = "python -m tools.golden"
FORMAT = 1


def blob_key(led: dict) -> list:
    """One reported LED as stored: [track, cx (0.01 px), cy (0.01 px), area (0.1 px^2)]."""
    return [int(led["track"]), round(float(led["cx"]), 2), round(float(led["cy"]), 2),
            round(float(led["area_px"]), 1)]


def frame_hash(keys: list) -> str:
    """12 hex digits of the SHA-1 of the frame's sorted LED keys."""
    return hashlib.sha1(json.dumps(sorted(keys)).encode()).hexdigest()[:12]


def _pick(metrics: dict) -> dict:
    """The eval metrics kept (None where the recording has none)."""
    def get(*path):
        v = metrics
        for p in path:
            if not isinstance(v, dict) or p not in v:
                return None
            v = v[p]
        return v

    out = {k: metrics.get(k) for k in ("frames", "matched_led_frames", "ids_correct", "wrong_ids", "id_rate")}
    out["distance_rel_error_p50"] = get("distance_rel_error", "p50")
    out["distance_rel_error_n"] = get("distance_rel_error", "n")
    for b in get("distance_rel_error", "by_area_px") or []:
        out[f"distance_rel_error_p50_area_{b['area_px']}"] = b.get("p50")
    for kind in ("filtered", "raw"):
        for q in ("p50", "p95"):
            out[f"position_error_m_{kind}_{q}"] = get("position_error_m", kind, q)
    return out


def run_and_eval(folder: Path, out_path: Path) -> dict:
    """`occloc run FOLDER --out OUT` then `occloc eval OUT --truth --json`, in this process."""
    from receiver.cli import main as cli

    with contextlib.redirect_stderr(io.StringIO()):
        rc = cli(["run", str(folder), "--out", str(out_path)])
    if rc != 0:
        raise RuntimeError(f"occloc run {folder} failed (exit {rc})")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        rc = cli(["eval", str(out_path), "--truth", str(folder / "truth.jsonl"), "--json"])
    if rc != 0:
        raise RuntimeError(f"occloc eval of {folder} failed (exit {rc})")
    return json.loads(buf.getvalue())


def compute(name: str) -> dict:
    """The golden record of recordings/NAME (see the module docstring)."""
    folder = RECORDINGS / name
    with tempfile.TemporaryDirectory() as tmp:
        out_path = Path(tmp) / "run.jsonl"
        metrics = run_and_eval(folder, out_path)
        lines = [json.loads(line) for line in out_path.read_text().splitlines() if line.strip()]
    frames, blobs, tracks = [], [], {}
    for line in lines:
        keys = sorted(blob_key(led) for led in line["leds"])
        frames.append({"frame": line["frame"], "n": len(keys), "hash": frame_hash(keys)})
        blobs.append(keys)
        for led in line["leds"]:
            if led.get("id") is not None:
                tracks.setdefault(str(led["track"]), {"id": int(led["id"]), "frame": int(line["frame"])})
    tracks = dict(sorted(tracks.items(), key=lambda kv: int(kv[0])))
    return {"format": FORMAT, "recording": f"recordings/{name}", "regenerate": REGENERATE,
            "frames": frames, "tracks": tracks, "metrics": _pick(metrics), "blobs": blobs}


def dump(record: dict) -> str:
    """The stored text: one frame (or track) per line, so a diff shows which one changed."""
    parts = ["{"]
    items = list(record.items())
    for i, (k, v) in enumerate(items):
        sep = "," if i < len(items) - 1 else ""
        if k in ("frames", "blobs") and v:
            body = ",\n".join("    " + json.dumps(x, separators=(",", ":")) for x in v)
            parts.append(f'  "{k}": [\n{body}\n  ]{sep}')
        elif k in ("tracks", "metrics") and v:
            body = ",\n".join(f"    {json.dumps(a)}: {json.dumps(b)}" for a, b in v.items())
            parts.append(f'  "{k}": {{\n{body}\n  }}{sep}')
        else:
            parts.append(f"  {json.dumps(k)}: {json.dumps(v)}{sep}")
    parts.append("}")
    return "\n".join(parts) + "\n"


def golden_path(name: str) -> Path:
    return GOLDEN / f"{name}.json"


def load(name: str) -> dict:
    return json.loads(golden_path(name).read_text())


METRIC_REL_TOL = 1e-6
METRIC_ABS_TOL = 1e-9


def differences(stored: dict, now: dict, limit: int = 10) -> list[str]:
    """Human-readable differences (empty: equal): frame hashes and track IDs exactly, metrics
    to a relative 1e-6."""
    out: list[str] = []
    sf, nf = stored["frames"], now["frames"]
    if len(sf) != len(nf):
        out.append(f"frames: {len(sf)} stored, {len(nf)} now")
    for a, b, ka, kb in zip(sf, nf, stored.get("blobs", [None] * len(sf)), now["blobs"]):
        if a != b:
            msg = f"frame {b['frame']}: LEDs {a['n']} stored, {b['n']} now, hash {a['hash']} -> {b['hash']}"
            if ka is not None:
                gone = [k for k in ka if k not in kb]
                new = [k for k in kb if k not in ka]
                msg += f"; [track, cx, cy, area] stored only {gone[:4]}, now only {new[:4]}"
            out.append(msg)
    st, nt = stored["tracks"], now["tracks"]
    for tr in sorted(set(st) | set(nt), key=int):
        if st.get(tr) != nt.get(tr):
            out.append(f"track {tr}: first decode stored {st.get(tr)}, now {nt.get(tr)}")
    sm, nm = stored["metrics"], now["metrics"]
    for k in sorted(set(sm) | set(nm)):
        a, b = sm.get(k), nm.get(k)
        if isinstance(a, (int, float)) and isinstance(b, (int, float)):
            if abs(a - b) <= max(METRIC_ABS_TOL, METRIC_REL_TOL * abs(a)):
                continue
        elif a == b:
            continue
        out.append(f"metric {k}: stored {a}, now {b}")
    if len(out) > limit:
        out = out[:limit] + [f"... and {len(out) - limit} more"]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.golden", description=__doc__.split("\n\n")[0])
    p.add_argument("names", nargs="*", metavar="NAME", help=f"recordings ({', '.join(NAMES)}; default all)")
    p.add_argument("--check", action="store_true", help="compare with the stored files, write nothing")
    args = p.parse_args(argv)
    names = args.names or list(NAMES)
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        p.error(f"unknown recording {', '.join(unknown)} (choose from {', '.join(NAMES)})")
    GOLDEN.mkdir(parents=True, exist_ok=True)
    bad = 0
    for name in names:
        rec = compute(name)
        if args.check:
            diff = differences(load(name), rec) if golden_path(name).exists() else ["no stored file"]
            bad += bool(diff)
            print(f"{name}: " + ("same" if not diff else "DIFFERS\n  " + "\n  ".join(diff)))
        else:
            golden_path(name).write_text(dump(rec))
            m = rec["metrics"]
            print(f"wrote {golden_path(name).relative_to(ROOT)}: {len(rec['frames'])} frames, "
                  f"{len(rec['tracks'])} decoded tracks, id_rate {m['id_rate']}, wrong {m['wrong_ids']}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
