"""CRSF device ping and device info, sans-IO: who is on a CRSF line, and which firmware.

Both are extended frames (types from 0x28 on carry a destination and an origin address first):

    [address][length][type][destination][origin][payload][CRC-8/DVB-S2]

- DEVICE_PING (0x28), handset → any device: no payload. Sent to the broadcast destination
  (0x00), every device on the line answers.
- DEVICE_INFO (0x29), device → whoever pinged: the device's name (null-terminated), then
  its serial number (4 bytes), hardware id (4), software id (4, big-endian), the number of
  its parameters (1) and the parameter protocol version (1). An ExpressLRS device gives
  `ELRS` as its serial number and its version major.minor.patch in the software id's low
  three bytes (3.4.0 is 00 03 04 00); TBS gives major.minor in the low two (00 00 05 0F is
  5.15).

`encode_device_ping` returns the bytes to write; `device_info_of` picks a DEVICE_INFO out
of what `codec.CrsfDecoder` parsed (an `OtherFrame`: the codec keeps the types it does not
know as they came). Nothing here raises on what a device sends: a frame that is not a
whole device info is None.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from usb2rc.protocols.crsf import codec

TYPE_DEVICE_PING = 0x28
TYPE_DEVICE_INFO = 0x29
ADDRESS_BROADCAST = 0x00  # a ping's destination: every device answers
SERIAL_ELRS = b"ELRS"  # what ExpressLRS devices give as their serial number

_IDS = struct.Struct(">4sIIBB")  # serial number, hardware id, software id, count, version


@dataclass(frozen=True)
class DeviceInfo:
    """One device's DEVICE_INFO: the addresses it came with and its fields."""

    destination: int
    origin: int
    name: str  # as the device names itself (UTF-8, undecodable bytes replaced)
    serial_number: bytes  # 4 bytes; `ELRS` on ExpressLRS devices
    hardware_id: int
    software_id: int
    parameter_count: int
    protocol_version: int

    @property
    def firmware(self) -> str:
        """The software id as a dotted version: its bytes, high to low, leading zero bytes
        left out (3.4.0 for ExpressLRS's 00 03 04 00, 5.15 for TBS's 00 00 05 0F)."""
        parts = list(self.software_id.to_bytes(4, "big"))
        while len(parts) > 1 and parts[0] == 0:
            del parts[0]
        return ".".join(map(str, parts))

    @property
    def maker(self) -> str:
        """`ExpressLRS` when the serial number says so, else `CRSF` (the protocol is all that
        is known for sure)."""
        return "ExpressLRS" if self.serial_number == SERIAL_ELRS else "CRSF"


def encode_device_ping(
    address: int = codec.ADDRESS_MODULE,
    destination: int = ADDRESS_BROADCAST,
    origin: int = codec.ADDRESS_RADIO,
) -> bytes:
    """A DEVICE_PING as a handset sends it: to `address` (the frame's first byte: 0xEE a
    transmitter module, 0xC8 a flight controller), for `destination` (every device), from
    `origin` (the handset). Raises ValueError when an address is not a byte."""
    for value in (destination, origin):
        if not 0 <= value <= 0xFF:
            raise ValueError(f"address must be a byte, got {value!r}")
    return codec.encode_frame(address, TYPE_DEVICE_PING, bytes((destination, origin)))


def parse_device_info(payload: bytes) -> DeviceInfo | None:
    """A DEVICE_INFO's payload (what follows the type byte: destination, origin, name, ids),
    or None when it is cut short or its name has no terminating null."""
    if len(payload) < 2:
        return None
    destination, origin = payload[0], payload[1]
    end = payload.find(b"\0", 2)
    if end < 0 or len(payload) - (end + 1) < _IDS.size:
        return None
    name = payload[2:end].decode("utf-8", "replace")
    serial, hardware, software, count, version = _IDS.unpack_from(payload, end + 1)
    return DeviceInfo(destination, origin, name, serial, hardware, software, count, version)


def device_info_of(frame: codec.CrsfFrame) -> DeviceInfo | None:
    """The DEVICE_INFO a decoded frame holds, or None (another type, or not whole)."""
    if not isinstance(frame, codec.OtherFrame) or frame.type != TYPE_DEVICE_INFO:
        return None
    return parse_device_info(frame.payload)
