"""The S2-PSK decoder's sample ring (receiver.decode.s2psk.S2pskDecoder._t / _x): the same kept
samples, and so the same states, as the arrays it replaced (np.append per step, a boolean mask
per trim), over long streams (the ring wraps and grows), timestamps that step back, and
decodes every frame or every few."""

import numpy as np
import pytest

from receiver.decode.s2psk import S2pskDecoder, pair_xor
from signals import s2psk_samples


class AppendDecoder(S2pskDecoder):
    """The reference: the samples kept in arrays rebuilt by np.append on every step."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self._rt, self._rx = np.zeros(0), np.zeros(0)

    @property
    def _t(self):
        return self._rt

    @property
    def _x(self):
        return self._rx

    def step(self, t_s, soft_xor, decode=True):
        self.samples += 1
        if self._t0 is None:
            self._t0 = float(t_s)
        t = float(t_s) - self._t0
        if self._rt.size and self._rt[0] < t - self.history_s:
            keep = self._rt >= t - self.history_s
            self._rt, self._rx = self._rt[keep], self._rx[keep]
        self._rt = np.append(self._rt, t)
        self._rx = np.append(self._rx, self.sign * float(soft_xor))
        # the decode itself: the ring's own code, reading the reference's arrays
        self._tb, self._xb, self._lo, self._hi = self._rt, self._rx, 0, self._rt.size
        self._first, self._rising = float(self._rt[0]), False
        return self._decide(t, decode)


def _stream(seed, n, *, shuffle=0, gap=False):
    rng = np.random.default_rng(seed)
    t, a, b = s2psk_samples(0x2A, 200.0, 16, n, rng, noise=4.0)
    if gap:  # the stream stops for longer than the history: every kept sample is dropped
        t[n // 3:] += 20.0
    x = np.array([pair_xor(a[i], b[i], 190.0, 155.0, 10.0, 15.0) for i in range(t.size)])
    if shuffle:  # a few timestamps stepping back (a stream that does not only grow)
        for i in rng.choice(np.arange(1, t.size), shuffle, replace=False):
            t[i] = t[i - 1] - rng.uniform(0.0, 0.5)
    return t, x


@pytest.mark.parametrize("seed,n,shuffle,every,gap", [(1, 900, 0, 1, False), (2, 700, 0, 3, False),
                                                      (3, 600, 5, 1, False), (4, 120, 0, 1, False),
                                                      (6, 900, 0, 2, True), (7, 600, 3, 1, True)])
def test_ring_keeps_what_the_arrays_kept(seed, n, shuffle, every, gap):
    t, x = _stream(seed, n, shuffle=shuffle, gap=gap)
    ring, ref = S2pskDecoder(), AppendDecoder()
    decoded = 0
    for i in range(t.size):
        due = i % every == 0
        s1, s0 = ring.step(t[i], x[i], due), ref.step(t[i], x[i], due)
        assert s1 == s0
        assert np.array_equal(ring._t, ref._rt) and np.array_equal(ring._x, ref._rx)
        decoded += s1.led_id is not None
    if n >= 600 and not shuffle and not gap:
        assert decoded > 0  # the streams long enough do decode (the comparison covers decodes)
    assert ring._tb.size >= ring._hi - ring._lo


def test_ring_grows_past_its_first_size():
    dec = S2pskDecoder(history_s=60.0)  # ~1800 samples at 30 fps: more than the initial ring
    t, x = _stream(5, 1500)
    for i in range(t.size):
        dec.step(t[i], x[i], decode=False)
    assert dec._hi - dec._lo == t.size
    assert np.array_equal(dec._t, t - t[0]) and np.array_equal(dec._x, x)
