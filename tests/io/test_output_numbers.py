"""The JSON lines' numbers (receiver.io.output._num) are Python's round to the bit, its short
path included: random values, decimal ties and values a hair off them, zeros of both signs."""

import math

import numpy as np

from receiver.io.output import _num


def test_num_is_round_to_the_bit():
    rng = np.random.default_rng(3)
    for nd in (1, 2, 3, 4, 6):
        ties = [(int(k) * 10 + 5) / 10 ** (nd + 1) for k in rng.integers(-10 ** 6, 10 ** 6, 20000)]
        vals = (rng.normal(0.0, 1000.0, 20000).tolist() + rng.uniform(-2.0, 2.0, 20000).tolist() + ties
                + [t * (1 + 1e-15) for t in ties] + [0.0, -0.0, 1e-9, -1e-9, -0.005, 0.005, 1e12, -1e12, 5e-7])
        for v in vals:
            got, want = _num(v, nd), round(v, nd)
            assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want), (v, nd)


def test_num_none_for_missing_and_non_finite():
    assert _num(None, 2) is None and _num(math.nan, 2) is None and _num(-math.inf, 3) is None
    assert _num(np.float32(1.25), 1) == round(float(np.float32(1.25)), 1)
