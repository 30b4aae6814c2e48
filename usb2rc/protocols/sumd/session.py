"""The SUMD line session: one frame of the output's channels a tick (status 0x81 in failsafe)."""

from __future__ import annotations

from collections.abc import Sequence

from usb2rc.lines.session import ChannelValues, FrameLineSession, FrameSession
from usb2rc.protocols.sumd import codec as sumd


class SumdSession(FrameLineSession):
    """The SUMD line: one frame a tick (status 0x81 while failsafe)."""

    def frame(self, channels: Sequence[int], failsafe: bool) -> bytes:
        return sumd.encode_sumd(channels, failsafe=failsafe)


class SumdLine(FrameSession[SumdSession]):
    def __init__(self, name: str, channels: ChannelValues, frame_length: int, rate_hz: float):
        super().__init__(name, SumdSession(), channels, frame_length, 1.0 / rate_hz)
