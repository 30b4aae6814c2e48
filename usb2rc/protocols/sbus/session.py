"""The SBUS line session: a 25-byte frame a tick, the frame-lost and failsafe flags set while
a listed channel's node is in failsafe (docs/ICD.md, "SBUS output")."""

from __future__ import annotations

from collections.abc import Sequence

from usb2rc.lines.session import ChannelSession, ChannelValues
from usb2rc.protocols import rc11
from usb2rc.protocols.rc11_channels import padded
from usb2rc.protocols.sbus import codec as sbus


class SbusSession(ChannelSession):
    """SBUS: channels 1..16 analogue, 17 and 18 digital (on above the centre)."""

    def __init__(self, name: str, channels: ChannelValues, rate_hz: float) -> None:
        super().__init__(name, channels, sbus.FRAME_LEN, 1.0 / rate_hz)

    def encode(self, values: Sequence[int], failsafe: bool) -> bytes:
        digital = values[rc11.CHANNELS :]
        return sbus.encode_sbus(
            padded(values),
            ch17=len(digital) > 0 and digital[0] > rc11.CENTRE,
            ch18=len(digital) > 1 and digital[1] > rc11.CENTRE,
            frame_lost=failsafe,
            failsafe=failsafe,
        )
