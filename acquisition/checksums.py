"""The CRCs our binary protocols use (MSB-first, not reflected): CRC-16 from the standard
library's C code, CRC-8 table-driven."""

from __future__ import annotations

import binascii


def _msb_first_table(poly: int, width_bits: int) -> tuple[int, ...]:
    top, mask = 1 << (width_bits - 1), (1 << width_bits) - 1
    table = []
    for byte in range(256):
        crc = byte << (width_bits - 8)
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & mask if crc & top else (crc << 1) & mask
        table.append(crc)
    return tuple(table)


_CRC8_TABLE = _msb_first_table(0x1D, 8)


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no xorout (check of b'123456789': 0x29B1).
    binascii.crc_hqx is this CRC with the initial value given (a C loop: every pulse edge and
    frame header is checked)."""
    return binascii.crc_hqx(data, 0xFFFF)


def crc8_sae_j1850(data: bytes) -> int:
    """CRC-8/SAE-J1850: poly 0x1D, init 0xFF, xorout 0xFF (check of b'123456789': 0x4B)."""
    crc = 0xFF
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc ^ 0xFF
