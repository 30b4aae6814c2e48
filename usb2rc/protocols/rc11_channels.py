"""What the CRSF and SBUS sessions share: the 16 channels of an 11-bit block, padded."""

from __future__ import annotations

from collections.abc import Sequence

from usb2rc.nodes.scaling import RC11_LOW
from usb2rc.protocols import rc11

UNLISTED = RC11_LOW  # channels past the list: 988 µs ("off" for a switch channel)


def padded(channels: Sequence[int], count: int = rc11.CHANNELS) -> list[int]:
    """The listed channels, then UNLISTED up to `count`."""
    return [*channels[:count], *([UNLISTED] * (count - len(channels)))]
