"""The OOK decoder's four accumulators live as the rows of one (4, 54) array: the packed
kernels (decay4, add4) equal np.bincount sums and a row-wise decay, and every update keeps the
views."""

from __future__ import annotations

import numpy as np
import pytest

from receiver.core.native import require
from receiver.decode.ook import PACKET_LEN, OokDecoder, _cyclic_index

_k = require("receiver.decode._ook")


@pytest.mark.parametrize("extra", [-1, 2, 3])
def test_packed_kernels_equal_bincount_sums(extra):
    """add4 / decay4 equal np.bincount sums of the chips at their packet positions and a row-wise
    decay, bit for bit."""
    rng = np.random.default_rng(extra + 5)
    acc4 = rng.normal(size=(4, PACKET_LEN))
    rows = acc4.copy()
    for shift in (0, 7, -3, 60):
        soft, cw = rng.normal(size=40), rng.uniform(0, 1, 40)
        _k.add4(acc4, extra, soft, cw, shift)
        pos = _cyclic_index(soft.size)[shift % PACKET_LEN]
        w = np.bincount(pos, cw, PACKET_LEN)
        rows[0] += np.bincount(pos, cw * soft, PACKET_LEN)
        rows[1] += w
        if extra > 0:
            rows[extra] += w
        _k.decay4(acc4, 0.93)
        rows *= 0.93
        assert np.array_equal(acc4, rows)
    with pytest.raises(ValueError):
        _k.add4(np.zeros((3, PACKET_LEN)), -1, soft, cw, 0)


def test_accumulators_stay_rows_of_one_array():
    dec = OokDecoder(2000.0, 15.0)
    dec.acc[:] = np.arange(PACKET_LEN)
    dec.acc_w[:] = 1.0
    dec._rotate(5)
    for i, name in enumerate(("acc", "acc_w", "trust_w", "timed_w")):
        assert np.shares_memory(getattr(dec, name), dec._acc4[i])
    assert dec.acc[0] == 5.0 and dec.acc[-1] == 4.0
    dec._clear()
    assert not dec._acc4.any()
