"""A second CRSF / SBUS decoder, written for the tests from the protocol descriptions alone
(docs/ICD.md, "CRSF output" and "SBUS output"), bit by bit, sharing no code with
usb2rc.protocols: the codec's frames are checked against it, and the end-to-end tests read
the daemon's lines with it.

- CRC-8/DVB-S2: polynomial x^8 + x^7 + x^6 + x^4 + x^2 + 1 (0xD5), MSB first, init 0, over
  the type and payload of a CRSF frame.
- 11-bit channels, LSB first: channel n's bit k is bit (11n + k) of the block, which is bit
  (11n + k) mod 8 of byte (11n + k) div 8.
"""

from __future__ import annotations

from dataclasses import dataclass, field


def crc8_d5(data: bytes) -> int:
    crc = 0
    for byte in data:
        for bit in range(7, -1, -1):  # MSB first
            top = (crc >> 7) & 1
            crc = (crc << 1) & 0xFF
            if top ^ ((byte >> bit) & 1):
                crc ^= 0xD5
    return crc


def channels11(block: bytes, count: int = 16) -> list[int]:
    values = []
    for n in range(count):
        value = 0
        for k in range(11):
            bit = 11 * n + k
            if block[bit // 8] >> (bit % 8) & 1:
                value |= 1 << k
        values.append(value)
    return values


@dataclass
class RefCrsfFrame:
    address: int
    type: int
    payload: bytes

    @property
    def channels(self) -> list[int]:
        return channels11(self.payload)


@dataclass
class RefSbusFrame:
    channels: list[int]
    ch17: bool
    ch18: bool
    frame_lost: bool
    failsafe: bool


@dataclass
class RefCrsfReader:
    """Frames to a module (0xEE) or handset (0xEA) or FC (0xC8), CRC-checked."""

    buffer: bytearray = field(default_factory=bytearray)
    bad: int = 0

    def feed(self, data: bytes) -> list[RefCrsfFrame]:
        self.buffer += data
        out = []
        while len(self.buffer) >= 2:
            if self.buffer[0] not in (0xEE, 0xEA, 0xC8) or not 2 <= self.buffer[1] <= 62:
                del self.buffer[0]
                continue
            total = self.buffer[1] + 2
            if len(self.buffer) < total:
                break
            frame = bytes(self.buffer[:total])
            if crc8_d5(frame[2:-1]) != frame[-1]:
                self.bad += 1
                del self.buffer[0]
                continue
            out.append(RefCrsfFrame(frame[0], frame[2], frame[3:-1]))
            del self.buffer[:total]
        return out


@dataclass
class RefSbusReader:
    buffer: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[RefSbusFrame]:
        self.buffer += data
        out = []
        while len(self.buffer) >= 25:
            if self.buffer[0] != 0x0F or self.buffer[24] != 0x00:
                del self.buffer[0]
                continue
            out.append(parse_sbus(bytes(self.buffer[:25])))
            del self.buffer[:25]
        return out


def parse_sbus(frame: bytes) -> RefSbusFrame:
    flags = frame[23]
    return RefSbusFrame(
        channels11(frame[1:23]),
        ch17=bool(flags & 1),
        ch18=bool(flags & 2),
        frame_lost=bool(flags & 4),
        failsafe=bool(flags & 8),
    )


def crsf_frame(address: int, frame_type: int, payload: bytes) -> bytes:
    """A CRSF frame built from the description (for a fake module's replies)."""
    body = bytes([frame_type]) + payload
    return bytes([address, len(body) + 1]) + body + bytes([crc8_d5(body)])


def rc11(value_int16: int) -> int:
    """The documented scaling (docs/ICD.md): 172 + round((v + 32768) * 1639 / 65535)."""
    from fractions import Fraction

    return 172 + round(Fraction((value_int16 + 32768) * 1639, 65535))
