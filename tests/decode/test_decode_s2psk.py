"""S2-PSK decoder (receiver/decode_s2psk.py) against exact frame-rate samples of emitter pairs."""

import numpy as np
import pytest

from firmware_tx.framing import s2psk_packet
from receiver.decode.s2psk import PACKET_LEN, S2pskDecoder, decode_symbols, kind_of, pair_xor
from signals import s2psk_samples

# the levels s2psk_samples renders by default: offsets (10, 15), gains (180, 140)
A_ON, B_ON, A_OFF, B_OFF = 190.0, 155.0, 10.0, 15.0


def feed(dec, t, a, b, led_id=None, levels=(A_ON, B_ON, A_OFF, B_OFF), negate=False):
    """Run a decoder over samples; returns (seconds to first right decode or None, states).
    Asserts on the way that no wrong ID is ever reported."""
    first, states = None, []
    for i in range(t.size):
        x = pair_xor(a[i], b[i], *levels)
        st = dec.step(t[i], -x if negate else x)
        states.append(st)
        if led_id is not None:
            assert st.led_id in (None, led_id), (hex(led_id), st)
            if st.led_id == led_id and first is None:
                first = t[i] - t[0]
    return first, states


def test_pair_xor_clean_and_straddling():
    assert pair_xor(190, 155, A_ON, B_ON, A_OFF, B_OFF) == pytest.approx(-1.0)  # both on
    assert pair_xor(10, 15, A_ON, B_ON, A_OFF, B_OFF) == pytest.approx(-1.0)  # both off
    assert pair_xor(190, 15, A_ON, B_ON, A_OFF, B_OFF) == pytest.approx(1.0)
    assert pair_xor(10, 155, A_ON, B_ON, A_OFF, B_OFF) == pytest.approx(1.0)
    for f in np.linspace(0.0, 1.0, 11):  # exposure straddling a clock edge by fraction f
        a, b_in, b_anti = 10 + 180 * f, 15 + 140 * f, 15 + 140 * (1 - f)
        assert pair_xor(a, b_in, A_ON, B_ON, A_OFF, B_OFF) <= 1e-9
        assert pair_xor(a, b_anti, A_ON, B_ON, A_OFF, B_OFF) >= -1e-9
    assert pair_xor(50, 50, 10, 10, 10, 10) == 0.0  # unlearned levels: no information


def test_decode_symbols_any_rotation():
    for led_id in (0x00, 0x2A, 0x81, 0xFF):
        m = np.array(s2psk_packet(led_id), dtype=np.float64) * 2 - 1
        for rot in range(PACKET_LEN):
            assert decode_symbols(np.roll(m, rot))[0] == led_id


def test_decode_symbols_single_symbol_error_rejected():
    """One wrong symbol anywhere: rejected (CRC-4 or a broken Manchester pair / sync)."""
    for led_id in range(256):
        m = np.array(s2psk_packet(led_id), dtype=np.float64) * 2 - 1
        for pos in range(PACKET_LEN):
            bad = m.copy()
            bad[pos] = -bad[pos]
            assert decode_symbols(bad)[0] is None, (led_id, pos)


@pytest.mark.parametrize("led_id", [0x00, 0x2A, 0x81])
def test_protocol_vectors_decode(led_id):
    rng = np.random.default_rng(led_id)
    t, a, b = s2psk_samples(led_id, 200, 16, 150, rng)
    first, states = feed(S2pskDecoder(200.0, 16), t, a, b, led_id)
    assert states[-1].led_id == led_id
    assert states[-1].kind == ("FV" if led_id >= 0x80 else "SL")
    assert first is not None and first < 3.5  # a packet is 2.4 s


def test_kind_of():
    assert kind_of(0x7F) == "SL" and kind_of(0x80) == "FV" and kind_of(None) is None


def test_id_sweep_never_wrong():
    """Many IDs, 200/125 Hz clocks, jittered timestamps, missed frames, exposures up to 80 %
    of a clock half-period (straddling clock edges), noise: right ID or None, never wrong."""
    rng = np.random.default_rng(4)
    decoded = 0
    n = 48
    for trial in range(n):
        led_id = int(rng.integers(0, 256))
        clk = [200, 125][trial % 2]
        half_s = 0.5 / clk
        fps = float(rng.uniform(24, 60))
        n_frames = int(fps * 2 * PACKET_LEN * 16 / clk)  # two packets of samples
        t, a, b = s2psk_samples(led_id, clk, 16, n_frames, rng, fps=fps,
                                jitter_s=float(rng.uniform(0, 0.006)),
                                exposure_s=float(rng.uniform(0.05, 0.8)) * half_s,
                                drop_prob=float(rng.uniform(0, 0.15)),
                                noise=float(rng.uniform(0, 8)))
        first, states = feed(S2pskDecoder(float(clk), 16), t, a, b, led_id)
        decoded += states[-1].led_id == led_id
    assert decoded >= 0.9 * n


def test_inverted_polarity_option():
    rng = np.random.default_rng(5)
    t, a, b = s2psk_samples(0x5A, 200, 16, 150, rng)
    # an emitter using the other convention: every soft XOR flipped
    first, states = feed(S2pskDecoder(200.0, 16, inverted=True), t, a, b, 0x5A, negate=True)
    assert states[-1].led_id == 0x5A
    _, states = feed(S2pskDecoder(200.0, 16), t, a, b, None, negate=True)
    assert all(s.led_id in (None, 0x5A) for s in states)


def test_noise_only_never_decodes():
    rng = np.random.default_rng(6)
    dec = S2pskDecoder()
    t = np.cumsum(rng.uniform(0.025, 0.040, 600))
    for ti in t:
        assert dec.step(ti, float(rng.uniform(-1, 1))).led_id is None


def test_id_change_is_followed():
    rng = np.random.default_rng(8)
    t1, a1, b1 = s2psk_samples(0x12, 200, 16, 120, rng)
    t2, a2, b2 = s2psk_samples(0x9C, 200, 16, 300, rng, t0_s=float(t1[-1]) + 0.033)
    dec = S2pskDecoder()
    _, s1 = feed(dec, t1, a1, b1)
    assert s1[-1].led_id == 0x12
    _, s2 = feed(dec, t2, a2, b2)
    assert {s.led_id for s in s2} <= {0x12, 0x9C}
    assert s2[-1].led_id == 0x9C and s2[-1].kind == "FV"


def test_seconds_to_first_decode():
    """At 30 fps, 200 Hz clock, 16 clocks/symbol: about one packet (2.4 s) to the first ID."""
    rng = np.random.default_rng(10)
    secs = []
    for _ in range(16):
        led_id = int(rng.integers(0, 256))
        t, a, b = s2psk_samples(led_id, 200, 16, 200, rng, jitter_s=0.003, noise=3.0)
        first, _ = feed(S2pskDecoder(), t, a, b, led_id)
        secs.append(first if first is not None else 99.0)
    assert np.median(secs) <= 3.0
    assert max(secs) <= 6.0


def test_step_benchmark(benchmark):
    rng = np.random.default_rng(12)
    t, a, b = s2psk_samples(0x81, 200, 16, 400, rng)
    dec = S2pskDecoder()
    x = [pair_xor(a[i], b[i], A_ON, B_ON, A_OFF, B_OFF) for i in range(t.size)]
    for i in range(200):
        dec.step(t[i], x[i])
    state = {"i": 200, "t": float(t[199])}

    def one():
        i = state["i"] % t.size
        state["t"] += 1 / 30
        state["i"] += 1
        return dec.step(state["t"], x[i])

    benchmark(one)


def test_stored_only_samples_decode_at_the_next_check():
    """`decode=False` keeps the sample and skips the decode; the next decoding step sees every
    stored sample (a decoded pair is re-checked every few frames, receiver.decode.policy)."""
    rng = np.random.default_rng(8)
    t, a, b = s2psk_samples(0x12, 200, 16, 120, rng)
    ref, lazy = S2pskDecoder(), S2pskDecoder()
    for i, (ti, ai, bi) in enumerate(zip(t, a, b)):
        x = pair_xor(ai, bi, A_ON, B_ON, A_OFF, B_OFF)
        r = ref.step(ti, x)
        s = lazy.step(ti, x, decode=i == len(t) - 1)
        if i < len(t) - 1:
            assert s.led_id is None  # nothing decoded while only stored
    assert r.led_id == s.led_id == 0x12
    assert np.array_equal(ref._t, lazy._t) and np.array_equal(ref._x, lazy._x)


def test_a_history_shorter_than_a_packet_is_refused():
    """A decode needs a whole 30-symbol packet of samples: a shorter `history_s` would silently
    never decode, so it is refused (one packet, 2.4 s at the defaults, is the least)."""
    with pytest.raises(ValueError, match="whole packet"):
        S2pskDecoder(history_s=2.0)
    assert S2pskDecoder(history_s=2.4).history_s == 2.4
