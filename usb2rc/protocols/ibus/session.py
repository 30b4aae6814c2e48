"""The iBus line session: a 32-byte frame a tick while every listed channel is live, nothing
while one is in failsafe (docs/ICD.md, "iBus output")."""

from __future__ import annotations

from typing import Any

from usb2rc.lines.session import ChannelValues, FrameSession
from usb2rc.protocol import ibus
from usb2rc.rc_sessions import IbusSession


class IbusLine(FrameSession):
    engine: IbusSession

    def __init__(self, name: str, channels: ChannelValues, rate_hz: float) -> None:
        super().__init__(name, IbusSession(), channels, ibus.FRAME_LEN, 1.0 / rate_hz)

    def stats(self, now: float) -> dict[str, Any]:
        return {**super().stats(now), "frames_withheld": self.engine.withheld}
