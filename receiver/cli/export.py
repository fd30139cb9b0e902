"""`occloc export`: a run's JSON Lines (or a recording's truth.jsonl) as a TUM trajectory (for
evo), CSV or GeoJSON (`receiver.evaluate.export`)."""

from __future__ import annotations

import os
import sys

HELP = "convert a run's JSON lines (or truth.jsonl) to a TUM trajectory (evo), CSV or GeoJSON"


def add_arguments(p) -> None:
    p.add_argument("run", metavar="RUN.jsonl", help="output of `occloc run --out`, or a recording's truth.jsonl")
    p.add_argument("--format", required=True, choices=("tum", "csv", "geojson"),
                   help="tum: 't x y z qx qy qz qw' per pose (evo_traj, evo_ape); csv: one row per frame; "
                        "geojson: points and track in WGS 84 (needs --origin)")
    p.add_argument("--out", metavar="FILE", help="write here (default: standard output); its extension must "
                                                 "fit the format (.tum/.txt, .csv, .geojson/.json)")
    p.add_argument("--raw", action="store_true",
                   help="each frame's own fix (position.raw) instead of the filtered position")
    p.add_argument("--origin", metavar="LAT,LON",
                   help="geojson: latitude,longitude (degrees) of the map's (0, 0); x is east, y north")


def main(args) -> int:
    from receiver.core.errors import InputError
    from receiver.evaluate import export
    from receiver.io.files import claim_output, dumps, read_jsonl

    output = claim_output(args.out, [args.run], "--out")
    if args.out is not None:
        ext = os.path.splitext(args.out)[1].lower()
        # no extension: a device or pipe (/dev/stdout, /dev/null) or a name of the user's choice
        if ext and ext not in export.EXTENSIONS[args.format]:
            raise InputError(f"--out {args.out}: a {args.format} file ends in "
                             f"{' or '.join(export.EXTENSIONS[args.format])}, not {ext}")
    origin = export.parse_origin(args.origin) if args.format == "geojson" else None
    lines = [obj for _, obj in read_jsonl(args.run, "run")]
    note = ""
    if args.format == "tum":
        text, missing = export.to_tum(lines, raw=args.raw)
        if missing:
            note = f"; {missing} poses without an orientation left out"
        if export.photo_times(lines):
            note += "; photos have no time of their own: t is the frame number"
        n = text.count("\n")
    elif args.format == "csv":
        text = export.to_csv(lines, raw=args.raw)
        n = text.count("\n") - 1
    else:
        obj = export.to_geojson(lines, origin, raw=args.raw)
        text = dumps(obj, separators=(",", ":")) + "\n"
        n = sum(f["geometry"]["type"] == "Point" for f in obj["features"])
    if args.format != "csv" and n == 0:
        raise InputError(f"{args.run}: no frame with a position to export")
    if args.out is None:
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        with output.open() as out:
            out.write(text)
    kind = export.trajectory_kind(lines)
    what = {"truth": "truth camera poses", "position": "positions", "hv": "host-vehicle poses"}[kind]
    print(f"occloc: {n} {'rows' if args.format == 'csv' else what} of {len(lines)} lines written"
          f"{' to ' + args.out if args.out else ''}{note}", file=sys.stderr)
    return 0
