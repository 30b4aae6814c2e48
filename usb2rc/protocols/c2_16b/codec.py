"""SERaero C2-16B frames, sans-IO: encoders return bytes, `Decoder.feed` turns bytes into frames.

A frame is 35 bytes, followed by an LF (0x0A) unless `line_feed=False`:

    0-1    "H-"
    2      status: data '>' '!' '<' '&' '%', or service '1'..'8' (ASCII) / 0x01..0x08 (binary)
    3      Node-ID
    4      message code (destination ID in '&' frames); service code in service frames
           (usb2rc sends 0x00; the decoder accepts any value, docs/ICD.md "Service code")
    5-24   10 axes, 16 bit little-endian (X, Y, Z, Slider, Rx, Ry, Rz, Dial, Aux1, Aux2)
    25-28  button group 1, uint32 little-endian
    29-32  button group 2, uint32 little-endian
    33-34  CRC-16/ARC over bytes 0-32, low byte first

Service frames carry a 28-byte payload in bytes 5-32, zero-filled after its content.
Encoders raise ValueError on any bad argument; the decoder never raises.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import TypeAlias

from usb2rc.config.layout import AXIS_COUNT, AXIS_NAMES, STARTUP_NODE_ID
from usb2rc.protocols.crc import arc_position_table, crc16_arc
from usb2rc.protocols.stream import Rejected, StreamDecoder, header_tail

FRAME_LEN = 35
HEADER = b"H-"
LF = 0x0A

LIVE = 0x3E  # '>'
FAILSAFE = 0x21  # '!'
CONFIG_REQUEST = 0x3C  # '<'
HANDOVER = 0x26  # '&'
LOW_BATTERY = 0x25  # '%'

DATA_STATUS_NAMES: dict[int, str] = {
    LIVE: "live",
    FAILSAFE: "failsafe",
    CONFIG_REQUEST: "config-request",
    HANDOVER: "handover",
    LOW_BATTERY: "low-battery",
}
DATA_STATUSES = frozenset(DATA_STATUS_NAMES)

# The one home of the node layout on the wire (every other module imports these).
PAYLOAD_LEN = 28  # bytes 5-32 of a service frame
TEXT_LEN = 12  # device string, device type and startup text: at most 12 ASCII bytes
ASCII_SERVICE_OFFSET = 0x30  # service n is sent as the character '0' + n by default

_CRC_OFFSET = FRAME_LEN - 2
_DATA_BODY = struct.Struct("<10HII")  # bytes 5-32 of a data frame, the axes as uint16
_FRAME = struct.Struct(f"<2sBBB{PAYLOAD_LEN}sH")  # a whole frame from its parts
_FRAME_LF = struct.Struct(f"<2sBBB{PAYLOAD_LEN}sHB")  # ... and its LF
_DATA_FIELDS = struct.Struct("<BBB10hII")  # bytes 2-32 with the axes as int16 (decoding)
_CRC = struct.Struct("<H")
_VID_PID = struct.Struct("<HH")
_UINT16_MASK = 0xFFFF

# The CRC is linear (usb2rc.protocols.crc): a frame's is the XOR of the header's share, each
# header byte's share at its position and the CRC of bytes 5-32 (5 leading zero bytes do not
# change a CRC that starts at 0). A frame is then one CRC over the bytes that changed.
_HEADER_CRC = crc16_arc(HEADER + bytes(_CRC_OFFSET - len(HEADER)))
_STATUS_CRC = arc_position_table(2, _CRC_OFFSET)
_NODE_CRC = arc_position_table(3, _CRC_OFFSET)
_CODE_CRC = arc_position_table(4, _CRC_OFFSET)


class Service(IntEnum):
    """Service frame kinds; the value is the binary status byte (ASCII: '0' + value)."""

    CONNECTED = 1
    DISCONNECTED = 2
    ERROR = 3
    POLL = 4
    DEVICE_STRING = 5
    VID_PID = 6
    DEVICE_TYPE = 7
    STARTUP = 8

    @property
    def service_name(self) -> str:
        """`"connected"`, `"vid-pid"`, `"device-string"`, ... as the CLI and docs name it."""
        return self.name.lower().replace("_", "-")


_TEXT_SERVICES = frozenset({Service.DEVICE_STRING, Service.DEVICE_TYPE, Service.STARTUP})

# Status byte on the wire -> service, for both encodings.
_SERVICE_BY_STATUS: dict[int, Service] = {
    **{service.value: service for service in Service},
    **{ASCII_SERVICE_OFFSET + service.value: service for service in Service},
}

# bytes.translate table: printable ASCII stays, everything else becomes '?'.
_PRINTABLE_OR_QUESTION = bytes(b if 0x20 <= b <= 0x7E else ord("?") for b in range(256))


@dataclass(frozen=True, slots=True)
class DataFrame:
    """A data frame: status is one of `> ! < & %` as an int byte; axes as int16 when decoded."""

    status: int
    node_id: int
    code: int
    axes: tuple[int, ...]
    group1: int
    group2: int


@dataclass(frozen=True, slots=True)
class ServiceFrame:
    """A service frame. `payload` is always the 28 bytes 5-32 (shorter input is zero-filled).

    `code` is byte 4, the ICD's "Service Code": usb2rc sends 0, but its codes are left TBD
    by the ICD, so a frame from another implementation may carry any value."""

    service: Service
    node_id: int
    payload: bytes = bytes(PAYLOAD_LEN)
    binary_status: bool = False
    code: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.service, Service):
            object.__setattr__(self, "service", _as_service(self.service))
        if type(self.payload) is not bytes or len(self.payload) != PAYLOAD_LEN:
            object.__setattr__(self, "payload", _padded_payload(self.payload))

    @property
    def vid(self) -> int | None:
        """Vendor ID of a VID_PID frame (bytes 5-6), else None."""
        if self.service is not Service.VID_PID:
            return None
        vid: int = _VID_PID.unpack_from(self.payload)[0]
        return vid

    @property
    def pid(self) -> int | None:
        """Product ID of a VID_PID frame (bytes 7-8), else None."""
        if self.service is not Service.VID_PID:
            return None
        pid: int = _VID_PID.unpack_from(self.payload)[1]
        return pid

    @property
    def text(self) -> str | None:
        """ASCII text up to the first NUL (DEVICE_STRING, DEVICE_TYPE, STARTUP), else None.

        Bytes that are not printable ASCII read as '?'.
        """
        if self.service not in _TEXT_SERVICES:
            return None
        raw = self.payload.split(b"\0", 1)[0]
        return raw.translate(_PRINTABLE_OR_QUESTION).decode("ascii")

    @property
    def error_code(self) -> int | None:
        """Device error code of an ERROR frame (byte 5), else None."""
        if self.service is not Service.ERROR:
            return None
        return self.payload[0]


Frame: TypeAlias = DataFrame | ServiceFrame


# --- encoding ------------------------------------------------------------------------------


def _check_int(name: str, value: object, low: int, high: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise ValueError(f"{name} must be an int in {low}..{high}, got {value!r}")
    return value


def _as_service(service: object) -> Service:
    if isinstance(service, Service):
        return service
    if isinstance(service, int) and not isinstance(service, bool) and 1 <= service <= 8:
        return Service(service)
    raise ValueError(f"service must be a Service (1..8), got {service!r}")


def _padded_payload(payload: object) -> bytes:
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise ValueError(f"payload must be bytes, got {type(payload).__name__}")
    raw = bytes(payload)
    if len(raw) > PAYLOAD_LEN:
        raise ValueError(f"payload is {len(raw)} bytes, a service frame holds {PAYLOAD_LEN}")
    return raw.ljust(PAYLOAD_LEN, b"\0")


def _check_data_status(status: object) -> int:
    if isinstance(status, int) and not isinstance(status, bool) and status in DATA_STATUSES:
        return status
    if isinstance(status, int) and status in _SERVICE_BY_STATUS:
        hint = " (service frames are built with encode_service)"
    else:
        hint = ""
    raise ValueError(
        "status must be a data status byte: '>' 0x3E, '!' 0x21, '<' 0x3C, '&' 0x26 or "
        f"'%' 0x25, got {status!r}{hint}"
    )


def _wire_axes(axes: Sequence[int]) -> list[int]:
    """Axes as uint16 for packing; accepts int16 or uint16 values (-32768..65535)."""
    if len(axes) != AXIS_COUNT:
        raise ValueError(f"expected {AXIS_COUNT} axes {AXIS_NAMES}, got {len(axes)}")
    # Fast path with C-level builtins; the per-axis loop only runs to name the bad axis.
    if set(map(type, axes)) != {int} or min(axes) < -32768 or max(axes) > 65535:
        values: Sequence[object] = axes  # compiled, an `int` would take a bool as 0 or 1
        for name, value in zip(AXIS_NAMES, values, strict=True):
            _check_int(f"axis {name}", value, -32768, 65535)
    return list(map(_UINT16_MASK.__and__, axes))


def _frame(
    status: int, node_id: int, code: int, body: bytes, line_feed: bool, body_crc: int
) -> bytes:
    """A frame from its checked parts: the CRC from the header bytes' shares (one lookup
    each) and `body_crc`, the CRC of the 28-byte body."""
    crc = _HEADER_CRC ^ _STATUS_CRC[status] ^ _NODE_CRC[node_id] ^ _CODE_CRC[code] ^ body_crc
    if line_feed:
        return _FRAME_LF.pack(HEADER, status, node_id, code, body, crc, LF)
    return _FRAME.pack(HEADER, status, node_id, code, body, crc)


def _data_checks_pass(status: object, node_id: object, code: object) -> bool:
    """The checks of the usual, valid case in one expression (`type(x) is int` excludes
    bool as the named checks do)."""
    return (
        type(status) is int
        and status in DATA_STATUSES
        and type(node_id) is int
        and 0 <= node_id <= 255
        and type(code) is int
        and 0 <= code <= 255
    )


def _groups_pass(group1: object, group2: object) -> bool:
    return (
        type(group1) is int
        and 0 <= group1 <= 0xFFFFFFFF
        and type(group2) is int
        and 0 <= group2 <= 0xFFFFFFFF
    )


def encode_data(
    status: int,
    node_id: int,
    code: int,
    axes: Sequence[int],
    group1: int,
    group2: int,
    *,
    line_feed: bool = True,
) -> bytes:
    """A data frame. Axes take int16 or uint16 values (-32768..65535), packed little-endian."""
    body = _checked_body(status, node_id, code, axes, group1, group2)
    return _frame(status, node_id, code, body, line_feed, crc16_arc(body))


class DataFrames:
    """`encode_data` for one output's frames: each node's body (bytes 5-32: axes and
    buttons) and its CRC are kept while that content stays the same, so a frame whose
    content did not change gets only its status, code and CRC (three table lookups)."""

    def __init__(self, line_feed: bool = True) -> None:
        self.line_feed = line_feed
        # node_id -> ((axes, group1, group2), body, the body's CRC)
        self._kept: dict[int, tuple[tuple[tuple[int, ...], int, int], bytes, int]] = {}

    def encode(
        self,
        status: int,
        node_id: int,
        code: int,
        axes: Sequence[int],
        group1: int,
        group2: int,
    ) -> bytes:
        content = (tuple(axes), group1, group2)
        kept = self._kept.get(node_id)
        if kept is None or kept[0] != content or not _data_checks_pass(status, node_id, code):
            body = _checked_body(status, node_id, code, axes, group1, group2)
            kept = (content, body, crc16_arc(body))
            self._kept[node_id] = kept
        return _frame(status, node_id, code, kept[1], self.line_feed, kept[2])


def _checked_body(
    status: int, node_id: int, code: int, axes: Sequence[int], group1: int, group2: int
) -> bytes:
    """Bytes 5-32 of a data frame, after every argument's check (ValueError)."""
    if not (_data_checks_pass(status, node_id, code) and _groups_pass(group1, group2)):
        # the named checks, in their order, to say what is wrong
        _check_data_status(status)
        _check_int("node_id", node_id, 0, 255)
        _check_int("code", code, 0, 255)
        _wire_axes(axes)  # its error before the groups', in the legacy encoder's order
        _check_int("group1", group1, 0, 0xFFFFFFFF)
        _check_int("group2", group2, 0, 0xFFFFFFFF)
    return _DATA_BODY.pack(*_wire_axes(axes), group1, group2)


def encode_service(
    service: Service | int,
    node_id: int,
    payload: bytes = b"",
    *,
    binary_status: bool = False,
    line_feed: bool = True,
    code: int = 0,
) -> bytes:
    """A service frame; status '1'..'8' (or 0x01..0x08 with binary_status); byte 4 is the
    service code, 0 in everything usb2rc sends."""
    kind = _as_service(service)
    _check_int("node_id", node_id, 0, 255)
    _check_int("service code", code, 0, 255)
    wire_payload = _padded_payload(payload)
    status = kind.value if binary_status else ASCII_SERVICE_OFFSET + kind.value
    return _frame(status, node_id, code, wire_payload, line_feed, crc16_arc(wire_payload))


def ascii_field(text: str, limit: int = TEXT_LEN) -> bytes:
    """`text` as at most `limit` ASCII bytes; characters that are not printable ASCII → '?'."""
    if not isinstance(text, str):
        raise ValueError(f"text must be a str, got {type(text).__name__}")
    cleaned = "".join(char if " " <= char <= "~" else "?" for char in text[:limit])
    return cleaned.encode("ascii")


def connected(node_id: int, **options: bool) -> bytes:
    """Service '1': a USB device on this node connected."""
    return encode_service(Service.CONNECTED, node_id, b"", **options)


def disconnected(node_id: int, **options: bool) -> bytes:
    """Service '2': the node's USB device disconnected."""
    return encode_service(Service.DISCONNECTED, node_id, b"", **options)


def device_error(node_id: int, code: int, **options: bool) -> bytes:
    """Service '3': device error, `code` (0..255) in byte 5."""
    _check_int("error code", code, 0, 255)
    return encode_service(Service.ERROR, node_id, bytes([code]), **options)


def poll_request(node_id: int, **options: bool) -> bytes:
    """Service '4': request a device poll of this node."""
    return encode_service(Service.POLL, node_id, b"", **options)


def device_string(node_id: int, text: str, **options: bool) -> bytes:
    """Service '5': product string, ASCII, at most 12 bytes, NUL padded."""
    return encode_service(Service.DEVICE_STRING, node_id, ascii_field(text), **options)


def vid_pid(node_id: int, vid: int, pid: int, **options: bool) -> bytes:
    """Service '6': vendor ID in bytes 5-6, product ID in bytes 7-8, little-endian."""
    payload = _VID_PID.pack(_check_int("vid", vid, 0, 0xFFFF), _check_int("pid", pid, 0, 0xFFFF))
    return encode_service(Service.VID_PID, node_id, payload, **options)


def device_type(node_id: int, text: str, **options: bool) -> bytes:
    """Service '7': device type (`JOYSTICK`, `GAMEPAD`, ...), ASCII, at most 12 bytes."""
    return encode_service(Service.DEVICE_TYPE, node_id, ascii_field(text), **options)


def startup(version: str, **options: bool) -> bytes:
    """Service '8' from Node-ID 0xFF with `usb2rc X.Y.Z` in bytes 5-16.

    Raises ValueError when the text does not fit the 12 bytes rather than cutting it.
    """
    text = f"usb2rc {version}"
    if len(text) > TEXT_LEN:
        raise ValueError(f"startup text {text!r} is longer than {TEXT_LEN} bytes (bytes 5-16)")
    return encode_service(Service.STARTUP, STARTUP_NODE_ID, ascii_field(text), **options)


def encode(frame: Frame, *, line_feed: bool = True) -> bytes:
    """Encode a DataFrame or ServiceFrame (the service frame's own status encoding)."""
    if isinstance(frame, DataFrame):
        return encode_data(
            frame.status,
            frame.node_id,
            frame.code,
            frame.axes,
            frame.group1,
            frame.group2,
            line_feed=line_feed,
        )
    if isinstance(frame, ServiceFrame):
        return encode_service(
            frame.service,
            frame.node_id,
            frame.payload,
            binary_status=frame.binary_status,
            line_feed=line_feed,
            code=frame.code,
        )
    raise ValueError(f"not a C2-16B frame: {frame!r}")


# --- decoding ------------------------------------------------------------------------------


def _decode_data(buffer: bytearray, start: int) -> DataFrame:
    fields = _DATA_FIELDS.unpack_from(buffer, start + 2)
    return DataFrame(fields[0], fields[1], fields[2], fields[3:13], fields[13], fields[14])


class Decoder(StreamDecoder[Frame]):
    """Streaming C2-16B decoder (`usb2rc.protocols.stream`): `feed(chunk)` returns the frames
    completed by that chunk.

    Works for any chunking (one byte at a time included) and never raises. A candidate is an
    `H-` followed by a known status; byte 4 may hold anything (a service frame's service code
    is left TBD by the ICD, so another implementation may set one: `ServiceFrame.code`). A
    candidate whose CRC fails counts in `crc_failures`; a failed or implausible candidate skips
    ONE byte and the search for the next `H-` goes on, so a frame starting inside a corrupted
    region is still found. An LF right after a frame is consumed silently; every other byte
    that is not part of a frame counts in `bytes_skipped`. The buffer never holds more than
    one incomplete frame (34 bytes) between calls.
    """

    START = HEADER
    FRAME_LEN = FRAME_LEN  # the status is checked with the CRC, once all 35 bytes are in

    def __init__(self) -> None:
        super().__init__()
        self._lf_may_follow = False  # the buffer ended right after a frame

    def _scan_from(self, buffer: bytearray, end: int) -> int:
        """The previous chunk ended right after a frame: an LF starting this one is its LF."""
        if not self._lf_may_follow or end == 0:
            return 0
        self._lf_may_follow = False
        return 1 if buffer[0] == LF else 0

    def _after_frame(self, buffer: bytearray, pos: int, end: int) -> int:
        """Consume the LF after a frame ending at `pos`, or remember that it may come next."""
        if pos == end:
            self._lf_may_follow = True
            return pos
        return pos + 1 if buffer[pos] == LF else pos

    def _keep_tail(self, buffer: bytearray, pos: int, end: int) -> int:
        """No `H-` from pos on: skip everything but a trailing 'H' that may start one."""
        return header_tail(buffer, pos, end, HEADER)

    def _stream_ended(self) -> None:
        self._lf_may_follow = False

    def _parse(self, buffer: bytearray, start: int, length: int) -> Frame | Rejected:
        status = buffer[start + 2]
        service = _SERVICE_BY_STATUS.get(status)
        if service is None and status not in DATA_STATUSES:
            return Rejected.SHAPE
        crc_end = start + _CRC_OFFSET
        if crc16_arc(buffer[start:crc_end]) != _CRC.unpack_from(buffer, crc_end)[0]:
            return Rejected.CRC
        if service is None:
            return _decode_data(buffer, start)
        payload = bytes(buffer[start + 5 : crc_end])
        binary = status < ASCII_SERVICE_OFFSET
        return ServiceFrame(service, buffer[start + 3], payload, binary, buffer[start + 4])
