"""The CRCs on the wire: two CRC-16 variants and CRSF's CRC-8.

- C2-16B: CRC-16/ARC (polynomial 0x8005 reflected = 0xA001, init 0, no final XOR). This is
  what the ICD's bit-serial `gen_crc16` computes. Check value: `crc16_arc(b"123456789")`
  is 0xBB3D. Sent low byte first.
- SUMD: CRC-16/XMODEM (polynomial 0x1021, init 0, not reflected), the SUMD spec's `CRC16`
  routine; the standard library has it as `binascii.crc_hqx`. Check value 0x31C3. Sent
  high byte first.
- CRSF: CRC-8/DVB-S2 (polynomial 0xD5, init 0, not reflected, no final XOR) over the frame's
  type and payload. Check value: `crc8_dvb_s2(b"123456789")` is 0xBC.
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


_DVB_S2_POLY = 0xD5


def _dvb_s2_table_entry(index: int) -> int:
    crc = index
    for _ in range(8):
        crc = ((crc << 1) ^ _DVB_S2_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


_DVB_S2_TABLE: tuple[int, ...] = tuple(_dvb_s2_table_entry(index) for index in range(256))


def crc8_dvb_s2(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-8/DVB-S2 of `data` (the CRSF CRC), table driven; `crc` continues an earlier one."""
    table = _DVB_S2_TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc
