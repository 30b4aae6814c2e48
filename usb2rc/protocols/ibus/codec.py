"""FlySky iBus servo frames, sans-IO: `encode_ibus` returns bytes, `IbusDecoder` parses them.

    0      0x20 (the frame length, 32)
    1      0x40 (command: servo channels)
    2..29  14 channels, uint16 little-endian, pulse length in µs (1000..2000, centre 1500)
    30..31 checksum, uint16 little-endian: 0xFFFF minus the sum of bytes 0..29

115200 baud 8N1. iBus has no failsafe flag: a transmitter in failsafe stops sending, and the
receiver (or flight controller) fires its own failsafe on the silence (docs/ICD.md, "iBus
output").

The encoder raises ValueError on bad input; the decoder never raises.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.protocols.stream import Rejected, StreamDecoder, header_tail

HEADER = b"\x20\x40"
FRAME_LEN = 32
CHANNELS = 14
BAUDRATE = 115200
PULSE_LOW, PULSE_CENTRE, PULSE_HIGH = 1000, 1500, 2000  # µs

_INT16_SPAN = 65535  # from -32768 to +32767
_CHECKSUM_AT = FRAME_LEN - 2
_CHANNELS = struct.Struct(f"<{CHANNELS}H")
_CHECKSUM = struct.Struct("<H")


@dataclass(frozen=True, slots=True)
class IbusFrame:
    """One iBus servo frame: 14 channel values, µs."""

    channels: tuple[int, ...]

    # `usb2rc decode` prints any frame that describes itself (commands/decode.py).
    def kind(self) -> str:
        return "channels"

    def text(self) -> str:
        return f"ibus channels {list(self.channels)}"

    def record(self) -> dict[str, object]:
        return {"protocol": "ibus", "frame": self.kind(), "channels": list(self.channels)}


def checksum(data: bytes | bytearray | memoryview) -> int:
    """0xFFFF minus the byte sum of `data` (bytes 0..29 of a frame)."""
    return (0xFFFF - sum(data)) & 0xFFFF


def encode_ibus(channels: Sequence[int]) -> bytes:
    """A 32-byte iBus frame of 14 channel values 0..65535 (µs; receivers expect 1000..2000)."""
    if len(channels) != CHANNELS:
        raise ValueError(f"iBus carries {CHANNELS} channels, got {len(channels)}")
    for index, value in enumerate(channels, start=1):
        if type(value) is not int or not 0 <= value <= 0xFFFF:
            raise ValueError(f"channel {index} must be an int in 0..65535, got {value!r}")
    body = HEADER + _CHANNELS.pack(*channels)
    return body + _CHECKSUM.pack(checksum(body))


def axis_to_ibus(value_int16: int) -> int:
    """An int16 axis onto 1000..2000 µs: -32768 → 1000, 0 → 1500, +32767 → 2000.

    `1000 + round((value + 32768) * 1000 / 65535)` in integers (the quotient is never a half:
    the numerator is even, the denominator odd). Raises ValueError outside int16."""
    if type(value_int16) is not int or not -32768 <= value_int16 <= 32767:
        raise ValueError(f"axis value must be an int16 (-32768..32767), got {value_int16!r}")
    numerator = (value_int16 + 32768) * (PULSE_HIGH - PULSE_LOW)
    return PULSE_LOW + (2 * numerator + _INT16_SPAN) // (2 * _INT16_SPAN)


def button_to_ibus(pressed: bool) -> int:
    """A button as a channel: 2000 µs pressed, 1000 µs released."""
    return PULSE_HIGH if pressed else PULSE_LOW


class IbusDecoder(StreamDecoder[IbusFrame]):
    """Streaming iBus decoder on the common base (`usb2rc.protocols.stream`).

    A candidate is 0x20 0x40; one whose checksum fails counts in `crc_failures` and skips ONE
    byte. Frames of other commands or lengths (telemetry) are not candidates."""

    START = HEADER
    FRAME_LEN = FRAME_LEN

    def _keep_tail(self, buffer: bytearray, pos: int, end: int) -> int:
        """No 0x20 0x40 from pos on: keep a trailing 0x20 that may start one."""
        return header_tail(buffer, pos, end, HEADER)

    def _parse(self, buffer: bytearray, start: int, length: int) -> IbusFrame | Rejected:
        checksum_at = start + _CHECKSUM_AT
        wire = _CHECKSUM.unpack_from(buffer, checksum_at)[0]
        if checksum(buffer[start:checksum_at]) != wire:
            return Rejected.CRC
        return IbusFrame(_CHANNELS.unpack_from(buffer, start + 2))
