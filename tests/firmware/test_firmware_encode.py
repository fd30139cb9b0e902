"""Exhaustive encoder checks: every 16-bit OOK ID and every 8-bit S2-PSK ID, decoded back by an
independent decoder written here (sync search in the periodic stream, Manchester, CRC by
polynomial division over GF(2)), plus the run-length and sync-uniqueness rules of PROTOCOL.md.
"""

import numpy as np
import pytest

from firmware_tx.framing import ook_packet, s2psk_packet

SYNC_PATTERN = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)
# Generators with their top term (x^8+x^2+x+1, x^4+x+1): independent of crc.py's encoding.
G8 = 0b1_0000_0111
G4 = 0b1_0011


def all_packets(kind):
    n, fn = (1 << 16, ook_packet) if kind == "ook" else (1 << 8, s2psk_packet)
    raw = b"".join(bytes(fn(i)) for i in range(n))
    return np.frombuffer(raw, dtype=np.uint8).reshape(n, -1).copy()


@pytest.fixture(scope="module", params=["ook", "s2psk"])
def coded(request):
    kind = request.param
    pk = all_packets(kind)
    return kind, pk


def sync_positions(streams):
    """Boolean (n, L): circular positions where the SYNC pattern starts, per periodic stream."""
    n, length = streams.shape
    hit = np.ones((n, length), dtype=bool)
    for k, v in enumerate(SYNC_PATTERN):
        hit &= np.roll(streams, -k, axis=1) == v
    return hit


def poly_mod(codewords, gen, nbits):
    """Remainder of each `nbits`-bit codeword (int array) divided by the generator polynomial."""
    r = codewords.astype(np.int64).copy()
    deg = int(gen).bit_length() - 1
    for bit in range(nbits - 1, deg - 1, -1):
        on = (r >> bit) & 1
        r ^= on * (gen << (bit - deg))
    return r


def decode_streams(streams, id_bits, crc_bits):
    """Independent receiver: periodic streams seen from any phase -> (ids, crc_ok)."""
    n, length = streams.shape
    hit = sync_positions(streams)
    assert np.all(hit.sum(axis=1) == 1), "sync pattern must occur exactly once per period"
    start = np.argmax(hit, axis=1)
    # Sync edge = ON->OFF inside SYNC (start+3); data begins 3 chips after it.
    first_data = start + 3 + 3
    idx = (first_data[:, None] + np.arange(length - 6)[None, :]) % length
    data = np.take_along_axis(streams, idx, axis=1)
    a, b = data[:, 0::2], data[:, 1::2]
    assert np.all(a != b), "every Manchester pair must be 10 or 01"
    bits = a.astype(np.int64)  # 1 0 -> 1, 0 1 -> 0
    weights = 1 << np.arange(bits.shape[1] - 1, -1, -1, dtype=np.int64)
    word = bits @ weights
    ids = word >> crc_bits
    gen = G8 if crc_bits == 8 else G4
    crc_ok = poly_mod(word, gen, id_bits + crc_bits) == 0
    return ids, crc_ok


def test_every_id_decodes_back_from_any_phase(coded):
    kind, pk = coded
    id_bits, crc_bits = (16, 8) if kind == "ook" else (8, 4)
    n, length = pk.shape
    assert length == 6 + 2 * (id_bits + crc_bits)
    rng = np.random.default_rng(1234)
    phase = rng.integers(0, length, size=n)
    idx = (phase[:, None] + np.arange(length)[None, :]) % length
    seen = np.take_along_axis(pk, idx, axis=1)  # a receiver joins the stream anywhere
    ids, crc_ok = decode_streams(seen, id_bits, crc_bits)
    assert np.array_equal(ids, np.arange(n))
    assert crc_ok.all()


def test_independent_crc_rejects_single_bit_errors(coded):
    # Sanity of the test's own CRC: any single flipped data chip pair (= data bit) must fail.
    kind, pk = coded
    id_bits, crc_bits = (16, 8) if kind == "ook" else (8, 4)
    rng = np.random.default_rng(7)
    rows = rng.choice(pk.shape[0], size=min(512, pk.shape[0]), replace=False)
    bad = pk[rows].copy()
    bit = rng.integers(0, id_bits + crc_bits, size=rows.size)
    r = np.arange(rows.size)
    bad[r, 6 + 2 * bit] ^= 1
    bad[r, 7 + 2 * bit] ^= 1
    _, crc_ok = decode_streams(bad, id_bits, crc_bits)
    assert not crc_ok.any()


def runs_circular(stream):
    """Lengths of the runs of equal chips of one periodic stream, starting at a change."""
    s = np.asarray(stream)
    change = np.flatnonzero(s != np.roll(s, 1))
    return np.diff(np.append(change, change[0] + s.size))


def test_manchester_run_length_at_most_two_in_data(coded):
    _, pk = coded
    data = pk[:, 6:]
    three = (data[:, :-2] == data[:, 1:-1]) & (data[:, 1:-1] == data[:, 2:])
    assert not three.any()


def test_sync_runs_and_uniqueness_in_periodic_stream(coded):
    _, pk = coded
    hit = sync_positions(pk)
    assert np.all(hit.sum(axis=1) == 1)
    assert np.all(hit[:, 0])  # ... and it is where the packet starts
    # Around SYNC the ON and OFF runs are 3 or 4 chips; these are the only runs > 2.
    rng = np.random.default_rng(99)
    for row in rng.choice(pk.shape[0], size=min(2000, pk.shape[0]), replace=False):
        runs = runs_circular(pk[row])
        long_runs = runs[runs > 2]
        assert long_runs.size == 2 and np.all((long_runs >= 3) & (long_runs <= 4))
    # The ON->OFF sync edge itself (run >= 3 of ones then run >= 3 of zeros) is unique: a
    # 3-chip window of ones followed by 3 zeros occurs once per period for every ID.
    ones3 = np.ones_like(pk, dtype=bool)
    for k in range(3):
        ones3 &= np.roll(pk, -k, axis=1) == 1
    zeros3 = np.ones_like(pk, dtype=bool)
    for k in range(3, 6):
        zeros3 &= np.roll(pk, -k, axis=1) == 0
    assert np.all((ones3 & zeros3).sum(axis=1) == 1)


def test_manchester_balance_every_id(coded):
    # Half the chips are ON for every ID: no flicker at the packet rate (PROTOCOL.md section 2).
    _, pk = coded
    assert np.all(pk.sum(axis=1) * 2 == pk.shape[1])
