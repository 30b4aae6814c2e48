"""The HID stage's C loops (usb2rc.hid._speedups) against their Python twins.

The drain:
`ReportDecoder.feed_batch` takes the C drain where it is built and the layout allows; the
Python path is what runs without it. Both must leave the same values, button masks and
counts, and report the same masks after each change (`on_buttons`) and the same presses
(`feed_presses`, a pulled reader's press log): here on layouts with
signed and unsigned values of 1..32 bits at any bit offset, one-bit button runs and wide
buttons anywhere in bits 0..63, with and without report IDs (several IDs may share buttons),
and batches with short, empty and unknown-ID reports. The real descriptors are in
tests/test_decode_batch.py (against `feed`, one report at a time).

The event parse: `recording._events_as_written` takes the C parse first; where it answers it
must give what the Python parse gives, and lines as `format_event` writes them must be
answered (else the speed-up never runs).
"""

from __future__ import annotations

import io
import math
import os
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid import recording, speedups
from usb2rc.hid.descriptor import ButtonField, DeviceLayout, InputField, ReportDecoder
from usb2rc.hid.recording import RecordedEvent, format_event

if not speedups.built():
    if os.environ.get("CI"):
        pytest.fail("the C drain was not built (setup.py; needs a C compiler and Python headers)")
    pytest.skip("the C drain is not built here: only the Python path runs", allow_module_level=True)


@st.composite
def layouts(draw: st.DrawFn) -> DeviceLayout:
    uses_ids = draw(st.booleans())
    ids = sorted(draw(st.sets(st.integers(1, 255), min_size=1, max_size=3))) if uses_ids else [0]
    inputs: list[InputField] = []
    buttons: list[ButtonField] = []
    lengths = {}
    for rid in ids:
        offset = 0
        for _ in range(draw(st.integers(0, 6))):
            kind = draw(st.sampled_from(["value", "run", "wide"]))
            offset += draw(st.integers(0, 9))  # padding
            if kind == "value":
                size = draw(st.integers(1, 32))
                signed = draw(st.booleans())
                low, high = (-(1 << (size - 1)), (1 << (size - 1)) - 1) if signed else (0, 1)
                inputs.append(
                    InputField(len(inputs), rid, 0x10030, offset, size, low, high, False, 0)
                )
            elif kind == "run":
                size = draw(st.integers(1, 40))
                first = draw(st.integers(1, 65 - size))
                buttons.append(ButtonField(rid, first, size, offset, 1))
            else:
                size = draw(st.integers(2, 8))
                buttons.append(ButtonField(rid, draw(st.integers(1, 64)), 1, offset, size))
            offset += size
        lengths[rid] = (offset + 7) // 8
    count = max((b.first_button + b.count - 1 for b in buttons), default=0)
    layout = DeviceLayout(0x10004, uses_ids, tuple(inputs), count, lengths, tuple(buttons))
    assert layout.c_plan is not None  # inside the C drain's limits by construction
    return layout


@st.composite
def batches(draw: st.DrawFn, layout: DeviceLayout) -> list[list[bytes]]:
    ids = sorted(layout.input_report_lengths)

    def valid(rid: int) -> st.SearchStrategy[bytes]:
        size = layout.input_report_lengths[rid]
        head = bytes([rid]) if layout.uses_report_ids else b""
        return st.binary(min_size=size, max_size=size + 2).map(lambda body: head + body)

    report = st.one_of(
        st.sampled_from(ids).flatmap(valid),
        st.sampled_from(ids).flatmap(valid),
        st.binary(max_size=3),  # short, empty, an unknown ID
    )
    reports = draw(st.lists(report, max_size=25))
    # a repeat now and then: the same report twice in a row
    if reports and draw(st.booleans()):
        reports.insert(draw(st.integers(0, len(reports) - 1)), reports[0])
    cuts = sorted(draw(st.lists(st.integers(0, len(reports)), max_size=3)))
    return [reports[a:b] for a, b in zip([0, *cuts], [*cuts, len(reports)], strict=True)]


def drained(decoder: ReportDecoder, parts: list[list[bytes]]) -> tuple[object, ...]:
    masks: list[int] = []
    results = [decoder.feed_batch(part, masks.append) for part in parts]
    return decoder.state(), decoder.reports, decoder.bad_reports, results, masks


def pressed(decoder: ReportDecoder, parts: list[list[bytes]]) -> tuple[object, ...]:
    results = [decoder.feed_presses(part) for part in parts]
    return decoder.state(), decoder.reports, decoder.bad_reports, results


@settings(max_examples=500, deadline=None)
@given(st.data())
def test_the_c_drain_leaves_what_the_python_path_leaves(data: st.DataObject) -> None:
    layout = data.draw(layouts())
    parts = data.draw(batches(layout))
    c_decoder, py_decoder = ReportDecoder(layout), ReportDecoder(layout, compiled=False)
    assert c_decoder._c_plan is not None and py_decoder._c_plan is None
    assert drained(c_decoder, parts) == drained(py_decoder, parts)
    c_decoder, py_decoder = ReportDecoder(layout), ReportDecoder(layout, compiled=False)
    assert pressed(c_decoder, parts) == pressed(py_decoder, parts)


def test_layouts_outside_the_c_drain_take_the_python_path() -> None:
    wide = InputField(0, 0, 0x10030, 0, 33, 0, 1, False, 0)
    assert DeviceLayout(0x10004, False, (wide,), 0, {0: 5}).c_plan is None
    high = ButtonField(0, 60, 8, 0, 1)  # buttons 60..67: past the uint64 mask
    assert DeviceLayout(0x10004, False, (), 67, {0: 1}, (high,)).c_plan is None
    broad = ButtonField(0, 1, 1, 0, 70)  # one button 70 bits wide
    assert DeviceLayout(0x10004, False, (), 1, {0: 9}, (broad,)).c_plan is None


def test_the_pure_python_switch_turns_the_c_loops_off() -> None:
    """Read at import, as the daemon starts: a process started with it runs the twins, and
    every node step in Python (usb2rc.nodes.steady: one switch for every C loop); each says
    so at start."""
    field = InputField(0, 0, 0x10030, 0, 8, 0, 255, False, 0)
    assert DeviceLayout(0x10004, False, (field,), 0, {0: 1}).c_plan is not None
    script = (
        "from usb2rc.hid import speedups\n"
        "from usb2rc.hid.descriptor import DeviceLayout, InputField\n"
        "field = InputField(0, 0, 0x10030, 0, 8, 0, 255, False, 0)\n"
        "assert speedups.compiled() is None\n"
        "assert DeviceLayout(0x10004, False, (field,), 0, {0: 1}).c_plan is None\n"
        "print(speedups.status())\n"
        "from usb2rc.nodes import steady\n"
        "assert steady.compiled() is None\n"
        "print(steady.status())\n"
    )
    env = dict(os.environ, **{speedups.PURE_PYTHON_ENV: "1"})
    done = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("switched off") == 2


EVENTS = st.builds(
    RecordedEvent,
    st.floats(min_value=0, max_value=1e7, allow_nan=False),
    st.binary(min_size=1, max_size=70),
)


def c_parse(lines: list[str]) -> recording.EventBatch | None:
    c_loops = speedups.compiled()
    assert c_loops is not None
    parsed: recording.EventBatch | None = c_loops.parse_events(lines)
    return parsed


@settings(max_examples=300, deadline=None)
@given(st.lists(EVENTS, max_size=20), st.sampled_from(["", "\n", "\r\n", "  \n"]))
def test_lines_as_written_parse_in_c_as_in_python(events: list[RecordedEvent], end: str) -> None:
    lines = [format_event(e) + end for e in events]
    parsed = c_parse(lines)
    assert parsed == recording._events_as_written_py(lines)
    assert (parsed is None) == (not lines)  # an empty batch is no batch


EDITS = st.sampled_from(
    [
        "E:  ",
        "E: -",
        "e: ",
        " E: ",
        "\t",
        "  ",
        " 0",
        "0 ",
        "x",
        "1e3",
        "+",
        "_",
        ".",
        "..",
        "\u00e9",
    ]
)


@settings(max_examples=1000, deadline=None)
@given(st.lists(EVENTS, min_size=1, max_size=4), st.data())
def test_any_other_spelling_is_the_python_parses_call(
    events: list[RecordedEvent], data: st.DataObject
) -> None:
    """An edited line: the C parse either gives what the Python parse gives, or no verdict."""
    lines = [format_event(e) for e in events]
    k = data.draw(st.integers(0, len(lines) - 1))
    at = data.draw(st.integers(0, len(lines[k])))
    cut = data.draw(st.integers(0, 2))
    lines[k] = lines[k][:at] + data.draw(EDITS) + lines[k][at + cut :]
    parsed = c_parse(lines)
    if parsed is not None:
        assert parsed == recording._events_as_written_py(lines)


STAMPS = st.tuples(
    st.text("0123456789", min_size=1, max_size=19), st.text("0123456789", max_size=19)
).map(lambda parts: f"{parts[0]}.{parts[1]}" if parts[1] else parts[0])


@settings(max_examples=1000, deadline=None)
@given(STAMPS, st.binary(min_size=1, max_size=4))
def test_a_stamp_reads_as_float_reads_it(stamp: str, report: bytes) -> None:
    """Up to 15 digits the C parse divides (one correctly rounded division); beyond, it asks
    float()'s own parser: either way the same float, bit for bit."""
    line = f"E: {stamp} {len(report)} {report.hex(' ')}\n"
    parsed = c_parse([line])
    assert parsed is not None
    assert parsed[0][0].hex() == float(stamp).hex()


def c_block(text: str) -> tuple[list[float], list[bytes], int, int] | None:
    """`recording._block_as_written` on the C loops (`parse_packed`, its events as lists)."""
    assert speedups.compiled() is not None
    return recording._block_as_written(text)


@settings(max_examples=500, deadline=None)
@given(st.lists(EVENTS, max_size=20), st.sampled_from(["\n", "\r\n", "  \n"]), st.data())
def test_a_block_parses_in_c_as_in_python(
    events: list[RecordedEvent], end: str, data: st.DataObject
) -> None:
    """A block of lines as written, cut anywhere (the replay reads 8 KB at a time): the C
    parse gives what the Python twin gives, None included. Edited: the same, or no verdict
    (None: the lines then take the line parses, as `parse_events`'s no verdict does)."""
    text = "".join(format_event(e) + end for e in events)
    text = text[: data.draw(st.integers(0, len(text)))]
    edited = bool(text) and data.draw(st.booleans())
    if edited:
        at = data.draw(st.integers(0, len(text)))
        text = text[:at] + data.draw(EDITS) + text[at:]
    parsed = c_block(text)
    if parsed is not None or not edited:
        assert parsed == recording._block_as_written_py(text)


@given(st.lists(EVENTS, min_size=1, max_size=20), st.sampled_from(["\n", "\r\n"]))
def test_a_block_of_complete_lines_gives_their_events_and_where_they_end(
    events: list[RecordedEvent], end: str
) -> None:
    lines = [format_event(e) + end for e in events]
    parsed = c_block("".join(lines) + "E: 1.5 2 0")  # a line the block cut: for the next
    one_by_one = [recording._event_as_written(line) for line in lines]
    assert parsed == (
        [e.time_s for e in one_by_one if e is not None],
        [e.report for e in one_by_one if e is not None],
        len("".join(lines)),
        len(events),
    )


def c_packed(text: str) -> tuple[recording.PlayedEvents, int, int] | None:
    c_loops = speedups.compiled()
    assert c_loops is not None
    packed: tuple[recording.PlayedEvents, int, int] | None = c_loops.parse_packed(text)
    return packed


@settings(max_examples=500, deadline=None)
@given(st.lists(EVENTS, max_size=20), st.sampled_from(["\n", "\r\n", "  \n"]), st.data())
def test_a_packed_block_holds_what_its_lists_hold(
    events: list[RecordedEvent], end: str, data: st.DataObject
) -> None:
    """A block `parse_packed` takes (cut anywhere, edited anywhere): its Events object
    counts its lines, has none taken yet, and ends at its last event's time."""
    text = "".join(format_event(e) + end for e in events)
    text = text[: data.draw(st.integers(0, len(text)))]
    if text and data.draw(st.booleans()):
        at = data.draw(st.integers(0, len(text)))
        text = text[:at] + data.draw(EDITS) + text[at:]
    packed = c_packed(text)
    if packed is None:
        return
    events_c, _, lines_c = packed
    times, reports = events_c.pairs()
    assert len(times) == len(reports) == lines_c >= 1
    assert (len(events_c), events_c.left, events_c.last_time) == (lines_c, lines_c, times[-1])


FINITE = st.floats(min_value=-1e6, max_value=2e6, allow_nan=False)


@given(
    st.lists(st.floats(min_value=0, max_value=1e6, allow_nan=False), min_size=1, max_size=30),
    st.floats(min_value=0, max_value=1e6, allow_nan=False),
    st.floats(min_value=0.01, max_value=1000, allow_nan=False),
    FINITE,
    st.lists(st.tuples(FINITE, st.integers(-1, 40)), max_size=20),
)
def test_packed_events_play_as_their_python_twin(
    times: list[float],
    start: float,
    speed: float,
    floor: float,
    takes: list[tuple[float, int]],
) -> None:
    """`_speedups.Events` against `recording.EventList` on the same events: the same due
    times bit for bit (a running maximum from `floor`), the same reports taken at each
    (now, limit), the same next due and count left after each take."""
    reports = [bytes([k % 256]) * (1 + k % 5) for k in range(len(times))]
    text = "".join(
        format_event(RecordedEvent(t, r)) + "\n" for t, r in zip(times, reports, strict=True)
    )
    packed = c_packed(text)
    assert packed is not None
    c_events = packed[0]
    py_events = recording.EventList(*c_events.pairs())
    assert c_events.pairs() == py_events.pairs()
    last = c_events.schedule(start, speed, floor)
    assert last.hex() == py_events.schedule(start, speed, floor).hex()
    for now, limit in sorted(takes):
        assert c_events.take(now, limit) == py_events.take(now, limit)
        assert (c_events.next_due, c_events.left) == (py_events.next_due, py_events.left)
    assert c_events.take(math.inf, len(times)) == py_events.take(math.inf, len(times))
    assert c_events.left == py_events.left == 0


@settings(max_examples=50, deadline=None)
@given(st.lists(EVENTS, min_size=1, max_size=400), st.sampled_from(["\n", "\r\n"]))
def test_a_recordings_batches_are_the_same_with_the_c_loops_off(
    events: list[RecordedEvent], end: str
) -> None:
    """From a text file, read in blocks: every event, in order, with or without C."""
    text = "R: 1 00\n" + "".join(format_event(e) + end for e in events)
    got = []
    for switched_off in (False, True):
        before = speedups._SWITCHED_OFF
        speedups._SWITCHED_OFF = switched_off
        try:
            batches = recording.open_recording_batches(io.StringIO(text, newline=None))[1]
            got.append(
                [(t, r) for times, reports in batches for t, r in zip(times, reports, strict=True)]
            )
            played = recording.open_recording_played(io.StringIO(text, newline=None))[1]
            got.append([(t, r) for b in played for t, r in zip(*b.pairs(), strict=True)])
        finally:
            speedups._SWITCHED_OFF = before
    assert got[0] == got[1] == got[2] == got[3]
    assert [r for _, r in got[0]] == [e.report for e in events]
