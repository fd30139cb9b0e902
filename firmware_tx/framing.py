"""Packet framing of the on-air format (PROTOCOL.md sections 1-3).

    packet = SYNC + Manchester(payload + crc)

A packet is returned as a `bytearray` of 0/1 values, one per chip (OOK) or symbol (S2-PSK),
first-sent first. Streams repeat packets back to back with no gap. MicroPython-compatible:
no dataclasses, no typing, only bytearray/ints.
"""

from firmware_tx.crc import crc4, crc8

SYNC = b"\x01\x01\x01\x00\x00\x00"

OOK_ID_BITS = 16
OOK_CRC_BITS = 8
OOK_PACKET_LEN = len(SYNC) + 2 * (OOK_ID_BITS + OOK_CRC_BITS)  # 54 chips

S2PSK_ID_BITS = 8
S2PSK_CRC_BITS = 4
S2PSK_PACKET_LEN = len(SYNC) + 2 * (S2PSK_ID_BITS + S2PSK_CRC_BITS)  # 30 symbols

# Distance from the sync edge (ON->OFF transition inside SYNC) to the first data chip.
SYNC_EDGE_TO_DATA = 3


def bits_msb(value, nbits):
    """The low `nbits` of `value`, most-significant bit first, as a bytearray of 0/1."""
    out = bytearray(nbits)
    for i in range(nbits):
        out[i] = (value >> (nbits - 1 - i)) & 1
    return out


def manchester(bits):
    """Manchester code: data 1 -> chips 1 0, data 0 -> chips 0 1 (first chip first)."""
    out = bytearray(2 * len(bits))
    for i in range(len(bits)):
        b = bits[i] & 1
        out[2 * i] = b
        out[2 * i + 1] = b ^ 1
    return out


def _packet(value, id_bits, crc, crc_bits):
    data = bits_msb(value, id_bits) + bits_msb(crc, crc_bits)
    return bytearray(SYNC) + manchester(data)


def ook_packet(led_id):
    """54-chip OOK packet for a 16-bit LED-ID (payload + CRC-8)."""
    if not 0 <= led_id <= 0xFFFF:
        raise ValueError("OOK ID must be 0..65535")
    return _packet(led_id, OOK_ID_BITS, crc8(led_id, OOK_ID_BITS), OOK_CRC_BITS)


def s2psk_packet(led_id):
    """30-symbol S2-PSK packet for an 8-bit ID (payload + CRC-4)."""
    if not 0 <= led_id <= 0xFF:
        raise ValueError("S2-PSK ID must be 0..255")
    return _packet(led_id, S2PSK_ID_BITS, crc4(led_id, S2PSK_ID_BITS), S2PSK_CRC_BITS)


def packet(mode, led_id):
    """Packet for `mode` in ('ook', 's2psk')."""
    if mode == "ook":
        return ook_packet(led_id)
    if mode == "s2psk":
        return s2psk_packet(led_id)
    raise ValueError("packets exist only in ook and s2psk modes")


def to_str(bits):
    """'0'/'1' text of a 0/1 bytearray (as DUMP replies carry it)."""
    return "".join("1" if b else "0" for b in bits)
