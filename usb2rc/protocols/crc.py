"""The CRCs on the wire: two CRC-16 variants and CRSF's CRC-8.

- C2-16B: CRC-16/ARC (polynomial 0x8005 reflected = 0xA001, init 0, no final XOR). This is
  what the ICD's bit-serial `gen_crc16` computes. Check value: `crc16_arc(b"123456789")`
  is 0xBB3D. Sent low byte first.
- SUMD: CRC-16/XMODEM (polynomial 0x1021, init 0, not reflected), the SUMD spec's `CRC16`
  routine; the standard library has it as `binascii.crc_hqx`. Check value 0x31C3. Sent
  high byte first.
- CRSF: CRC-8/DVB-S2 (polynomial 0xD5, init 0, not reflected, no final XOR) over the frame's
  type and payload. Check value: `crc8_dvb_s2(b"123456789")` is 0xBC.

Speed: every CRC here is linear (init 0, no final XOR): for two messages of one length,
the CRC of `a XOR b` is `crc(a) XOR crc(b)`. So a frame's CRC can be put together from parts
computed once: each header byte's share at its position (`arc_position_table`: C2-16B's
header bytes are one lookup each), XOR the CRC of the rest. Tables of two bytes per lookup
(64 K entries) were measured and left out: a hot loop ran ~2x faster on CRC-16, slower on
CRC-8, and a tick every 20 ms finds such a table out of the CPU's caches.
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


def crc16_arc(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16/ARC of `data`, table driven, one table lookup per byte; `crc` continues an
    earlier one."""
    table = _ARC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


def arc_position_table(position: int, length: int) -> tuple[int, ...]:
    """For each value of the byte at `position` of a `length`-byte message: the CRC-16/ARC of
    that message with every other byte 0. By linearity, a message's CRC is the XOR of its
    bytes' entries, so a header byte's share of a frame's CRC is one lookup."""
    if not 0 <= position < length:
        raise ValueError(f"position {position} is not in a {length}-byte message")
    single_bits = [
        crc16_arc(bytes(position) + bytes((1 << bit,)) + bytes(length - position - 1))
        for bit in range(8)
    ]
    table = [0] * 256
    for value in range(1, 256):
        lowest = value & -value
        table[value] = table[value ^ lowest] ^ single_bits[lowest.bit_length() - 1]
    return tuple(table)


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
