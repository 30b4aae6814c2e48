"""The CRCs against their check values and against bit-by-bit ports of the specs' C routines."""

from __future__ import annotations

import random

from hypothesis import given
from hypothesis import strategies as st

from usb2rc.protocols.crc import crc16_arc, crc16_xmodem

CHECK_INPUT = b"123456789"


def icd_gen_crc16(data: bytes) -> int:
    """The C2-16B ICD's `gen_crc16`, line by line, with its uint16 wrap-around made explicit."""
    poly = 0x8005
    out = 0
    crc = 0
    bits_read = 0
    index = 0
    size = len(data)
    while size > 0:
        bit_flag = out >> 15
        out = (out << 1) & 0xFFFF
        out |= (data[index] >> bits_read) & 1
        bits_read += 1
        if bits_read > 7:
            bits_read = 0
            index += 1
            size -= 1
        if bit_flag:
            out ^= poly
    for _ in range(16):
        bit_flag = out >> 15
        out = (out << 1) & 0xFFFF
        if bit_flag:
            out ^= poly
    in_bit, out_bit = 0x8000, 0x0001
    while in_bit:
        if in_bit & out:
            crc |= out_bit
        in_bit >>= 1
        out_bit <<= 1
    return crc


def sumd_spec_crc16(data: bytes) -> int:
    """The SUMD spec's `CRC16(crc, value)` applied to each byte, starting from 0."""
    crc = 0
    for value in data:
        crc = (crc ^ (value << 8)) & 0xFFFF
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021 if crc & 0x8000 else crc << 1) & 0xFFFF
    return crc


def test_arc_check_value() -> None:
    assert crc16_arc(CHECK_INPUT) == 0xBB3D


def test_xmodem_check_value() -> None:
    assert crc16_xmodem(CHECK_INPUT) == 0x31C3


def test_reference_ports_reach_the_check_values() -> None:
    assert icd_gen_crc16(CHECK_INPUT) == 0xBB3D
    assert sumd_spec_crc16(CHECK_INPUT) == 0x31C3


def test_empty_input_is_zero() -> None:
    assert crc16_arc(b"") == 0
    assert crc16_xmodem(b"") == 0


def test_arc_accepts_bytearray_and_memoryview() -> None:
    assert crc16_arc(bytearray(CHECK_INPUT)) == crc16_arc(memoryview(CHECK_INPUT)) == 0xBB3D


def test_arc_table_matches_icd_routine_on_seeded_random_frames() -> None:
    rng = random.Random(20220520)
    for _ in range(300):
        data = rng.randbytes(33)
        assert crc16_arc(data) == icd_gen_crc16(data)


@given(st.binary(max_size=80))
def test_arc_table_matches_icd_routine(data: bytes) -> None:
    assert crc16_arc(data) == icd_gen_crc16(data)


@given(st.binary(max_size=80))
def test_xmodem_matches_sumd_spec_routine(data: bytes) -> None:
    assert crc16_xmodem(data) == sumd_spec_crc16(data)
