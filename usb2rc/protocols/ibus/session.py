"""The iBus line session: a 32-byte frame a tick while every listed channel is live, nothing
while one is in failsafe (docs/ICD.md, "iBus output")."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from usb2rc.lines.session import ChannelSession, ChannelValues
from usb2rc.protocols.ibus import codec as ibus


class IbusSession(ChannelSession):
    """iBus: channels 1..14 in µs; channels past the list at 1000 µs ("off" for a switch)."""

    def __init__(self, name: str, channels: ChannelValues, rate_hz: float) -> None:
        super().__init__(name, channels, ibus.FRAME_LEN, 1.0 / rate_hz)
        self.withheld = 0  # ticks without a frame because a channel is in failsafe

    def encode(self, values: Sequence[int], failsafe: bool) -> bytes:
        if failsafe:
            self.withheld += 1
            return b""
        unlisted = [ibus.PULSE_LOW] * (ibus.CHANNELS - len(values))
        return ibus.encode_ibus([*values[: ibus.CHANNELS], *unlisted])

    def stats(self, now: float) -> dict[str, Any]:
        return {**super().stats(now), "frames_withheld": self.withheld}
