"""The four stream decoders as they were before `usb2rc.protocols.stream` (issue 21): the
reference that tests/test_stream_decoder.py holds the new ones to, frame for frame and counter
for counter. Copied unchanged but for imports; do not edit them to follow the new code."""

from __future__ import annotations

from usb2rc.protocols.c2_16b.codec import (
    _CRC as _C2_CRC,
)
from usb2rc.protocols.c2_16b.codec import (
    _CRC_OFFSET,
    _SERVICE_BY_STATUS,
    ASCII_SERVICE_OFFSET,
    DATA_STATUSES,
    LF,
    Frame,
    ServiceFrame,
    _decode_data,
)
from usb2rc.protocols.c2_16b.codec import (
    FRAME_LEN as C2_FRAME_LEN,
)
from usb2rc.protocols.c2_16b.codec import (
    HEADER as C2_HEADER,
)
from usb2rc.protocols.crc import crc8_dvb_s2, crc16_arc, crc16_xmodem
from usb2rc.protocols.crsf.codec import ADDRESSES, MAX_LENGTH, MIN_LENGTH, CrsfFrame
from usb2rc.protocols.crsf.codec import parse_frame as parse_crsf
from usb2rc.protocols.sbus.codec import FOOTER, SbusFrame
from usb2rc.protocols.sbus.codec import FRAME_LEN as SBUS_FRAME_LEN
from usb2rc.protocols.sbus.codec import HEADER as SBUS_HEADER
from usb2rc.protocols.sbus.codec import parse_frame as parse_sbus
from usb2rc.protocols.sumd.codec import (
    _CHANNELS_BY_COUNT,
    _CRC,
    CRC_LEN,
    HEADER_LEN,
    MAX_CHANNELS,
    STATUS_FAILSAFE,
    STATUS_LIVE,
    VENDOR_ID,
    SumdFrame,
    frame_length,
)


class OldC2Decoder:
    """Streaming C2-16B decoder: `feed(chunk)` returns the frames completed by that chunk.

    Works for any chunking (one byte at a time included) and never raises. A candidate is an
    `H-` followed by a known status; byte 4 may hold anything (a service frame's service code
    is left TBD by the ICD, so another implementation may set one: `ServiceFrame.code`). A
    candidate whose CRC fails counts in `crc_failures`; a failed or implausible candidate skips
    ONE byte and the search for the next `H-` goes on, so a frame starting inside a corrupted
    region is still found. An LF right after a frame is consumed silently; every other byte
    that is not part of a frame counts in `bytes_skipped`. The buffer never holds more than
    one incomplete frame (34 bytes) between calls.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._lf_may_follow = False  # the buffer ended right after a frame
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bytes_in = 0

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Frame]:
        self.bytes_in += len(chunk)
        self._buffer += chunk
        return self._scan()

    def flush(self) -> list[Frame]:
        """End of stream: the buffered bytes (an incomplete frame) count as skipped."""
        self.bytes_skipped += len(self._buffer)
        self._buffer.clear()
        self._lf_may_follow = False
        return []

    def _scan(self) -> list[Frame]:
        buffer = self._buffer
        end = len(buffer)
        pos = self._consume_pending_line_feed(buffer, end)
        frames: list[Frame] = []
        while True:
            start = buffer.find(C2_HEADER, pos)
            if start < 0:
                pos = self._skip_to_possible_header(buffer, pos, end)
                break
            self.bytes_skipped += start - pos
            pos = start
            if end - start < C2_FRAME_LEN:
                break  # wait for the rest of this candidate
            frame = self._frame_at(buffer, start)
            if frame is None:
                self.bytes_skipped += 1
                pos = start + 1
                continue
            frames.append(frame)
            pos = self._after_frame(buffer, start + C2_FRAME_LEN, end)
        del buffer[:pos]
        self.frames += len(frames)
        return frames

    def _consume_pending_line_feed(self, buffer: bytearray, end: int) -> int:
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

    def _skip_to_possible_header(self, buffer: bytearray, pos: int, end: int) -> int:
        """No `H-` from pos on: skip everything but a trailing 'H' that may start one."""
        keep_from = end - 1 if end > pos and buffer[end - 1] == C2_HEADER[0] else end
        self.bytes_skipped += keep_from - pos
        return keep_from

    def _frame_at(self, buffer: bytearray, start: int) -> Frame | None:
        status = buffer[start + 2]
        service = _SERVICE_BY_STATUS.get(status)
        if service is None and status not in DATA_STATUSES:
            return None
        crc_end = start + _CRC_OFFSET
        if crc16_arc(buffer[start:crc_end]) != _C2_CRC.unpack_from(buffer, crc_end)[0]:
            self.crc_failures += 1
            return None
        if service is None:
            return _decode_data(buffer, start)
        payload = bytes(buffer[start + 5 : crc_end])
        binary = status < ASCII_SERVICE_OFFSET
        return ServiceFrame(service, buffer[start + 3], payload, binary, buffer[start + 4])


class OldSumdDecoder:
    """Streaming SUMD decoder, the same contract as the C2-16B `Decoder`.

    A candidate is 0xA8, status 0x01/0x81 and a count of 2..32; one whose CRC fails counts in
    `crc_failures`. A failed or implausible candidate skips ONE byte and the search for the
    next 0xA8 goes on. Bytes outside frames count in `bytes_skipped`. The buffer holds at most
    one incomplete frame (68 bytes) between calls. Because frames differ in length, a
    plausible header near the end of a capture can hide a shorter frame behind it until more
    bytes come: call `flush()` at the end of the stream.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bytes_in = 0

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[SumdFrame]:
        self.bytes_in += len(chunk)
        self._buffer += chunk
        return self._scan(at_end=False)

    def flush(self) -> list[SumdFrame]:
        """End of stream: incomplete candidates are skipped; frames found behind them return."""
        frames = self._scan(at_end=True)
        self.bytes_skipped += len(self._buffer)
        self._buffer.clear()
        return frames

    def _scan(self, at_end: bool) -> list[SumdFrame]:
        buffer = self._buffer
        end = len(buffer)
        pos = 0
        frames: list[SumdFrame] = []
        while True:
            start = buffer.find(VENDOR_ID, pos)
            if start < 0:
                self.bytes_skipped += end - pos
                pos = end
                break
            self.bytes_skipped += start - pos
            pos = start
            length = self._candidate_length(buffer, start, end)
            complete = length is not None and start + length <= end
            if not complete and not at_end:
                break  # wait for the rest of this candidate
            frame = self._frame_at(buffer, start, length) if complete and length else None
            if frame is None or length is None:
                self.bytes_skipped += 1
                pos = start + 1
                continue
            frames.append(frame)
            pos = start + length
        del buffer[:pos]
        self.frames += len(frames)
        return frames

    @staticmethod
    def _candidate_length(buffer: bytearray, start: int, end: int) -> int | None:
        """Frame length of a plausible header at `start`, 0 if implausible, None if cut off."""
        if end - start < HEADER_LEN:
            return None
        status, count = buffer[start + 1], buffer[start + 2]
        if status not in (STATUS_LIVE, STATUS_FAILSAFE) or not 2 <= count <= MAX_CHANNELS:
            return 0
        return frame_length(count)

    def _frame_at(self, buffer: bytearray, start: int, length: int) -> SumdFrame | None:
        crc_at = start + length - CRC_LEN
        if crc16_xmodem(buffer[start:crc_at]) != _CRC.unpack_from(buffer, crc_at)[0]:
            self.crc_failures += 1
            return None
        count = buffer[start + 2]
        channels = _CHANNELS_BY_COUNT[count].unpack_from(buffer, start + HEADER_LEN)
        return SumdFrame(buffer[start + 1] == STATUS_FAILSAFE, channels)


class OldCrsfDecoder:
    """Streaming CRSF decoder, the same contract as the C2-16B and SUMD decoders.

    A candidate is a known address byte followed by a length of 2..62; one whose CRC fails
    counts in `crc_failures`. A failed or implausible candidate skips ONE byte and the search
    goes on. Bytes outside frames count in `bytes_skipped`. Call `flush()` at the end of the
    stream (a plausible header near the end waits for bytes that never come)."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bytes_in = 0

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[CrsfFrame]:
        self.bytes_in += len(chunk)
        self._buffer += chunk
        return self._scan(at_end=False)

    def flush(self) -> list[CrsfFrame]:
        frames = self._scan(at_end=True)
        self.bytes_skipped += len(self._buffer)
        self._buffer.clear()
        return frames

    def _scan(self, at_end: bool) -> list[CrsfFrame]:
        buffer = self._buffer
        end = len(buffer)
        pos = 0
        frames: list[CrsfFrame] = []
        while pos < end:
            if buffer[pos] not in ADDRESSES:
                self.bytes_skipped += 1
                pos += 1
                continue
            if end - pos < 2:
                if at_end:
                    self.bytes_skipped += end - pos
                    pos = end
                break
            length = buffer[pos + 1]
            if not MIN_LENGTH <= length <= MAX_LENGTH:
                self.bytes_skipped += 1
                pos += 1
                continue
            frame_end = pos + 2 + length
            if frame_end > end:
                if not at_end:
                    break
                self.bytes_skipped += 1
                pos += 1
                continue
            body = bytes(buffer[pos + 2 : frame_end - 1])
            if crc8_dvb_s2(body) != buffer[frame_end - 1]:
                self.crc_failures += 1
                self.bytes_skipped += 1
                pos += 1
                continue
            frames.append(parse_crsf(buffer[pos], body[0], body[1:]))
            pos = frame_end
        del buffer[:pos]
        self.frames += len(frames)
        return frames


class OldSbusDecoder:
    """Streaming SBUS decoder, the same contract as the other decoders.

    A frame is 0x0F, 22 bytes, a flags byte, 0x00. Anything else skips ONE byte. SBUS has
    no CRC (`crc_failures` stays 0; it is there for the common summary)."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bytes_in = 0

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[SbusFrame]:
        self.bytes_in += len(chunk)
        self._buffer += chunk
        return self._scan()

    def flush(self) -> list[SbusFrame]:
        frames = self._scan()
        self.bytes_skipped += len(self._buffer)
        self._buffer.clear()
        return frames

    def _scan(self) -> list[SbusFrame]:
        buffer = self._buffer
        end = len(buffer)
        pos = 0
        frames: list[SbusFrame] = []
        while True:
            start = buffer.find(SBUS_HEADER, pos)
            if start < 0:
                self.bytes_skipped += end - pos
                pos = end
                break
            self.bytes_skipped += start - pos
            pos = start
            if end - start < SBUS_FRAME_LEN:
                break
            if buffer[start + SBUS_FRAME_LEN - 1] != FOOTER:
                self.bytes_skipped += 1
                pos = start + 1
                continue
            frames.append(parse_sbus(buffer[start : start + SBUS_FRAME_LEN]))
            pos = start + SBUS_FRAME_LEN
        del buffer[:pos]
        self.frames += len(frames)
        return frames
