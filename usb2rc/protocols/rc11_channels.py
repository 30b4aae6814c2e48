"""What the CRSF and SBUS outputs share: the 11-bit channels' scale (`RC11_SCALE`, through
`protocols.rc11`'s scaling) and the 16 channels of a block, padded."""

from __future__ import annotations

from collections.abc import Sequence

from usb2rc.protocols import rc11
from usb2rc.protocols.channels import WireScale

RC11_SCALE = WireScale(rc11.axis_to_rc11, rc11.button_to_rc11)  # 172..1811, centre 992
UNLISTED = rc11.LOW  # channels past the list: 988 µs ("off" for a switch channel)


def padded(channels: Sequence[int], count: int = rc11.CHANNELS) -> list[int]:
    """The listed channels, then UNLISTED up to `count`."""
    return [*channels[:count], *([UNLISTED] * (count - len(channels)))]
