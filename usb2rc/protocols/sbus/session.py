"""The SBUS line session: a 25-byte frame a tick, the frame-lost and failsafe flags set while
a listed channel's node is in failsafe (docs/ICD.md, "SBUS output")."""

from __future__ import annotations

from usb2rc.lines.session import ChannelValues, FrameSession
from usb2rc.protocol import sbus
from usb2rc.rc_sessions import SbusSession


class SbusLine(FrameSession):
    def __init__(self, name: str, channels: ChannelValues, rate_hz: float) -> None:
        super().__init__(name, SbusSession(), channels, sbus.FRAME_LEN, 1.0 / rate_hz)
