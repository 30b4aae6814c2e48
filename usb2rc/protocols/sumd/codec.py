"""Graupner HoTT SUMD frames, sans-IO: `encode_sumd` returns bytes, `SumdDecoder` parses them.

    0      0xA8 (vendor ID, Graupner)
    1      status: 0x01 live, 0x81 failsafe
    2      channel count n, 2..32
    3..    n channels, uint16 big-endian, pulse length in µs × 8
    last 2 CRC-16/XMODEM over the header and the channels, big-endian

The encoder raises ValueError on bad input; the decoder never raises.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.protocols.crc import crc16_xmodem
from usb2rc.protocols.stream import Rejected, StreamDecoder

VENDOR_ID = 0xA8
STATUS_LIVE = 0x01
STATUS_FAILSAFE = 0x81
MIN_CHANNELS = 2
MAX_CHANNELS = 32
HEADER_LEN = 3
CRC_LEN = 2

# Wire values (µs × 8) of the spec's stick table.
PULSE_EXTENDED_LOW = 0x1C20  # 900 µs, -150 %
PULSE_LOW = 0x2260  # 1100 µs, -100 %
PULSE_CENTRE = 0x2EE0  # 1500 µs
PULSE_HIGH = 0x3B60  # 1900 µs, +100 %
PULSE_EXTENDED_HIGH = 0x41A0  # 2100 µs, +150 %

_INT16_SPAN = 65535  # from -32768 to +32767
_CRC = struct.Struct(">H")
# Header + channels for each channel count (index = count).
_BODY_BY_COUNT = {count: struct.Struct(f">BBB{count}H") for count in range(2, 33)}
_CHANNELS_BY_COUNT = {count: struct.Struct(f">{count}H") for count in range(2, 33)}


@dataclass(frozen=True, slots=True)
class SumdFrame:
    """One SUMD frame: `channels` holds the 2..32 wire values (µs × 8)."""

    failsafe: bool
    channels: tuple[int, ...]


def frame_length(channel_count: int) -> int:
    """Bytes on the wire for a frame of `channel_count` channels."""
    return HEADER_LEN + 2 * channel_count + CRC_LEN


def encode_sumd(channels: Sequence[int], failsafe: bool = False) -> bytes:
    """A SUMD frame of 2..32 channels, each a uint16 wire value (µs × 8)."""
    count = len(channels)
    if not MIN_CHANNELS <= count <= MAX_CHANNELS:
        raise ValueError(f"SUMD carries {MIN_CHANNELS}..{MAX_CHANNELS} channels, got {count}")
    values: Sequence[object] = channels  # compiled, an `int` would take a bool as 0 or 1
    for index, value in enumerate(values, start=1):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
            raise ValueError(f"channel {index} must be an int in 0..65535, got {value!r}")
    status = STATUS_FAILSAFE if failsafe else STATUS_LIVE
    body = _BODY_BY_COUNT[count].pack(VENDOR_ID, status, count, *channels)
    return body + _CRC.pack(crc16_xmodem(body))


def axis_to_sumd(value_int16: int, extended: bool = False) -> int:
    """Scale an int16 axis onto the SUMD pulse range (wire value, µs × 8).

    One straight line through both ends: -32768 → 0x2260 (1100 µs), +32767 → 0x3B60 (1900 µs);
    with `extended`, 0x1C20 (900 µs) .. 0x41A0 (2100 µs). The result is
    `low + round((value + 32768) * (high - low) / 65535)`, computed in integers. The exact
    quotient is never a half (the numerator is even, the denominator odd), so there is no tie
    to break. The centre lands exactly: 0 → 0x2EE0 (1500 µs) in both ranges, because the
    line passes 0.05 (0.07 extended) of a step above it. Raises ValueError outside int16.
    """
    if not isinstance(value_int16, int) or not -32768 <= value_int16 <= 32767:
        raise ValueError(f"axis value must be an int16 (-32768..32767), got {value_int16!r}")
    low, high = (PULSE_EXTENDED_LOW, PULSE_EXTENDED_HIGH) if extended else (PULSE_LOW, PULSE_HIGH)
    numerator = (value_int16 + 32768) * (high - low)
    return low + (2 * numerator + _INT16_SPAN) // (2 * _INT16_SPAN)


def button_to_sumd(pressed: bool) -> int:
    """A button as a channel: 1900 µs pressed, 1100 µs released."""
    return PULSE_HIGH if pressed else PULSE_LOW


class SumdDecoder(StreamDecoder[SumdFrame]):
    """Streaming SUMD decoder on the common base (`usb2rc.protocols.stream`).

    A candidate is 0xA8, status 0x01/0x81 and a count of 2..32; one whose CRC fails counts in
    `crc_failures`. A failed or implausible candidate skips ONE byte and the search for the
    next 0xA8 goes on. Bytes outside frames count in `bytes_skipped`. The buffer holds at most
    one incomplete frame (68 bytes) between calls. Because frames differ in length, a
    plausible header near the end of a capture can hide a shorter frame behind it until more
    bytes come: call `flush()` at the end of the stream.
    """

    START = bytes((VENDOR_ID,))

    def _candidate_length(self, buffer: bytearray, start: int, end: int) -> int | None:
        """Frame length of a plausible header at `start`, 0 if implausible, None if cut off."""
        if end - start < HEADER_LEN:
            return None
        status, count = buffer[start + 1], buffer[start + 2]
        if status not in (STATUS_LIVE, STATUS_FAILSAFE) or not 2 <= count <= MAX_CHANNELS:
            return 0
        return frame_length(count)

    def _parse(self, buffer: bytearray, start: int, length: int) -> SumdFrame | Rejected:
        crc_at = start + length - CRC_LEN
        if crc16_xmodem(buffer[start:crc_at]) != _CRC.unpack_from(buffer, crc_at)[0]:
            return Rejected.CRC
        count = buffer[start + 2]
        channels = _CHANNELS_BY_COUNT[count].unpack_from(buffer, start + HEADER_LEN)
        return SumdFrame(buffer[start + 1] == STATUS_FAILSAFE, channels)
