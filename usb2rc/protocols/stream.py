"""The one resync-and-count loop of every serial stream decoder, sans-IO.

The protocols' stream decoders (MAVLink's is pymavlink's) share one contract: `feed(chunk)`
returns the frames that chunk completed, for any chunking, and never raises; `flush()` ends
the stream; the counters `frames`, `bytes_in`, `bytes_skipped` and `crc_failures` say what
was seen.
`StreamDecoder` holds that loop once. A protocol supplies three steps:

- `_find_start(buffer, pos, end)`: where the next candidate frame may start (-1: nowhere),
  or just `START`, the bytes every frame starts with;
- `_candidate_length(buffer, start, end)`: its length in bytes, 0 when its header is
  implausible, None when the header is cut off (wait for more bytes), or just `FRAME_LEN`
  when every frame has one length;
- `_parse(buffer, start, length)`: the frame, or `Rejected.CRC` / `Rejected.SHAPE`.

A rejected or implausible candidate skips ONE byte and the search goes on, so a frame
starting inside a corrupted region is still found. A candidate cut off by the end of the
buffer waits for more bytes; at `flush()` it is skipped the same way, so a shorter frame hidden
behind a plausible header still comes out. Two optional hooks serve C2-16B's line feed and its
two-byte header: `_after_frame` (what to consume after a frame) and `_keep_tail` (the bytes
kept when no candidate starts, because they may begin one).

`START` and `FRAME_LEN`, and a decoder without hooks, are the hot path's shortcuts: the loop
then calls no method for them (decoding runs on every read of the RX threads).
"""

from __future__ import annotations

from enum import Enum
from typing import Final, Generic, TypeVar

FrameT = TypeVar("FrameT")


def header_tail(buffer: bytearray, pos: int, end: int, header: bytes) -> int:
    """For `_keep_tail` of a two-byte header: keep a last byte that may be its first half."""
    return end - 1 if end > pos and buffer[end - 1] == header[0] else end


class Rejected(Enum):
    """Why `_parse` refused a complete candidate: its checksum (counted in `crc_failures`) or
    its shape (a footer or another fixed byte: not counted, no checksum was tried)."""

    CRC = "crc"
    SHAPE = "shape"


class StreamDecoder(Generic[FrameT]):
    """Streaming decoder skeleton: subclasses supply the three protocol steps above."""

    START: bytes | None = None  # every frame starts with these bytes: `_find_start` finds them
    FRAME_LEN: int | None = None  # every frame has this length: `_candidate_length` says it
    _hooked = False  # a subclass overrides a hook (set by __init_subclass__)

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        cls._hooked = any(getattr(cls, name) is not getattr(StreamDecoder, name) for name in _HOOKS)

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bytes_in = 0

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[FrameT]:
        """The frames completed by `chunk`."""
        self.bytes_in += len(chunk)
        self._buffer += chunk
        return self._scan(at_end=False)

    def flush(self) -> list[FrameT]:
        """End of stream: incomplete candidates are skipped; frames found behind them return."""
        frames = self._scan(at_end=True)
        self.bytes_skipped += len(self._buffer)
        self._buffer.clear()
        self._stream_ended()
        return frames

    # --- the protocol's steps ----------------------------------------------------------------

    def _find_start(self, buffer: bytearray, pos: int, end: int) -> int:
        assert self.START is not None, "a decoder gives START or its own _find_start"
        return buffer.find(self.START, pos)

    def _candidate_length(self, buffer: bytearray, start: int, end: int) -> int | None:
        return self.FRAME_LEN

    def _parse(self, buffer: bytearray, start: int, length: int) -> FrameT | Rejected:
        raise NotImplementedError

    # --- optional hooks (the defaults suit every protocol but C2-16B) ---------------------

    def _scan_from(self, buffer: bytearray, end: int) -> int:
        """Where a scan starts (C2-16B: after a line feed owed by the previous chunk)."""
        return 0

    def _after_frame(self, buffer: bytearray, pos: int, end: int) -> int:
        """Where the search goes on after a frame ending at `pos`."""
        return pos

    def _keep_tail(self, buffer: bytearray, pos: int, end: int) -> int:
        """No candidate from `pos` on: where the bytes kept for the next chunk begin."""
        return end

    def _stream_ended(self) -> None:
        """`flush()` emptied the buffer: forget any state about what follows it."""

    # --- the loop ----------------------------------------------------------------------------

    def _scan(self, at_end: bool) -> list[FrameT]:
        # The RX hot path: the steps are bound once per call, and the shortcuts (START,
        # FRAME_LEN, no hooks) spare a method call per candidate.
        buffer = self._buffer
        end = len(buffer)
        start_bytes, fixed_length, hooked = self.START, self.FRAME_LEN, self._hooked
        find_start, candidate_length, parse = self._find_start, self._candidate_length, self._parse
        pos = self._scan_from(buffer, end) if hooked else 0
        frames: list[FrameT] = []
        skipped = 0
        while True:
            if start_bytes is not None:
                start = buffer.find(start_bytes, pos)
            else:
                start = find_start(buffer, pos, end)
            if start < 0:
                keep_from = self._keep_tail(buffer, pos, end) if hooked else end
                skipped += keep_from - pos
                pos = keep_from
                break
            skipped += start - pos
            pos = start
            length = fixed_length or candidate_length(buffer, start, end)
            if length is None or start + length > end:
                if not at_end:
                    break  # wait for the rest of this candidate
                skipped += 1
                pos = start + 1
                continue
            frame = parse(buffer, start, length) if length else _SHAPE
            # Module constants compared by identity: `Rejected.CRC` and isinstance on an Enum
            # class cost 0.15 µs each, per frame.
            if frame is _CRC or frame is _SHAPE:
                if frame is _CRC:
                    self.crc_failures += 1
                skipped += 1
                pos = start + 1
                continue
            frames.append(frame)
            pos = start + length
            if hooked:
                pos = self._after_frame(buffer, pos, end)
        del buffer[:pos]
        self.bytes_skipped += skipped
        self.frames += len(frames)
        return frames


_HOOKS = ("_scan_from", "_after_frame", "_keep_tail")
_CRC: Final = Rejected.CRC
_SHAPE: Final = Rejected.SHAPE
