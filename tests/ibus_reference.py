"""A second iBus decoder, written from the protocol description alone (FlySky iBus servo
frames as flight-controller firmware documents them), sharing no code with usb2rc:

    a frame is 32 bytes: 0x20 (length), 0x40 (command), then 14 channels as 16-bit
    little-endian pulse lengths in microseconds, then a 16-bit little-endian checksum equal
    to 0xFFFF minus the sum of the 30 bytes before it.

It hunts for 0x20 0x40 byte by byte, so it shares no resync logic with usb2rc's decoder."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RefIbusFrame:
    channels: list[int]


class RefIbusReader:
    """Bytes in, frames out; a bad checksum drops the first byte and hunts again."""

    def __init__(self) -> None:
        self.pending = b""
        self.bad_checksums = 0

    def feed(self, data: bytes) -> list[RefIbusFrame]:
        self.pending += data
        frames = []
        while len(self.pending) >= 32:
            if self.pending[0] != 0x20 or self.pending[1] != 0x40:
                self.pending = self.pending[1:]
                continue
            candidate = self.pending[:32]
            wanted = 0xFFFF - sum(candidate[:30])
            if candidate[30] | candidate[31] << 8 != wanted:
                self.bad_checksums += 1
                self.pending = self.pending[1:]
                continue
            frames.append(
                RefIbusFrame([candidate[2 + 2 * i] | candidate[3 + 2 * i] << 8 for i in range(14)])
            )
            self.pending = self.pending[32:]
        return frames


def microseconds(value_int16: int) -> int:
    """The documented scaling (docs/ICD.md, "iBus output"): an int16 axis straight onto
    1000..2000 µs, rounded to the nearest µs."""
    exact = (value_int16 + 32768) * 1000 / 65535
    return 1000 + int(exact + 0.5)
