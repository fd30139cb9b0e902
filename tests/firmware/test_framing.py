"""PROTOCOL.md test vectors and CRC check values."""

import pytest

from firmware_tx.crc import crc4, crc8, crc_bytes
from firmware_tx.framing import ook_packet, s2psk_packet, to_str

VECTORS = [
    ("ook", 0x0000, 0x00, "111000010101010101010101010101010101010101010101010101"),
    ("ook", 0x002A, 0xD6, "111000010101010101010101011001100110011010011001101001"),
    ("ook", 0xBEEF, 0x1A, "111000100110101010100110101001101010100101011010011001"),
    ("s2psk", 0x00, 0x0, "111000010101010101010101010101"),
    ("s2psk", 0x2A, 0x7, "111000010110011001100101101010"),
    ("s2psk", 0x81, 0xD, "111000100101010101011010100110"),
]


def test_crc_check_values():
    assert crc_bytes(b"123456789", 0x07, 8) == 0xF4
    assert crc_bytes(b"123456789", 0x3, 4) == 0xE


@pytest.mark.parametrize("mode,led_id,crc,packet", VECTORS)
def test_protocol_vectors(mode, led_id, crc, packet):
    if mode == "ook":
        assert crc8(led_id) == crc
        assert to_str(ook_packet(led_id)) == packet
    else:
        assert crc4(led_id) == crc
        assert to_str(s2psk_packet(led_id)) == packet


@pytest.mark.parametrize("bad", [-1, 0x10000])
def test_ook_id_range(bad):
    with pytest.raises(ValueError):
        ook_packet(bad)
