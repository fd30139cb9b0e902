"""The vehicle locator alone on a recording's geometry: `python -m tools.locator_replay DIR`
feeds receiver.locate.vehicle.VehicleLocator PairObservations built from DIR/truth.jsonl (each
light's two emitters as projected, with Gaussian centroid noise; blobs within the saturation
ranges given bloomed and flagged saturated; an ID only once the light has been in view for a
whole packet) and scores the host and the cars ahead against the same truth. It tells what the
locator does when the pairing is right, apart from the pairing (receiver.vision.pairing);
`occloc run` + `occloc eval` score the whole receiver.

    python -m tools.locator_replay ../shared/independent/vehicle-s7
    python -m tools.locator_replay DIR --sl-saturated-within-m 60 --fv-saturated-within-m 40 --bloom 2.5

The truth is read here only (a tool), never inside the receiver.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from receiver.core.errors import InputError
from receiver.core.records import PairObservation
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.locate.vehicle import VehicleLocator


def truth_pairs(leds: list, t_s: float, first_seen: dict, rng, args) -> list[PairObservation]:
    """The frame's pairs from its truth `leds` (INTERFACES.md truth with `emitters`, `kind`):
    lights with both emitters visible and at least 1 px^2; `first_seen` (ID -> t_s) is kept up."""
    out = []
    for led in leds:
        em = led.get("emitters")
        if not em or len(em) != 2 or not all(e["visible"] and e["area_px"] >= 1.0 for e in em):
            first_seen.pop(led["id"], None)
            continue
        first_seen.setdefault(led["id"], t_s)
        kind = led.get("kind") or ("SL" if led["id"] <= 0x7F else "FV")       # PROTOCOL.md ID ranges
        within = args.sl_saturated_within_m if kind == "SL" else args.fv_saturated_within_m
        sat = led["distance_m"] < within
        a, b = ((e["cx"] + rng.normal(0, args.centroid_px), e["cy"] + rng.normal(0, args.centroid_px)) for e in em)
        area = [e["area_px"] * (args.bloom if sat else 1.0) for e in em]
        decoded = t_s - first_seen[led["id"]] >= args.packet_s
        out.append(PairObservation(key=(2 * led["id"], 2 * led["id"] + 1), led_id=led["id"] if decoded else None,
                                   kind=kind if decoded else None, a_px=a, b_px=b, area_a_px=area[0],
                                   area_b_px=area[1], separation_px=math.dist(a, b), both_visible=True,
                                   a_seen=(a, area[0], 0), b_seen=(b, area[1], 0), a_saturated=sat, b_saturated=sat))
    return out


def replay(folder: str, args) -> dict:
    loc = VehicleLocator(load_camera(f"{folder}/camera.yaml"), load_map(f"{folder}/map.json"))
    rng = np.random.default_rng(args.seed)
    first_seen: dict = {}
    hv_err, fv_rel, fv_bear, unmatched, wrong_id, frames = [], [], [], 0, 0, 0
    with open(f"{folder}/truth.jsonl") as f:
        for line in f:
            rec = json.loads(line)
            frames += 1
            vehicle = loc.step(rec["t"], truth_pairs(rec["leds"], rec["t"], first_seen, rng, args)).vehicle or {}
            tv = rec["vehicle"]
            hv = vehicle.get("hv")
            if hv is not None:
                hv_err.append(math.hypot(hv["x"] - tv["hv"]["x"], hv["y"] - tv["hv"]["y"]))
            for e in vehicle.get("fv", []):
                match = [x for x in tv["fv"] if e["id"] is not None and x["id"] == e["id"]] or \
                        [x for x in tv["fv"] if abs(x["angle_deg"] - e["angle_deg"]) < 2.0]
                if not match:
                    unmatched += 1
                    continue
                if e["id"] is not None and e["id"] != match[0]["id"]:
                    wrong_id += 1
                fv_rel.append(abs(e["distance_m"] / match[0]["distance_m"] - 1.0) * 100.0)
                fv_bear.append(abs(e["angle_deg"] - match[0]["angle_deg"]))

    def stat(v, q):
        return round(float(np.percentile(v, q)), 4) if v else None

    return {"frames": frames, "hv_placed": len(hv_err), "hv_2d_median_m": stat(hv_err, 50),
            "hv_2d_p95_m": stat(hv_err, 95), "hv_2d_max_m": stat(hv_err, 100), "fv_entries": len(fv_rel),
            "fv_unmatched": unmatched, "fv_wrong_id": wrong_id, "fv_distance_median_pct": stat(fv_rel, 50),
            "fv_distance_p95_pct": stat(fv_rel, 95), "fv_bearing_median_deg": stat(fv_bear, 50),
            "fv_bearing_p95_deg": stat(fv_bear, 95), "unplaced": loc.unplaced}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.locator_replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", help="recording folders with camera.yaml, map.json, truth.jsonl "
                                               "(truth with per-light `emitters` and `kind`)")
    ap.add_argument("--centroid-px", type=float, default=0.2, help="centroid noise 1-sigma, px [0.2]")
    ap.add_argument("--bloom", type=float, default=2.5, help="a saturated blob's area over its emitter's [2.5]")
    ap.add_argument("--sl-saturated-within-m", type=float, default=60.0, help="street lights saturate within [60]")
    ap.add_argument("--fv-saturated-within-m", type=float, default=40.0, help="taillights saturate within [40]")
    ap.add_argument("--packet-s", type=float, default=2.4, help="in view this long before its ID is known [2.4]")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    for folder in args.folders:
        try:
            print(folder, json.dumps(replay(folder, args)))
        except (InputError, OSError, ValueError, KeyError) as e:
            print(f"locator_replay: {folder}: {e}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
