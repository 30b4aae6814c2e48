"""The SUMD line session: one frame of the output's channels a tick (status 0x81 in failsafe)."""

from __future__ import annotations

from collections.abc import Sequence

from usb2rc.lines.session import ChannelSession, ChannelValues
from usb2rc.protocols.sumd import codec as sumd


class SumdSession(ChannelSession):
    """The SUMD line: one frame a tick (status 0x81 while failsafe)."""

    def __init__(self, name: str, channels: ChannelValues, frame_length: int, rate_hz: float):
        super().__init__(name, channels, frame_length, 1.0 / rate_hz)

    def encode(self, values: Sequence[int], failsafe: bool) -> bytes:
        return sumd.encode_sumd(values, failsafe=failsafe)
