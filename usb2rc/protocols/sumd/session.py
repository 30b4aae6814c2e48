"""The SUMD line session: one frame of the output's channels a tick (status 0x81 in failsafe)."""

from __future__ import annotations

from usb2rc.lines.session import ChannelValues, FrameSession
from usb2rc.session import SumdSession


class SumdLine(FrameSession):
    def __init__(self, name: str, channels: ChannelValues, frame_length: int, rate_hz: float):
        super().__init__(name, SumdSession(), channels, frame_length, 1.0 / rate_hz)
