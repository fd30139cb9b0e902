"""S2pskDecoder.folded_sums against known truth: noise-free samples of a packet fold to its
symbols, counted once per sample, at the sample times' own symbol phase; and the per-ID best
score of `best_per_id`."""

import numpy as np
import pytest

from firmware_tx.framing import s2psk_packet
from receiver.decode import s2psk
from receiver.decode.s2psk import PACKET_LEN, S2pskDecoder


@pytest.mark.parametrize("seed", range(8))
def test_fold_of_clean_samples_is_the_packet(seed):
    """Samples at 30 fps of a +-1 packet (random start, a symbol-grid offset the phase search
    must find): every position's mean is its symbol, the counts add up to the samples kept off
    the symbol edges, and the sums of squares equal the counts (every value is +-1)."""
    rng = np.random.default_rng(seed)
    dec = S2pskDecoder()
    pkt = np.array(list(s2psk_packet(int(rng.integers(0, 256)))), float) * 2 - 1
    offset = rng.uniform(0, 1)                          # symbols
    n = int(2 * PACKET_LEN * dec.symbol_s * 30)
    t = np.arange(n) / 30.0 + rng.uniform(0, 0.03)
    u = t / dec.symbol_s - offset
    frac = u - np.floor(u)
    keep = (frac > 0.2) & (frac < 0.8)                   # samples well inside their symbol
    t = t[keep]
    x = pkt[(np.floor(t / dec.symbol_s - offset).astype(int)) % PACKET_LEN]
    for ti, xi in zip(t, x):
        dec.step(ti, xi, decode=False)
    sums, cnt, sq = dec.folded_sums()
    seen = cnt > 0
    assert seen.sum() >= PACKET_LEN - 2 and cnt.sum() == len(dec._t)
    assert np.array_equal(sq, cnt)
    pos = np.flatnonzero(seen)
    means = sums[pos] / cnt[pos]
    shift = [k for k in range(PACKET_LEN) if np.array_equal(means, pkt[(pos + k) % PACKET_LEN])]
    assert shift, (means, pkt)                              # the packet, up to its start position


def test_no_samples_fold_to_zeros():
    assert all(np.array_equal(a, np.zeros(PACKET_LEN)) for a in S2pskDecoder().folded_sums())


def test_best_per_id_is_the_reshaped_max():
    """soft_stats' per-ID best score equals reshape(B, 256, 30).max(axis=2), also with ties, signed
    zeros and NaNs (the argmax over IDs that follows sees the same values)."""
    rng = np.random.default_rng(5)
    for trial in range(30):
        b = int(rng.integers(1, 4))
        sc = np.round(rng.normal(0, 3, (b, 30 * 256)), int(rng.integers(0, 3)))
        if trial % 3 == 0:
            sc[rng.random(sc.shape) < 0.01] = np.nan
        if trial % 4 == 0:
            sc[rng.random(sc.shape) < 0.3] = -0.0
        got, want = s2psk.best_per_id(sc), sc.reshape(b, -1, PACKET_LEN).max(axis=2)
        assert got.shape == want.shape and np.array_equal(got, want, equal_nan=True)
        assert np.array_equal(np.argmax(got, axis=1), np.argmax(want, axis=1))
