"""Futaba SBUS frames, sans-IO: `encode_sbus` returns bytes, `SbusDecoder` parses them.

    0       0x0F header
    1..22   channels 1..16, 11 bits each, LSB first (`usb2rc.protocols.rc11`)
    23      flags: bit 0 channel 17, bit 1 channel 18 (digital), bit 2 frame lost,
            bit 3 failsafe; bits 4..7 zero
    24      0x00 footer

100000 baud, 8 data bits, even parity, 2 stop bits (12 bit times a byte), inverted on the
wire (docs/PI.md, "SBUS wiring"). No checksum: a decoder takes a 0x0F ... 0x00 pair 24 bytes
apart (receivers do not check the flags byte's unused bits, and published frames set them).

The encoder raises ValueError on bad input; the decoder never raises.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.protocols import rc11
from usb2rc.protocols.stream import Rejected, StreamDecoder

HEADER = 0x0F
FOOTER = 0x00
FRAME_LEN = 25
FLAGS_AT = 1 + rc11.BLOCK_LEN  # 23
FLAG_CH17 = 0x01
FLAG_CH18 = 0x02
FLAG_FRAME_LOST = 0x04
FLAG_FAILSAFE = 0x08
BAUDRATE = 100000
BITS_PER_BYTE = 12  # start, 8 data, even parity, 2 stop


@dataclass(frozen=True, slots=True)
class SbusFrame:
    """One SBUS frame: 16 analogue channels 0..2047, the two digital ones, the two flags."""

    channels: tuple[int, ...]
    ch17: bool = False
    ch18: bool = False
    frame_lost: bool = False
    failsafe: bool = False


def encode_sbus(
    channels: Sequence[int],
    *,
    ch17: bool = False,
    ch18: bool = False,
    frame_lost: bool = False,
    failsafe: bool = False,
) -> bytes:
    """A 25-byte SBUS frame of 16 channel values 0..2047 and the flags."""
    flags = (
        (FLAG_CH17 if ch17 else 0)
        | (FLAG_CH18 if ch18 else 0)
        | (FLAG_FRAME_LOST if frame_lost else 0)
        | (FLAG_FAILSAFE if failsafe else 0)
    )
    # the whole frame as one little-endian integer: header, block, flags, footer (0)
    frame = HEADER | rc11.block(channels) << 8 | flags << (8 * FLAGS_AT)
    return frame.to_bytes(FRAME_LEN, "little")


def parse_frame(data: bytes | bytearray | memoryview) -> SbusFrame:
    """The frame at the start of `data` (25 bytes, header and footer already checked)."""
    flags = data[FLAGS_AT]
    return SbusFrame(
        rc11.unpack(data[1:FLAGS_AT]),
        ch17=bool(flags & FLAG_CH17),
        ch18=bool(flags & FLAG_CH18),
        frame_lost=bool(flags & FLAG_FRAME_LOST),
        failsafe=bool(flags & FLAG_FAILSAFE),
    )


class SbusDecoder(StreamDecoder[SbusFrame]):
    """Streaming SBUS decoder on the common base (`usb2rc.protocols.stream`).

    A frame is 0x0F, 22 bytes, a flags byte, 0x00. Anything else skips ONE byte. SBUS has
    no CRC (`crc_failures` stays 0; it is there for the common summary)."""

    START = bytes((HEADER,))
    FRAME_LEN = FRAME_LEN

    def _parse(self, buffer: bytearray, start: int, length: int) -> SbusFrame | Rejected:
        if buffer[start + FRAME_LEN - 1] != FOOTER:
            return Rejected.SHAPE
        return parse_frame(buffer[start : start + FRAME_LEN])
