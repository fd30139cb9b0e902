"""PROTOCOL.md's constants, defined once for the receiver (the firmware, the other side of the
contract, has its own in `firmware_tx.framing`, from which the packet layout is taken).

Defaults marked *default* in PROTOCOL.md are configuration: a map's `rate_hz` /
`symbol_clocks` override them per light.
"""

from __future__ import annotations

from firmware_tx.framing import OOK_ID_BITS, OOK_PACKET_LEN, S2PSK_CRC_BITS, S2PSK_ID_BITS, S2PSK_PACKET_LEN, SYNC

OOK_RATE_HZ = 20000.0  # section 2: default chip rate (1-50 kHz allowed)
S2PSK_CLOCK_HZ = 200.0  # section 3: default clock f_clk (125 Hz also used)
S2PSK_SYMBOL_CLOCKS = 16  # section 3: default clock periods per symbol N
FV_ID_MIN = 0x80  # section 3: S2-PSK IDs 0x00-0x7F are street lights, 0x80-0xFF vehicles
TONE_MIN_SPACING_HZ = 50.0  # section 4: tone channels are at least this far apart

__all__ = ["OOK_RATE_HZ", "S2PSK_CLOCK_HZ", "S2PSK_SYMBOL_CLOCKS", "FV_ID_MIN", "TONE_MIN_SPACING_HZ",
           "OOK_ID_BITS", "OOK_PACKET_LEN", "S2PSK_CRC_BITS", "S2PSK_ID_BITS", "S2PSK_PACKET_LEN", "SYNC"]
