"""The hid-recorder text format (hid-tools' `hid-recorder`), read and written sans-IO.

    # comment lines
    D: 0                                   device number (several devices in one file)
    R: 119 05 01 09 04 a1 01 ...           report descriptor: length, then hex bytes
    N: Thrustmaster T.16000M               name
    P: usb-0000:00:14.0-1.2/input0         physical path
    I: 3 044f b10a                         bus, vendor, product (hex)
    E: 0.004123 9 01 00 80 ...             event: seconds.micros since start, length, report bytes

Report bytes in `E:` lines start with the report ID when the device uses report IDs.
Only the first device of a file is read; `D:` lines for other devices are skipped.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from itertools import accumulate, islice
from typing import Protocol, TypeVar

from usb2rc.hid import speedups


class RecordingError(ValueError):
    """A hid-recorder file that cannot be used; the message names the line."""


# A recording is parsed a batch at a time: from a text file a block of BLOCK_CHARS
# characters split into lines here (a text file's own line iteration cost ~3.5x the split),
# from a list of lines BATCH_LINES of them. Its lines as hid-recorder writes them are
# parsed in one C call (usb2rc.hid.speedups) or a few C loops over the batch
# (`_events_as_written`). 8 KB (~40-140 lines) keeps the per-batch overhead below the
# lines' own cost.
BATCH_LINES = 64
BLOCK_CHARS = 8192
# A replayed device plays its file in blocks of PACKED_BLOCK_CHARS, each parsed packed
# (`PlayedEvents`: the reports back to back and their times as doubles, no object per event
# until it is handed over): twice the size, the per-batch overhead paid half as often. 32 KB
# saved a little more CPU but cost the five outputs 0.5 MB of RSS, 64 KB 1.4 MB, against
# their 40 MB (bench/README.md, "Where issue 40 stands", ninth pass).
PACKED_BLOCK_CHARS = 16384

# Recorded times (seconds since the recording's start) and reports, in file order.
EventBatch = tuple[list[float], list[bytes]]


class PlayedEvents(Protocol):
    """A batch of events as the replay backend plays it, in file order: `schedule` gives
    each its due time, `take` hands over those due, from the first not taken. The C loops'
    `_speedups.Events` (a block parsed packed) or `EventList` (its Python twin, over an
    `EventBatch`)."""

    def __len__(self) -> int: ...
    def schedule(self, start: float, speed: float, floor: float) -> float: ...
    def take(self, now: float, limit: int) -> list[bytes]: ...
    def pairs(self) -> EventBatch: ...
    @property
    def next_due(self) -> float: ...
    @property
    def last_time(self) -> float: ...
    @property
    def left(self) -> int: ...


class EventList:
    """`PlayedEvents` over an `EventBatch`: each due at start + t / speed, never before the
    one before it nor before `floor` (a running maximum). An empty one plays nothing (a
    replayed device's batch before its first)."""

    def __init__(self, times: list[float], reports: list[bytes]) -> None:
        self._times, self._reports = times, reports
        self._dues = [math.inf] * len(times)
        self._next = 0

    def __len__(self) -> int:
        return len(self._times)

    def schedule(self, start: float, speed: float, floor: float) -> float:
        """Each event's due time; the last one's."""
        self._dues = list(accumulate((start + t / speed for t in self._times), max, initial=floor))
        del self._dues[0]
        return self._dues[-1]

    def take(self, now: float, limit: int) -> list[bytes]:
        """The reports due at `now` (at most `limit`) from the first not taken."""
        first = self._next
        end = bisect_right(self._dues, now, first, min(len(self._dues), first + max(0, limit)))
        self._next = end
        return self._reports[first:end]

    def pairs(self) -> EventBatch:
        return self._times, self._reports

    @property
    def next_due(self) -> float:
        return self._dues[self._next] if self._next < len(self._dues) else math.inf

    @property
    def last_time(self) -> float:
        return self._times[-1]

    @property
    def left(self) -> int:
        return len(self._dues) - self._next


@dataclass(frozen=True)
class RecordedEvent:
    time_s: float
    report: bytes


@dataclass(frozen=True)
class Recording:
    descriptor: bytes
    name: str = ""
    phys: str = ""
    bus: int = 3
    vid: int = 0
    pid: int = 0
    events: tuple[RecordedEvent, ...] = field(default_factory=tuple)


def _hex_bytes(tokens: list[str]) -> bytes:
    """One byte per hex token. hid-recorder writes two digits each: bytes.fromhex (C) takes
    those ~10x faster than a generator. A 4 s recording at 1 kHz is 4000 lines, parsed while
    the daemon runs (a replayed plug), and Python-speed parsing holds the GIL in slices the
    output threads have to wait through."""
    try:
        data = bytes.fromhex(" ".join(tokens))
    except ValueError:
        data = b""  # a one-digit token, "+a", "0x1"...: int() decides, with its own error
    if len(data) == len(tokens):  # every token was two digits, one byte each
        return data
    return bytes(int(p, 16) for p in tokens)


def _hex_payload(rest: str, lineno: int, source: str) -> bytes:
    parts = rest.split()
    if not parts:
        raise RecordingError(f"{source}:{lineno}: empty line, expected a length and hex bytes")
    try:
        length = int(parts[0])
        data = _hex_bytes(parts[1:])
    except ValueError as exc:
        raise RecordingError(f"{source}:{lineno}: not a length and hex bytes ({exc})") from None
    if length != len(data):
        raise RecordingError(f"{source}:{lineno}: length {length} but {len(data)} bytes follow")
    return data


def _parse_event(rest: str, lineno: int, source: str) -> RecordedEvent:
    stamp, _, payload = rest.strip().partition(" ")
    try:
        time_s = float(stamp)
    except ValueError:
        time_s = math.nan
    if not math.isfinite(time_s) or time_s < 0:
        raise RecordingError(f"{source}:{lineno}: bad timestamp {stamp!r} (seconds, >= 0)")
    return RecordedEvent(time_s, _hex_payload(payload, lineno, source))


def _event_as_written(raw: str) -> RecordedEvent | None:
    """An `E:` line as hid-recorder (and `format_event`) write it: single spaces, a finite
    time >= 0, the length, then that many two-digit hex bytes; in a few C calls (a replayed
    device parses each line as it plays it, 1000 a second). None for anything else: the full
    parse takes it, with the same result or its named error."""
    parts = raw.rstrip().split(" ", 3)
    if len(parts) != 4:
        return None
    try:
        time_s, length, data = float(parts[1]), int(parts[2]), bytes.fromhex(parts[3])
    except ValueError:
        return None
    # length pairs of digits and length - 1 separators: every token is one two-digit byte
    if len(data) != length or len(parts[3]) != 3 * length - 1 or not 0 <= time_s < math.inf:
        return None
    return RecordedEvent(time_s, data)


def _events_as_written(lines: list[str]) -> EventBatch | None:
    """Every line of `lines` an `E:` line as `_event_as_written` takes it; None when any
    line is not, and the batch takes the full parse, a line at a time. In one C call where
    the HID stage's C loops are built (usb2rc.hid._speedups: it takes only the strictest
    spelling, and leaves any other to the Python below)."""
    c_loops = speedups.compiled()
    if c_loops is not None and (parsed := c_loops.parse_events(lines)) is not None:
        batch: EventBatch = parsed
        return batch
    return _events_as_written_py(lines)


def _events_as_written_py(lines: list[str]) -> EventBatch | None:
    """`_events_as_written` in C loops over the batch (one Python call per step, not per
    line). Same checks as `_event_as_written`'s."""
    parts = [line.rstrip().split(" ", 3) for line in lines]
    if set(map(len, parts)) != {4}:
        return None
    tags, stamps, counts, texts = zip(*parts, strict=True)
    if set(tags) != {"E:"}:
        return None
    try:
        times = list(map(float, stamps))
        lengths = list(map(int, counts))
        reports = list(map(bytes.fromhex, texts))
    except ValueError:
        return None
    if list(map(len, reports)) != lengths or not all(map(math.isfinite, times)):
        return None
    # each token two digits, one space apart: `length` pairs and `length - 1` spaces
    if list(map(len, texts)) != [3 * n - 1 for n in lengths] or min(times) < 0:
        return None
    return times, reports


def _block_as_written(text: str) -> tuple[list[float], list[bytes], int, int] | None:
    """The complete lines of a block of text (those its last newline ends) when every one is
    an `E:` line as written: (times, reports, end, lines), `end` the index after that
    newline, `lines` their count. None otherwise (the lines then take `_events_as_written`
    and the full parse). In one C call, without a string per line, where the HID stage's C
    loops are built (the packed parse, its events as lists)."""
    c_loops = speedups.compiled()
    if c_loops is not None:
        packed: tuple[PlayedEvents, int, int] | None = c_loops.parse_packed(text)
        if packed is None:
            return None
        times, reports = packed[0].pairs()
        return times, reports, packed[1], packed[2]
    return _block_as_written_py(text)


def _block_as_written_py(text: str) -> tuple[list[float], list[bytes], int, int] | None:
    """`_block_as_written` in Python: the lines split, then `_events_as_written_py`."""
    end = text.rfind("\n") + 1
    if not end:
        return None
    lines = text[: end - 1].split("\n")
    parsed = _events_as_written_py(lines) if text.isascii() else None
    return None if parsed is None else (parsed[0], parsed[1], end, len(lines))


def _block_packed(text: str) -> tuple[PlayedEvents, int, int] | None:
    """`_block_as_written`'s events as `PlayedEvents`: packed in one C call where the HID
    stage's C loops are built (`_speedups.parse_packed`), else an `EventList`."""
    c_loops = speedups.compiled()
    if c_loops is not None:
        packed: tuple[PlayedEvents, int, int] | None = c_loops.parse_packed(text)
        return packed
    parsed = _block_as_written_py(text)
    return None if parsed is None else (EventList(parsed[0], parsed[1]), parsed[2], parsed[3])


def _parse_ids(rest: str, lineno: int, source: str) -> tuple[int, int, int]:
    parts = rest.split()
    try:
        bus, vid, pid = (int(p, 16) for p in parts[:3])
    except ValueError:
        raise RecordingError(f"{source}:{lineno}: expected 'I: bus vid pid' in hex") from None
    return bus, vid, pid


class _LineParser:
    """The state of one file's parse, a line at a time: the header fields seen so far and
    which device's lines are being read."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.descriptor: bytes | None = None
        self.name = self.phys = ""
        self.bus, self.vid, self.pid = 3, 0, 0
        self.device_index = 0

    def line(self, lineno: int, raw: str) -> RecordedEvent | None:
        """Take one line; the event it holds, if it is an `E:` line of the first device."""
        if self.device_index == 0 and raw.startswith("E: "):
            event = _event_as_written(raw)
            if event is not None:
                return event
        line = raw.strip()
        if not line or line.startswith("#"):
            return None
        tag, sep, rest = line.partition(":")
        if not sep:
            raise RecordingError(f"{self.source}:{lineno}: expected 'X: ...', got {line[:40]!r}")
        tag, rest = tag.strip(), rest.strip()
        if tag == "D":
            self.device_index = int(rest) if rest.isdigit() else 0
            return None
        if self.device_index != 0:
            return None
        if tag == "E":
            return _parse_event(rest, lineno, self.source)
        if tag == "R":
            self.descriptor = _hex_payload(rest, lineno, self.source)
        elif tag == "N":
            self.name = rest
        elif tag == "P":
            self.phys = rest
        elif tag == "I":
            self.bus, self.vid, self.pid = _parse_ids(rest, lineno, self.source)
        # other tags (H:, S: ...) are informational and ignored
        return None

    def batches(self, lines: Iterator[str], lineno: int) -> Iterator[EventBatch]:
        """The events of `lines` (the first is line `lineno + 1`), a chunk of lines at a
        time (`_line_chunks`; from a text file, a block whose lines are all as written is
        parsed whole, `_block_as_written`); a batch with no event is not yielded. At a bad
        line, the events before it come out first, then its RecordingError."""
        for batch in self._chunk_batches(lines, lineno, self._as_written_block, BLOCK_CHARS):
            yield batch if isinstance(batch, tuple) else batch.pairs()

    def played(self, lines: Iterator[str], lineno: int) -> Iterator[PlayedEvents]:
        """`batches` as the replay backend plays them: a text file's blocks of
        PACKED_BLOCK_CHARS, each parsed packed when its lines are all as written
        (`_block_packed`), the others as `EventList`s."""
        for batch in self._chunk_batches(lines, lineno, self._packed_block, PACKED_BLOCK_CHARS):
            yield EventList(*batch) if isinstance(batch, tuple) else batch

    def _chunk_batches(
        self, lines: Iterator[str], lineno: int, parse: BlockParse, block_chars: int
    ) -> Iterator[EventBatch | PlayedEvents]:
        for chunk in _line_chunks(lines, parse, block_chars):
            if isinstance(chunk, tuple):  # a block as written: (its events, its lines)
                yield chunk[0]
                lineno += chunk[1]
                continue
            size = len(chunk)
            written = _events_as_written(chunk) if self.device_index == 0 else None
            if written is None:
                yield from self._line_by_line(chunk, lineno)
            else:
                del chunk  # the text is not held while its events are played
                yield written
            lineno += size

    def _as_written_block(self, text: str) -> tuple[EventBatch, int, int] | None:
        """`_block_as_written`, for the first device's lines only (the others' are read
        for their `D:` lines): (its events, the index after its last line, its lines)."""
        parsed = _block_as_written(text) if self.device_index == 0 else None
        return None if parsed is None else ((parsed[0], parsed[1]), parsed[2], parsed[3])

    def _packed_block(self, text: str) -> tuple[PlayedEvents, int, int] | None:
        """`_block_packed`, for the first device's lines only."""
        return _block_packed(text) if self.device_index == 0 else None

    def _line_by_line(self, chunk: list[str], lineno: int) -> Iterator[EventBatch]:
        times: list[float] = []
        reports: list[bytes] = []
        try:
            for number, raw in enumerate(chunk, start=lineno + 1):
                event = self.line(number, raw)
                if event is not None:
                    times.append(event.time_s)
                    reports.append(event.report)
        finally:  # also at a bad line: the events before it come out, then its error
            if times:
                yield times, reports

    def recording(self, events: tuple[RecordedEvent, ...]) -> Recording:
        if self.descriptor is None:
            raise RecordingError(f"{self.source}: no 'R:' report descriptor line")
        return Recording(
            self.descriptor, self.name, self.phys, self.bus, self.vid, self.pid, events
        )


# A block's complete lines parsed whole: (their events, the index after the last, their count)
BlockParse = Callable[[str], "tuple[EventBatch | PlayedEvents, int, int] | None"]


def _line_chunks(
    lines: Iterator[str], parse_block: BlockParse | None = None, block_chars: int = BLOCK_CHARS
) -> Iterator[list[str] | tuple[EventBatch | PlayedEvents, int]]:
    """The lines in lists: from a text file (what has `read`), a block of `block_chars` at
    a time split at its newlines (a line the block cuts waits for the next block; the lines
    come without their newline), else BATCH_LINES lines at a time. With `parse_block`, a
    block's complete lines it parses come as (their events, number of lines) instead."""
    read = getattr(lines, "read", None)
    if read is None:
        while chunk := list(islice(lines, BATCH_LINES)):
            yield chunk
        return
    pending = ""
    while block := read(block_chars):
        text = pending + block
        if parse_block is not None and (parsed := parse_block(text)) is not None:
            events, end, count = parsed
            pending = text[end:]
            yield events, count
            continue
        chunk = text.split("\n")
        pending = chunk.pop()
        if chunk:
            yield chunk
    if pending:
        yield [pending]


def parse_recording(lines: Iterable[str], source: str = "<recording>") -> Recording:
    """Parse hid-recorder text. Raises RecordingError naming the line on bad input."""
    parser = _LineParser(source)
    events = [
        event
        for lineno, raw in enumerate(lines, start=1)
        if (event := parser.line(lineno, raw)) is not None
    ]
    return parser.recording(tuple(events))


def open_recording(
    lines: Iterable[str], source: str = "<recording>"
) -> tuple[Recording, Iterator[RecordedEvent]]:
    """The header (a Recording without events) now, the events as they are taken
    (`open_recording_batches`, one event at a time)."""
    header, batches = open_recording_batches(lines, source)
    events = (
        RecordedEvent(time_s, report)
        for times, reports in batches
        for time_s, report in zip(times, reports, strict=True)
    )
    return header, events


def open_recording_batches(
    lines: Iterable[str], source: str = "<recording>"
) -> tuple[Recording, Iterator[EventBatch]]:
    """The header (a Recording without events) now, the events in batches as they are
    taken (`_LineParser.batches`).

    Reads the lines up to the first event only (hid-recorder writes the header first), so
    the cost of a long recording is paid as it is played, not all at once: the replay
    backend opens devices on threads that share the GIL with the output threads. The
    iterator raises RecordingError at the first bad line it reaches, after the events before
    it. Header lines after the first event are not in the header; a file whose `R:` comes
    after its first event is parsed whole here (and raises here if it has none)."""
    opened = _Opened(lines, source)
    return opened.header, opened.rest(opened.parser.batches)


def open_recording_played(
    lines: Iterable[str], source: str = "<recording>"
) -> tuple[Recording, Iterator[PlayedEvents]]:
    """`open_recording_batches` as the replay backend plays them (`_LineParser.played`)."""
    opened = _Opened(lines, source)
    return opened.header, (
        EventList(*batch) if isinstance(batch, tuple) else batch
        for batch in opened.rest(opened.parser.played)
    )


_Batch = TypeVar("_Batch")


class _Opened:
    """A recording read up to its first event (`open_recording_batches`), the rest to come."""

    def __init__(self, lines: Iterable[str], source: str) -> None:
        self.parser = parser = _LineParser(source)
        self._lines = iter(lines)
        self._first: RecordedEvent | None = None
        self._whole: EventBatch | None = None
        lineno = 0
        for lineno, raw in enumerate(self._lines, start=1):
            if (first := parser.line(lineno, raw)) is not None:
                self._first = first
                break
        self._lineno = lineno
        if parser.descriptor is None:
            numbered = enumerate(self._lines, start=self._lineno + 1)
            others = [e for n, raw in numbered if (e := parser.line(n, raw)) is not None]
            events = ([self._first] if self._first is not None else []) + others
            self._whole = [e.time_s for e in events], [e.report for e in events]
        self.header = parser.recording(())

    def rest(
        self, batches: Callable[[Iterator[str], int], Iterator[_Batch]]
    ) -> Iterator[_Batch | EventBatch]:
        """The first event, then `batches` of the lines after it (a file parsed whole: its
        events in one batch, if it has any)."""
        if self._whole is not None:
            if self._whole[0]:
                yield self._whole
            return
        if self._first is not None:
            yield [self._first.time_s], [self._first.report]
        yield from batches(self._lines, self._lineno)


def read_recording(path: str) -> Recording:
    with open(path, encoding="utf-8", errors="replace") as fh:
        return parse_recording(fh, source=str(path))


def _hex(data: bytes) -> str:
    return " ".join(f"{b:02x}" for b in data)


def format_header(rec: Recording) -> Iterator[str]:
    yield "D: 0"
    yield f"R: {len(rec.descriptor)} {_hex(rec.descriptor)}"
    yield f"N: {rec.name}"
    yield f"P: {rec.phys}"
    yield f"I: {rec.bus:x} {rec.vid:04x} {rec.pid:04x}"


def format_event(event: RecordedEvent) -> str:
    return f"E: {event.time_s:.6f} {len(event.report)} {_hex(event.report)}"


def format_recording(rec: Recording) -> str:
    lines = list(format_header(rec))
    lines.extend(format_event(e) for e in rec.events)
    return "\n".join(lines) + "\n"
