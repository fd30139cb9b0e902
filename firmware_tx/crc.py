"""CRCs of the on-air format (PROTOCOL.md section 5).

Both CRCs are plain MSB-first shift registers: no reflection, no final XOR, register starts
at 0. They run over a bit string (the payload is 16 or 8 bits, not whole bytes), so the
register is fed one bit at a time. MicroPython-compatible: ints only.
"""


def crc_bits(value, nbits, poly, width):
    """CRC of the `nbits` low bits of `value`, fed MSB first.

    `poly` is the generator without its top term (0x07 for x^8+x^2+x+1), `width` the CRC
    size in bits. Returns an int in [0, 2**width).
    """
    top = 1 << (width - 1)
    mask = (1 << width) - 1
    reg = 0
    for i in range(nbits - 1, -1, -1):
        bit = (value >> i) & 1
        fb = ((reg & top) != 0) ^ bit
        reg = (reg << 1) & mask
        if fb:
            reg ^= poly
    return reg


def crc_bytes(data, poly, width):
    """CRC over whole bytes (used for the standard "123456789" check values)."""
    top = 1 << (width - 1)
    mask = (1 << width) - 1
    reg = 0
    for byte in data:
        for i in range(7, -1, -1):
            fb = ((reg & top) != 0) ^ ((byte >> i) & 1)
            reg = (reg << 1) & mask
            if fb:
                reg ^= poly
    return reg


def crc8(value, nbits=16):
    """CRC-8, polynomial x^8+x^2+x+1 (0x07), over the low `nbits` of `value`."""
    return crc_bits(value, nbits, 0x07, 8)


def crc4(value, nbits=8):
    """CRC-4, polynomial x^4+x+1 (0x3), over the low `nbits` of `value`."""
    return crc_bits(value, nbits, 0x3, 4)
