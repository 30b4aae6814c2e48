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
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from itertools import islice

from usb2rc.hid import speedups


class RecordingError(ValueError):
    """A hid-recorder file that cannot be used; the message names the line."""


# A replayed device parses its file as it plays it, a batch at a time: from its file a block
# of BLOCK_CHARS characters split into lines here (a text file's own line iteration cost
# ~3.5x the split), from a list of lines BATCH_LINES of them. Its lines as hid-recorder
# writes them are parsed in one C call (usb2rc.hid.speedups) or a few C loops over the
# batch (`_events_as_written`). 8 KB (~40-140 lines) keeps the per-batch overhead below the
# lines' own cost; 16 KB saved a little more CPU but cost the five outputs 0.5 MB of RSS,
# past their 40 MB (bench/README.md, issue 40).
BATCH_LINES = 64
BLOCK_CHARS = 8192

# Recorded times (seconds since the recording's start) and reports, in file order.
EventBatch = tuple[list[float], list[bytes]]


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
    loops are built."""
    c_loops = speedups.compiled()
    if c_loops is not None:
        parsed: tuple[list[float], list[bytes], int, int] | None = c_loops.parse_block(text)
        return parsed
    return _block_as_written_py(text)


def _block_as_written_py(text: str) -> tuple[list[float], list[bytes], int, int] | None:
    """`_block_as_written` in Python: the lines split, then `_events_as_written_py`."""
    end = text.rfind("\n") + 1
    if not end:
        return None
    lines = text[: end - 1].split("\n")
    parsed = _events_as_written_py(lines) if text.isascii() else None
    return None if parsed is None else (parsed[0], parsed[1], end, len(lines))


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
        for chunk in _line_chunks(lines, self._as_written_block):
            if isinstance(chunk, tuple):  # a block as written: (times, reports, lines)
                yield chunk[0], chunk[1]
                lineno += chunk[2]
                continue
            size = len(chunk)
            written = _events_as_written(chunk) if self.device_index == 0 else None
            if written is None:
                yield from self._line_by_line(chunk, lineno)
            else:
                del chunk  # the text is not held while its events are played
                yield written
            lineno += size

    def _as_written_block(self, text: str) -> tuple[list[float], list[bytes], int, int] | None:
        """`_block_as_written`, for the first device's lines only (the others' are read
        for their `D:` lines)."""
        return _block_as_written(text) if self.device_index == 0 else None

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


BlockParse = Callable[[str], tuple[list[float], list[bytes], int, int] | None]


def _line_chunks(
    lines: Iterator[str], parse_block: BlockParse | None = None
) -> Iterator[list[str] | tuple[list[float], list[bytes], int]]:
    """The lines in lists: from a text file (what has `read`), a block of BLOCK_CHARS at a
    time split at its newlines (a line the block cuts waits for the next block; the lines
    come without their newline), else BATCH_LINES lines at a time. With `parse_block`, a
    block's complete lines it parses come as (times, reports, number of lines) instead."""
    read = getattr(lines, "read", None)
    if read is None:
        while chunk := list(islice(lines, BATCH_LINES)):
            yield chunk
        return
    pending = ""
    while block := read(BLOCK_CHARS):
        text = pending + block
        if parse_block is not None and (parsed := parse_block(text)) is not None:
            times, reports, end, count = parsed
            pending = text[end:]
            yield times, reports, count
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
    parser = _LineParser(source)
    rest = iter(lines)
    first: RecordedEvent | None = None
    lineno = 0
    for lineno, raw in enumerate(rest, start=1):
        if (first := parser.line(lineno, raw)) is not None:
            break
    if parser.descriptor is None:
        numbered = enumerate(rest, start=lineno + 1)
        others = [e for n, raw in numbered if (e := parser.line(n, raw)) is not None]
        events = ([first] if first is not None else []) + others
        header = parser.recording(())
        times = [e.time_s for e in events]
        return header, iter([(times, [e.report for e in events])] if events else [])

    def later() -> Iterator[EventBatch]:
        if first is not None:
            yield [first.time_s], [first.report]
        yield from parser.batches(rest, lineno)

    return parser.recording(()), later()


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
