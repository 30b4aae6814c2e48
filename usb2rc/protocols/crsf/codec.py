"""CRSF (Crossfire / ExpressLRS) frames, sans-IO: encoders return bytes, `CrsfDecoder` parses.

    0      address: 0xEE to a transmitter module, 0xEA to the handset, 0xC8 to a flight
           controller (the "sync" byte)
    1      length n: the bytes that follow (type + payload + CRC), 2..62
    2      type
    3..    payload (n - 2 bytes)
    last   CRC-8/DVB-S2 (poly 0xD5) over type and payload

The frames usb2rc uses (docs/ICD.md, "CRSF output"):

- RC_CHANNELS_PACKED (0x16), handset → module: 16 channels × 11 bits, LSB first
  (`usb2rc.protocols.rc11`); 26 bytes on the wire.
- LINK_STATISTICS (0x14), module → handset: 10 bytes (RSSI, link quality, SNR, antenna, RF
  mode, TX power; up- and downlink).
- RADIO_ID (0x3A) with sub-type 0x10 (timing correction, "OpenTX sync"), module → handset:
  an extended frame (destination 0xEA, origin 0xEE), then the module's packet interval and
  the handset's phase offset, both int32 big-endian in units of 0.1 µs.

The encoders raise ValueError on bad input; the decoder never raises.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.protocols import rc11
from usb2rc.protocols.crc import crc8_dvb_s2
from usb2rc.protocols.stream import Rejected, StreamDecoder

ADDRESS_FLIGHT_CONTROLLER = 0xC8  # also the "sync" byte
ADDRESS_RADIO = 0xEA  # the handset
ADDRESS_RECEIVER = 0xEC
ADDRESS_MODULE = 0xEE  # the transmitter module
ADDRESSES = frozenset({ADDRESS_FLIGHT_CONTROLLER, ADDRESS_RADIO, ADDRESS_RECEIVER, ADDRESS_MODULE})

TYPE_LINK_STATISTICS = 0x14
TYPE_RC_CHANNELS_PACKED = 0x16
TYPE_RADIO_ID = 0x3A
SUBTYPE_TIMING_CORRECTION = 0x10
EXTENDED_TYPES_FROM = 0x28  # types from here on carry destination and origin first

# Any address byte: where a candidate frame may start.
_ADDRESS_BYTE = re.compile(
    b"[" + b"".join(re.escape(bytes((a,))) for a in sorted(ADDRESSES)) + b"]"
)

MIN_LENGTH, MAX_LENGTH = 2, 62  # the length byte: type + payload + CRC
MAX_FRAME_LEN = MAX_LENGTH + 2
RC_FRAME_LEN = 2 + 1 + rc11.BLOCK_LEN + 1  # 26
LINK_STATISTICS_LEN = 10

# an RC frame's length and type bytes (little-endian), and the CRC so far after its type
_RC_LENGTH_AND_TYPE = (rc11.BLOCK_LEN + 2) | TYPE_RC_CHANNELS_PACKED << 8
_RC_TYPE_CRC = crc8_dvb_s2(bytes((TYPE_RC_CHANNELS_PACKED,)))

_LINK = struct.Struct(">BBBbBBBBBb")
_TIMING = struct.Struct(">BBBIi")


@dataclass(frozen=True, slots=True)
class RcChannels:
    """RC_CHANNELS_PACKED: 16 channel values 0..2047."""

    address: int
    channels: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class LinkStatistics:
    """LINK_STATISTICS as the module reports it. RSSI values are dBm as positive numbers
    (the wire carries -dBm); link quality in %; SNR in dB; tx power and RF mode are the
    protocol's enum indices."""

    uplink_rssi_1: int
    uplink_rssi_2: int
    uplink_link_quality: int
    uplink_snr: int
    active_antenna: int
    rf_mode: int
    uplink_tx_power: int
    downlink_rssi: int
    downlink_link_quality: int
    downlink_snr: int


@dataclass(frozen=True, slots=True)
class TimingSync:
    """RADIO_ID / timing correction: the module's packet interval (`rate`) and how far ahead
    of the module's need the handset's frames arrive, beyond a safety margin (`offset`), both
    in 0.1 µs. A positive offset: the handset may send later."""

    rate: int
    offset: int

    @property
    def interval_s(self) -> float:
        return self.rate * 1e-7

    @property
    def offset_s(self) -> float:
        return self.offset * 1e-7


@dataclass(frozen=True, slots=True)
class OtherFrame:
    """Any other valid CRSF frame, kept as it came."""

    address: int
    type: int
    payload: bytes


CrsfFrame = RcChannels | LinkStatistics | TimingSync | OtherFrame


def encode_frame(address: int, frame_type: int, payload: bytes = b"") -> bytes:
    """One CRSF frame: address, length, type, payload, CRC-8/DVB-S2."""
    if not 0 <= address <= 0xFF:
        raise ValueError(f"address must be a byte, got {address!r}")
    length = len(payload) + 2
    if not MIN_LENGTH <= length <= MAX_LENGTH:
        raise ValueError(f"a CRSF payload holds 0..{MAX_LENGTH - 2} bytes, got {len(payload)}")
    body = bytes((frame_type,)) + payload
    return bytes((address, length)) + body + bytes((crc8_dvb_s2(body),))


def encode_rc_channels(channels: Sequence[int], address: int = ADDRESS_MODULE) -> bytes:
    """RC_CHANNELS_PACKED of 16 values 0..2047 (26 bytes): `encode_frame`'s bytes, from the
    block's integer with the frame's other fields in one `int.to_bytes`."""
    block = rc11.block(channels)
    if not 0 <= address <= 0xFF:
        raise ValueError(f"address must be a byte, got {address!r}")
    payload = block.to_bytes(rc11.BLOCK_LEN, "little")
    crc = crc8_dvb_s2(payload, _RC_TYPE_CRC)
    frame = address | _RC_LENGTH_AND_TYPE << 8 | block << 24 | crc << (8 * (RC_FRAME_LEN - 1))
    return frame.to_bytes(RC_FRAME_LEN, "little")


def encode_link_statistics(stats: LinkStatistics, address: int = ADDRESS_RADIO) -> bytes:
    payload = _LINK.pack(
        stats.uplink_rssi_1,
        stats.uplink_rssi_2,
        stats.uplink_link_quality,
        stats.uplink_snr,
        stats.active_antenna,
        stats.rf_mode,
        stats.uplink_tx_power,
        stats.downlink_rssi,
        stats.downlink_link_quality,
        stats.downlink_snr,
    )
    return encode_frame(address, TYPE_LINK_STATISTICS, payload)


def encode_timing_sync(rate: int, offset: int) -> bytes:
    """The module's timing correction frame (0.1 µs units), as an ELRS module sends it."""
    payload = _TIMING.pack(ADDRESS_RADIO, ADDRESS_MODULE, SUBTYPE_TIMING_CORRECTION, rate, offset)
    return encode_frame(ADDRESS_RADIO, TYPE_RADIO_ID, payload)


def parse_frame(address: int, frame_type: int, payload: bytes) -> CrsfFrame:
    """A frame whose CRC matched, as its typed record (OtherFrame when not one of ours or
    when its payload is too short for its type)."""
    if frame_type == TYPE_RC_CHANNELS_PACKED and len(payload) >= rc11.BLOCK_LEN:
        return RcChannels(address, rc11.unpack(payload))
    if frame_type == TYPE_LINK_STATISTICS and len(payload) >= LINK_STATISTICS_LEN:
        return LinkStatistics(*_LINK.unpack_from(payload))
    if (
        frame_type == TYPE_RADIO_ID
        and len(payload) >= _TIMING.size
        and payload[2] == SUBTYPE_TIMING_CORRECTION
    ):
        _dest, _origin, _sub, rate, offset = _TIMING.unpack_from(payload)
        return TimingSync(rate, offset)
    return OtherFrame(address, frame_type, bytes(payload))


class CrsfDecoder(StreamDecoder[CrsfFrame]):
    """Streaming CRSF decoder on the common base (`usb2rc.protocols.stream`).

    A candidate is a known address byte followed by a length of 2..62; one whose CRC fails
    counts in `crc_failures`. A failed or implausible candidate skips ONE byte and the search
    goes on. Bytes outside frames count in `bytes_skipped`. Call `flush()` at the end of the
    stream (a plausible header near the end waits for bytes that never come)."""

    def _find_start(self, buffer: bytearray, pos: int, end: int) -> int:
        if pos < end and buffer[pos] in ADDRESSES:
            return pos  # the usual case: a frame right after the last one
        found = _ADDRESS_BYTE.search(buffer, pos)
        return -1 if found is None else found.start()

    def _candidate_length(self, buffer: bytearray, start: int, end: int) -> int | None:
        if end - start < 2:
            return None
        length = buffer[start + 1]
        return length + 2 if MIN_LENGTH <= length <= MAX_LENGTH else 0

    def _parse(self, buffer: bytearray, start: int, length: int) -> CrsfFrame | Rejected:
        frame_end = start + length
        body = bytes(buffer[start + 2 : frame_end - 1])
        if crc8_dvb_s2(body) != buffer[frame_end - 1]:
            return Rejected.CRC
        return parse_frame(buffer[start], body[0], body[1:])
