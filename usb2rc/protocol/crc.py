"""The two CRC-16 variants on the wire.

- C2-16B: CRC-16/ARC (polynomial 0x8005 reflected = 0xA001, init 0, no final XOR). This is
  what the ICD's bit-serial `gen_crc16` computes. Check value: `crc16_arc(b"123456789")`
  is 0xBB3D. Sent low byte first.
- SUMD: CRC-16/XMODEM (polynomial 0x1021, init 0, not reflected), the SUMD spec's `CRC16`
  routine; the standard library has it as `binascii.crc_hqx`. Check value 0x31C3. Sent
  high byte first.
"""

from __future__ import annotations

import binascii

_ARC_POLY_REFLECTED = 0xA001


def _arc_table_entry(index: int) -> int:
    crc = index
    for _ in range(8):
        crc = (crc >> 1) ^ _ARC_POLY_REFLECTED if crc & 1 else crc >> 1
    return crc


# One entry per possible value of (crc ^ byte) & 0xFF: the register after shifting out 8 bits.
_ARC_TABLE: tuple[int, ...] = tuple(_arc_table_entry(index) for index in range(256))


def crc16_arc(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/ARC of `data`, table driven, one table lookup per byte."""
    table = _ARC_TABLE
    crc = 0
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


def crc16_xmodem(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/XMODEM of `data` (the SUMD CRC)."""
    return binascii.crc_hqx(data, 0)
