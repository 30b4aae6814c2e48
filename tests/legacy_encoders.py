"""The encoders and CRCs as they were before issue 22's precompiled packing: the reference
that tests/test_codec_packing.py holds the new ones to, byte for byte and error for error.
Copied unchanged but for imports and names; do not edit them to follow the new code."""

from __future__ import annotations

import binascii
import struct
from collections.abc import Sequence

from usb2rc.protocols.c2_16b.codec import (
    AXIS_COUNT,
    AXIS_NAMES,
    DATA_STATUSES,
    HEADER,
    _check_data_status,
    _check_int,
)

# --- crc.py ----------------------------------------------------------------------------------


def _arc_table_entry(index: int) -> int:
    crc = index
    for _ in range(8):
        crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


_ARC_TABLE = tuple(_arc_table_entry(index) for index in range(256))


def crc16_arc(data: bytes | bytearray | memoryview) -> int:
    table = _ARC_TABLE
    crc = 0
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


def _dvb_s2_table_entry(index: int) -> int:
    crc = index
    for _ in range(8):
        crc = ((crc << 1) ^ 0xD5) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


_DVB_S2_TABLE = tuple(_dvb_s2_table_entry(index) for index in range(256))


def crc8_dvb_s2(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    table = _DVB_S2_TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc


# --- c2_16b.py: data frames ----------------------------------------------------------------

_DATA_BODY = struct.Struct("<2sBBB10HII")
_CRC_LE = struct.Struct("<H")


def _wire_axes(axes: Sequence[int]) -> list[int]:
    if len(axes) != AXIS_COUNT:
        raise ValueError(f"expected {AXIS_COUNT} axes {AXIS_NAMES}, got {len(axes)}")
    if set(map(type, axes)) != {int} or min(axes) < -32768 or max(axes) > 65535:
        for name, value in zip(AXIS_NAMES, axes, strict=True):
            _check_int(f"axis {name}", value, -32768, 65535)
    return list(map(0xFFFF.__and__, axes))


def encode_data(
    status: int,
    node_id: int,
    code: int,
    axes: Sequence[int],
    group1: int,
    group2: int,
    *,
    line_feed: bool = True,
) -> bytes:
    if not (
        type(status) is int
        and status in DATA_STATUSES
        and type(node_id) is int
        and 0 <= node_id <= 255
        and type(code) is int
        and 0 <= code <= 255
        and type(group1) is int
        and 0 <= group1 <= 0xFFFFFFFF
        and type(group2) is int
        and 0 <= group2 <= 0xFFFFFFFF
    ):
        _check_data_status(status)
        _check_int("node_id", node_id, 0, 255)
        _check_int("code", code, 0, 255)
        _wire_axes(axes)
        _check_int("group1", group1, 0, 0xFFFFFFFF)
        _check_int("group2", group2, 0, 0xFFFFFFFF)
    wire_axes = _wire_axes(axes)
    body = _DATA_BODY.pack(HEADER, status, node_id, code, *wire_axes, group1, group2)
    frame = body + _CRC_LE.pack(crc16_arc(body))
    return frame + b"\n" if line_feed else frame


# --- rc11.py, sbus.py, crsf.py -------------------------------------------------------------

_SHIFTS = tuple(11 * n for n in range(16))


def rc11_pack(channels: Sequence[int]) -> bytes:
    if len(channels) != 16:
        raise ValueError(f"the 11-bit block holds 16 channels, got {len(channels)}")
    block = 0
    for shift, value in zip(_SHIFTS, channels, strict=True):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 2047:
            raise ValueError(f"channel {shift // 11 + 1} must be an int in 0..2047, got {value!r}")
        block |= value << shift
    return block.to_bytes(22, "little")


def encode_sbus(
    channels: Sequence[int],
    *,
    ch17: bool = False,
    ch18: bool = False,
    frame_lost: bool = False,
    failsafe: bool = False,
) -> bytes:
    flags = (
        (0x01 if ch17 else 0)
        | (0x02 if ch18 else 0)
        | (0x04 if frame_lost else 0)
        | (0x08 if failsafe else 0)
    )
    return bytes((0x0F,)) + rc11_pack(channels) + bytes((flags, 0x00))


def crsf_encode_frame(address: int, frame_type: int, payload: bytes = b"") -> bytes:
    if not 0 <= address <= 0xFF:
        raise ValueError(f"address must be a byte, got {address!r}")
    length = len(payload) + 2
    if not 2 <= length <= 62:
        raise ValueError(f"a CRSF payload holds 0..60 bytes, got {len(payload)}")
    body = bytes((frame_type,)) + payload
    return bytes((address, length)) + body + bytes((crc8_dvb_s2(body),))


def encode_rc_channels(channels: Sequence[int], address: int = 0xEE) -> bytes:
    return crsf_encode_frame(address, 0x16, rc11_pack(channels))


# --- sumd.py, ibus.py ----------------------------------------------------------------------

_SUMD_BODY = {count: struct.Struct(f">BBB{count}H") for count in range(2, 33)}
_CRC_BE = struct.Struct(">H")


def encode_sumd(channels: Sequence[int], failsafe: bool = False) -> bytes:
    count = len(channels)
    if not 2 <= count <= 32:
        raise ValueError(f"SUMD carries 2..32 channels, got {count}")
    for index, value in enumerate(channels, start=1):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
            raise ValueError(f"channel {index} must be an int in 0..65535, got {value!r}")
    status = 0x81 if failsafe else 0x01
    body = _SUMD_BODY[count].pack(0xA8, status, count, *channels)
    return body + _CRC_BE.pack(binascii.crc_hqx(body, 0))


_IBUS_CHANNELS = struct.Struct("<14H")
_IBUS_CHECKSUM = struct.Struct("<H")


def encode_ibus(channels: Sequence[int]) -> bytes:
    if len(channels) != 14:
        raise ValueError(f"iBus carries 14 channels, got {len(channels)}")
    for index, value in enumerate(channels, start=1):
        if type(value) is not int or not 0 <= value <= 0xFFFF:
            raise ValueError(f"channel {index} must be an int in 0..65535, got {value!r}")
    body = b"\x20\x40" + _IBUS_CHANNELS.pack(*channels)
    return body + _IBUS_CHECKSUM.pack((0xFFFF - sum(body)) & 0xFFFF)
