"""An encoder that keeps its last frame: a line whose values did not change since the last
tick re-sends that frame's bytes instead of packing and checksumming them again.

For the frames that carry no counter (SUMD, SBUS, CRSF RC channels, iBus): the same values
give the same bytes. C2-16B frames carry a message code, so they have their own per-node
cache (`usb2rc.protocols.c2_16b.codec.NodeEncoder`).

    sbus_frame = LastFrame(sbus.encode_sbus)
    frame = sbus_frame(channels, ch17=False, ch18=False, frame_lost=False, failsafe=False)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any


class LastFrame:
    """`encode(channels, **options)` with a memory of one call: the same channels (==) and
    options return the last frame's bytes. Errors are the encoder's (a call that raises is
    not remembered). Not thread-safe: one session owns it."""

    def __init__(self, encode: Callable[..., bytes]) -> None:
        self.encode = encode
        self.encoded = 0  # calls that packed a frame (a figure for the bench and tests)
        self._key: tuple[tuple[int, ...], tuple[tuple[str, Any], ...]] | None = None
        self._frame = b""

    def __call__(self, channels: Sequence[int], **options: Any) -> bytes:
        key = (tuple(channels), tuple(options.items()))
        if key == self._key:
            return self._frame
        frame = self.encode(key[0], **options)
        self._key, self._frame = key, frame
        self.encoded += 1
        return frame
