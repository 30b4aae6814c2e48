"""The 16 × 11-bit channel block that CRSF (RC_CHANNELS_PACKED) and SBUS share, sans-IO.

Sixteen channels of 11 bits each, packed LSB first into 22 bytes: bit k of channel n is bit
11·n + k of the block, and bit j of the block is bit j mod 8 of byte j div 8. Read as one
little-endian integer of 176 bits, channel n is `(block >> 11·n) & 0x7FF`.

An axis takes 172..1811 of the 0..2047 a channel holds (988..2012 µs at the receiver), on one
line through both ends, centre 992 (docs/ICD.md, "CRSF and SBUS channel values"):
`axis_to_rc11`; a button is 172 or 1811 (`button_to_rc11`).
"""

from __future__ import annotations

from collections.abc import Sequence

CHANNELS = 16
BITS = 11
BLOCK_LEN = CHANNELS * BITS // 8  # 22 bytes
VALUE_MAX = (1 << BITS) - 1  # 2047
LOW, CENTRE, HIGH = 172, 992, 1811  # an axis's ends and centre: 988, 1500, 2012 µs
_INT16_SPAN = 65535  # from -32768 to +32767
_SHIFTS = tuple(BITS * n for n in range(CHANNELS))
_INT_ONLY = {int}


def pack(channels: Sequence[int]) -> bytes:
    """16 channel values 0..2047 as the 22-byte block; raises ValueError otherwise."""
    return block(channels).to_bytes(BLOCK_LEN, "little")


def block(channels: Sequence[int]) -> int:
    """16 channel values 0..2047 as the block's one integer (channel n at bit 11·n), for a
    frame that packs it with its other fields in one `int.to_bytes`; ValueError otherwise."""
    if len(channels) != CHANNELS:
        raise ValueError(f"the 11-bit block holds {CHANNELS} channels, got {len(channels)}")
    # Fast path with C-level builtins (`type(x) is int` excludes bool); the per-channel
    # checks only run to name the bad channel (or to accept an int subclass, as they did).
    if set(map(type, channels)) != _INT_ONLY or min(channels) < 0 or max(channels) > VALUE_MAX:
        _check_channels(channels)
    # One expression, no loop: 15 shifts and ORs of the channels in place.
    c0, c1, c2, c3, c4, c5, c6, c7, c8, c9, c10, c11, c12, c13, c14, c15 = channels
    return (
        c0
        | c1 << 11
        | c2 << 22
        | c3 << 33
        | c4 << 44
        | c5 << 55
        | c6 << 66
        | c7 << 77
        | c8 << 88
        | c9 << 99
        | c10 << 110
        | c11 << 121
        | c12 << 132
        | c13 << 143
        | c14 << 154
        | c15 << 165
    )


def _check_channels(channels: Sequence[object]) -> None:
    # each value as an object: compiled, an `int` loop variable would take a bool as 0 or 1
    for number, value in enumerate(channels, start=1):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= VALUE_MAX:
            raise ValueError(f"channel {number} must be an int in 0..2047, got {value!r}")


def unpack(data: bytes | bytearray | memoryview) -> tuple[int, ...]:
    """The 16 channel values of a 22-byte block (the first 22 bytes of `data`)."""
    block = int.from_bytes(bytes(data[:BLOCK_LEN]), "little")
    return tuple((block >> shift) & VALUE_MAX for shift in _SHIFTS)


def axis_to_rc11(value_int16: int) -> int:
    """An int16 axis onto 172..1811: `172 + round((v + 32768) * 1639 / 65535)`, so -32768 →
    172, 0 → 992 (the line passes 0.51 of a step above 991.5), 32767 → 1811. The exact
    quotient is never a half (the denominator is odd). Raises ValueError outside int16."""
    if not isinstance(value_int16, int) or not -32768 <= value_int16 <= 32767:
        raise ValueError(f"axis value must be an int16 (-32768..32767), got {value_int16!r}")
    span = HIGH - LOW
    return LOW + (2 * (value_int16 + 32768) * span + _INT16_SPAN) // (2 * _INT16_SPAN)


def button_to_rc11(pressed: bool) -> int:
    """A button as an 11-bit channel: 1811 pressed, 172 released."""
    return HIGH if pressed else LOW
