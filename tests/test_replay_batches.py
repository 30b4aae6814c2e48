"""A replayed device parses its file in batches and hands over what is due at the read.

The batches must give what a line at a time gives (the same events, the same error at the
same line, after the same events), and the device must behave as a hidraw queue read
through hidapi does: in file order, nothing before its time, every read after an unplug
fails, a close wakes a waiting read, and no thread besides the reader's.
"""

from __future__ import annotations

import errno
import io
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid import recording
from usb2rc.hid.backend import DeviceGone
from usb2rc.hid.recording import (
    RecordedEvent,
    Recording,
    RecordingError,
    _LineParser,
    format_event,
    format_recording,
    open_recording_batches,
    open_recording_played,
)
from usb2rc.hid.replay import ReplayBackend, ReplayDevice, install_file

JOYSTICK = bytes.fromhex("05010904a101c0")
HEADER = ["R: 7 05 01 09 04 a1 01 c0\n", "I: 3 044f b10a\n"]


def line_at_a_time(lines: list[str]) -> tuple[list[RecordedEvent], str | None]:
    """The events of the lines after the header, a line at a time, and the error that ends
    them (what a replayed device played before batches)."""
    parser = _LineParser("x")
    events: list[RecordedEvent] = []
    try:
        for number, raw in enumerate(lines, start=1):
            event = parser.line(number, raw)
            if event is not None:
                events.append(event)
    except RecordingError as exc:
        return events, str(exc)
    return events, None


def in_batches(
    lines: list[str], as_file: bool = False, played: bool = False
) -> tuple[list[RecordedEvent], str | None]:
    """`as_file`: read from a text file (blocks of BLOCK_CHARS), not from a list of lines;
    `played`: as the replay backend takes them (`open_recording_played`: blocks of
    PACKED_BLOCK_CHARS, packed)."""
    events: list[RecordedEvent] = []
    source: Iterable[str] = io.StringIO("".join(lines)) if as_file else lines
    batches: Iterator[tuple[list[float], list[bytes]]]
    try:
        if played:
            batches = (b.pairs() for b in open_recording_played(source, source="x")[1])
        else:
            batches = open_recording_batches(source, source="x")[1]
        for times, reports in batches:
            assert times, "a batch is never empty"
            events += [RecordedEvent(t, r) for t, r in zip(times, reports, strict=True)]
    except RecordingError as exc:
        return events, str(exc)
    return events, None


_WRITTEN = st.builds(
    lambda t, r: format_event(RecordedEvent(t, r)) + "\n",
    st.floats(0, 1e4, allow_nan=False),
    st.binary(min_size=1, max_size=20),
)
_ODD = st.sampled_from(
    [
        "# a comment\n",
        "\n",
        "E: 0.5 2 0a  ff\n",  # two spaces: the full parse takes it
        "E: 0.5 2 0A FF\n",  # capitals: as written too
        "E: 000001.250000 1 7f\n",  # hid-recorder's own zero-padded time
        "E: 0.5 1 00 \n",  # a trailing space
        "E: 0.5 1 00",  # no line end (a file's last line)
        "E:\t0.5 1 00\n",
        "E: 1_0 1 00\n",
        "N: a name after the events\n",
        "D: 1\n",  # another device's lines follow: skipped
        "D: 0\n",
        "E: 0.5 2 0a\n",  # bad: fewer bytes than said
        "E: soon 1 00\n",  # bad: not a time
        "E: -1 1 00\n",  # bad: before the start
        "X no colon\n",  # bad: not a line of the format
    ]
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(_WRITTEN, _WRITTEN, _WRITTEN, _ODD), max_size=40))
def test_batches_give_what_a_line_at_a_time_gives(lines: list[str]) -> None:
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(recording, "BATCH_LINES", 4)  # many batches, every boundary
        assert in_batches(HEADER + lines) == line_at_a_time(HEADER + lines)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.one_of(_WRITTEN, _WRITTEN, _WRITTEN, _ODD), max_size=40),
    st.integers(1, 90),
    st.sampled_from(["", "\n"]),
    st.booleans(),
)
def test_blocks_of_a_file_give_what_a_line_at_a_time_gives(
    lines: list[str], block: int, last_end: str, played: bool
) -> None:
    """Blocks that cut lines anywhere (a line's end waits for the next block), and a last
    line with or without its newline; as a list of events or as the replay plays them."""
    lines = [line.rstrip("\n") + "\n" for line in lines]  # one line each in the file
    if lines:
        lines[-1] = lines[-1].rstrip("\n") + last_end
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(recording, "BLOCK_CHARS", block)
        patch.setattr(recording, "PACKED_BLOCK_CHARS", block)
        got = in_batches(HEADER + lines, as_file=True, played=played)
        assert got == line_at_a_time(HEADER + lines)


def test_a_bad_line_in_a_batch_comes_after_the_good_ones_before_it() -> None:
    reports = [i.to_bytes(2, "little") for i in range(300)]
    good = [format_event(RecordedEvent(i / 1000, r)) + "\n" for i, r in enumerate(reports)]
    lines = HEADER + good + ["E: soon 1 00\n"] + good
    events, error = in_batches(lines)
    assert [e.report for e in events] == reports
    assert error == f"x:{len(HEADER) + 301}: bad timestamp 'soon' (seconds, >= 0)"


# --- the device -------------------------------------------------------------------------------


def recording_text(events: list[tuple[float, bytes]]) -> str:
    rec = Recording(
        JOYSTICK, "Stick", "", 3, 0x044F, 0xB10A, tuple(RecordedEvent(*e) for e in events)
    )
    return format_recording(rec)


def open_device(tmp_path: Path, events: list[tuple[float, bytes]], **kw: object) -> ReplayDevice:
    install_file(tmp_path / "s.hid", recording_text(events))
    backend = ReplayBackend(tmp_path, **kw)  # type: ignore[arg-type]
    return backend.open(backend.enumerate()[0])


def drain(device: ReplayDevice, count: int) -> list[bytes]:
    """A read that waits, then read_due and polls until empty (a pull's drain after it)."""
    got: list[bytes] = []
    deadline = time.monotonic() + 30
    while len(got) < count and time.monotonic() < deadline:
        first = device.read(1.0)
        if first is None:
            continue
        got.append(first)
        while True:
            got += device.read_due(1000)
            polled = device.read(0.0)
            if polled is None:
                break
            got.append(polled)
    return got


def test_a_drain_gets_every_report_in_order_across_batches_and_laps(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recording, "BATCH_LINES", 7)
    monkeypatch.setattr(recording, "PACKED_BLOCK_CHARS", 100)  # a few lines a batch
    events = [(i / 1000, i.to_bytes(2, "little")) for i in range(50)]
    device = open_device(tmp_path, events, loop=True, speed=20.0)
    try:
        assert drain(device, 150)[:150] == [r for _, r in events] * 3
    finally:
        device.close()


def test_no_thread_plays_a_device(tmp_path: Path) -> None:
    before = threading.active_count()
    device = open_device(tmp_path, [(i / 1000, bytes([i])) for i in range(20)])
    try:
        assert drain(device, 20) == [bytes([i]) for i in range(20)]
        assert threading.active_count() == before
    finally:
        device.close()


def test_a_report_comes_at_its_time_not_before(tmp_path: Path) -> None:
    opened = time.monotonic()
    device = open_device(tmp_path, [(0.0, b"\x01"), (0.2, b"\x02")])
    try:
        assert device.read(5.0) == b"\x01"
        assert device.read_due(10) == []
        assert device.read(0.0) is None
        assert device.read(5.0) == b"\x02"
        assert time.monotonic() - opened >= 0.2
    finally:
        device.close()


def test_a_time_before_the_one_before_comes_in_file_order(tmp_path: Path) -> None:
    device = open_device(tmp_path, [(0.0, b"\x01"), (0.15, b"\x02"), (0.01, b"\x03")])
    try:
        opened = time.monotonic()
        assert device.read(5.0) == b"\x01"
        assert device.read(5.0) == b"\x02"
        assert time.monotonic() - opened >= 0.15 - 0.01  # the device opened just before
        assert device.read(0.0) == b"\x03"  # due since 0.01 s: at once, after the one before
    finally:
        device.close()


def test_every_read_after_an_unplug_fails(tmp_path: Path) -> None:
    events = [(i / 1000, bytes([i])) for i in range(200)]
    device = open_device(tmp_path, events, speed=0.1)  # a report every 10 ms
    assert device.read(5.0) is not None
    (tmp_path / "s.hid").unlink()
    with pytest.raises(DeviceGone):
        while True:
            device.read(0.1)
    # hidapi: every read after that raises the same, blocking or not, even with reports due
    for timeout_s in (0.0, 0.05, 0.0):
        with pytest.raises(DeviceGone):
            device.read(timeout_s)
    assert device.read_due(10) == []
    device.close()


def test_a_close_wakes_a_read_waiting_for_a_report(tmp_path: Path) -> None:
    device = open_device(tmp_path, [(0.0, b"\x01"), (60.0, b"\x02")])
    assert device.read(5.0) == b"\x01"
    ended = threading.Event()
    errors: list[OSError] = []

    def wait_for_the_next() -> None:
        try:
            device.read(30.0)
        except OSError as exc:
            errors.append(exc)
        ended.set()

    thread = threading.Thread(target=wait_for_the_next)
    thread.start()
    try:
        device.close()
        assert ended.wait(10.0), "the read still waits after close()"
        [error] = errors
        assert error.errno == errno.EBADF
    finally:
        thread.join(10.0)
