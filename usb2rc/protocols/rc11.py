"""The 16 × 11-bit channel block that CRSF (RC_CHANNELS_PACKED) and SBUS share, sans-IO.

Sixteen channels of 11 bits each, packed LSB first into 22 bytes: bit k of channel n is bit
11·n + k of the block, and bit j of the block is bit j mod 8 of byte j div 8. Read as one
little-endian integer of 176 bits, channel n is `(block >> 11·n) & 0x7FF`.
"""

from __future__ import annotations

from collections.abc import Sequence

CHANNELS = 16
BITS = 11
BLOCK_LEN = CHANNELS * BITS // 8  # 22 bytes
VALUE_MAX = (1 << BITS) - 1  # 2047
_SHIFTS = tuple(BITS * n for n in range(CHANNELS))


def pack(channels: Sequence[int]) -> bytes:
    """16 channel values 0..2047 as the 22-byte block; raises ValueError otherwise."""
    if len(channels) != CHANNELS:
        raise ValueError(f"the 11-bit block holds {CHANNELS} channels, got {len(channels)}")
    block = 0
    for shift, value in zip(_SHIFTS, channels, strict=True):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= VALUE_MAX:
            raise ValueError(
                f"channel {shift // BITS + 1} must be an int in 0..2047, got {value!r}"
            )
        block |= value << shift
    return block.to_bytes(BLOCK_LEN, "little")


def unpack(data: bytes | bytearray | memoryview) -> tuple[int, ...]:
    """The 16 channel values of a 22-byte block (the first 22 bytes of `data`)."""
    block = int.from_bytes(bytes(data[:BLOCK_LEN]), "little")
    return tuple((block >> shift) & VALUE_MAX for shift in _SHIFTS)
