"""`occloc run` with each frame's camera shift taken from the truth camera (a measuring tool,
never the receiver): `python -m tools.truth_shift_run FOLDER OUT.jsonl`.

The shift the receiver's tracks and S2-PSK pairs are moved by (receiver.pipeline.Receiver's
`_frame_shift`) becomes the truth camera's yaw and pitch change since the previous frame times
the focal length (px; roll and the lights' own motion are left to the pairs). It tells what the
pairing does given a right camera-motion estimate, apart from that estimate;
`tools.vehicle_score --truth-shift` scores it. The truth is read here only.
"""

from __future__ import annotations

import json
import math
import sys


def truth_shift(folder: str):
    """The `_frame_shift(self, blobs)` replacement for recording `folder`."""
    from receiver.io.camera import load_camera

    cams = {}
    with open(f"{folder}/truth.jsonl") as f:
        for line in f:
            d = json.loads(line)
            cams[d["frame"]] = d["camera"]
    focal = load_camera(f"{folder}/camera.yaml").fx

    def shift(self, blobs):
        k = self.frames
        if k - 1 not in cams or k not in cams:
            return None
        a, b = cams[k - 1], cams[k]
        return (focal * math.radians(b["yaw"] - a["yaw"]), focal * math.radians(b["pitch"] - a["pitch"]))
    return shift


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m tools.truth_shift_run FOLDER OUT.jsonl", file=sys.stderr)
        return 2
    from pathlib import Path
    if not all((Path(argv[0]) / f).is_file() for f in ("truth.jsonl", "camera.yaml")):
        print(f"tools.truth_shift_run: {argv[0]}: no truth.jsonl and camera.yaml there", file=sys.stderr)
        return 2
    import receiver.pipeline as pipeline
    from receiver.cli import main as occloc

    pipeline.Receiver._frame_shift = truth_shift(argv[0])
    return occloc(["run", argv[0], "--out", argv[1]])


if __name__ == "__main__":
    sys.exit(main())
