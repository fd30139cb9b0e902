"""The compiled phase search and fold of S2pskDecoder.folded_sums (receiver/decode/_s2psk.pyx)
equals the numpy reference to the bit: the same phase, sums, counts and squares, and the same
decoded IDs over whole decoder runs."""

import numpy as np
import pytest

from receiver.decode import s2psk
from receiver.decode.s2psk import PACKET_LEN, S2pskDecoder

pytestmark = pytest.mark.skipif(s2psk._k is None, reason="kernel not built")


def _both(dec_factory, feed, monkeypatch):
    """Run `feed(decoder)` on a kernel decoder and a numpy one; their outputs."""
    out = []
    for kern in (s2psk._k, None):
        monkeypatch.setattr(s2psk, "_k", kern)
        out.append(feed(dec_factory()))
    return out


@pytest.mark.parametrize("seed", range(40))
def test_fold_equals_numpy(seed, monkeypatch):
    """Random sample times (rising, with jitter, or out of order) and soft values: every
    folded_sums call of a decoder gives the same arrays and phase on both paths."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    dt = rng.uniform(0.01, 0.05)
    t = np.cumsum(rng.uniform(0.2, 1.8, n) * dt) + rng.uniform(0, 100)
    if seed % 5 == 0:
        t = t[rng.permutation(n)]  # out of order (the ring's mask path)
    x = rng.normal(0, 1, n) * rng.choice([1.0, 1e-3, 1e3])
    if seed % 7 == 0:
        x = np.round(x)  # exact zeros and ties between phases

    def feed(dec):
        res = []
        for ti, xi in zip(t, x):
            dec.step(ti, xi, decode=False)
            s, c, q = dec.folded_sums()
            res.append((s.tobytes(), c.tobytes(), q.tobytes(), dec._phase))
        return res

    a, b = _both(lambda: S2pskDecoder(phase_every=3), feed, monkeypatch)
    assert a == b


@pytest.mark.parametrize("seed", range(6))
def test_decoder_ids_equal(seed, monkeypatch):
    """A whole noisy packet stream at 30 fps: the same states (IDs, confidences) frame by frame."""
    rng = np.random.default_rng(100 + seed)
    dec0 = S2pskDecoder()
    led = int(rng.integers(0, 256))
    from firmware_tx.framing import s2psk_packet
    pkt = np.array(list(s2psk_packet(led)), float) * 2 - 1
    n = 300
    t = np.arange(n) / 30.0 + rng.uniform(0, 1)
    sym = np.floor(t / dec0.symbol_s).astype(int) % PACKET_LEN
    x = pkt[sym] * rng.uniform(0.6, 1.0) + rng.normal(0, 0.2 + 0.3 * seed, n)

    def feed(dec):
        return [(st.led_id, st.confidence) for st in (dec.step(ti, xi) for ti, xi in zip(t, x))]

    a, b = _both(S2pskDecoder, feed, monkeypatch)
    assert a == b
    if seed <= 1:  # the clean ones decode, to their own ID
        assert a[-1][0] == led


def test_bad_sizes_raise():
    out = np.zeros(PACKET_LEN)
    with pytest.raises(ValueError):
        s2psk._k.folded_sums(np.zeros(3), np.zeros(2), np.zeros(1), 0.08, 0.1, PACKET_LEN, out, out, out)
    with pytest.raises(ValueError):
        s2psk._k.folded_sums(np.zeros(3), np.zeros(3), np.zeros(1), 0.08, 0.1, PACKET_LEN, out, out, np.zeros(4))
    with pytest.raises(ValueError):
        s2psk._k.folded_sums(np.zeros(3), np.zeros(3), np.zeros(0), 0.08, 0.1, PACKET_LEN, out, out, out)


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
