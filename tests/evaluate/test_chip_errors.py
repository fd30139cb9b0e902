"""tools.chip_errors: the wrong-chip rates of frames by distance from their ends."""

from __future__ import annotations

import numpy as np

from receiver.decode.ook import packet_template
from tools.chip_errors import chip_errors, main


def test_end_chips_read_off_count_at_the_ends_only():
    """Frames of 20 chips of one ID's packet at several shifts, the first chip of every frame
    and the last of every other frame flipped: the first chip is wrong in all frames, the last
    in half, the chips inside never; every frame fits its packet (19 of 20 chips), and without
    its end chips it fits perfectly."""
    t = packet_template(0xBEEF)
    frames = []
    for k, s in enumerate(range(0, 54, 6)):
        x = t[(s + np.arange(20)) % 54].copy()
        x[0] = -x[0]
        if k % 2:
            x[-1] = -x[-1]
        frames.append((0xBEEF, x))
    r = chip_errors(frames)
    assert r["frames"] == 9
    assert r["head"][0] == 1.0 and r["head"][1:] == [0.0, 0.0, 0.0]
    assert r["tail"][0] == 4 / 9 and r["inner"] == 0.0
    assert r["fit_share_inner"] == 1.0


def test_a_folder_without_truth_is_a_one_line_error(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no truth.jsonl" in err
