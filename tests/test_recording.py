"""The hid-recorder format: round trip, and timestamps a replay can wait on."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid.recording import (
    RecordedEvent,
    Recording,
    RecordingError,
    _LineParser,
    _parse_event,
    format_event,
    format_recording,
    parse_recording,
)


def test_round_trip():
    rec = Recording(
        bytes([5, 1, 9, 4]),
        "Stick",
        "usb-1/input0",
        3,
        0x044F,
        0xB10A,
        (RecordedEvent(0.5, b"\x01\x02"),),
    )
    assert parse_recording(format_recording(rec).splitlines()) == rec


@pytest.mark.parametrize("stamp", ["nan", "inf", "-1.0", "abc"])
def test_a_timestamp_that_is_not_a_time_is_refused_with_its_line(stamp):
    text = f"R: 2 05 01\nI: 3 044f b10a\nE: {stamp} 1 00\n"
    with pytest.raises(RecordingError, match=r"x\.hid:3: bad timestamp"):
        parse_recording(text.splitlines(), source="x.hid")


# --- the fast path for `E:` lines as written (issue 22) ---------------------------------------

_TOKENS = st.sampled_from(
    [
        *("", " ", "  ", "\t", "\n", "a", "0a", "ff", "0aff", "0x1", "x", "E:"),
        *("1", "2", "9", "+1", "1_0", "nan", "inf", "-0.5", "0.25", "1e3"),
    ]
)


def _full_parse(raw: str) -> tuple[str, object]:
    """What the line's parse gave before the fast path: the slow path alone."""
    try:
        line = raw.strip()
        return ("event", _parse_event(line.partition(":")[2].strip(), 1, "x"))
    except RecordingError as exc:
        return ("error", str(exc))


def _parse_line(raw: str) -> tuple[str, object]:
    try:
        return ("event", _LineParser("x").line(1, raw))
    except RecordingError as exc:
        return ("error", str(exc))


@settings(max_examples=500)
@given(
    st.floats(0, 1e6, allow_nan=False),
    st.binary(max_size=70),
    st.booleans(),
)
def test_a_written_event_line_parses_to_its_event(time_s: float, report: bytes, lf: bool) -> None:
    raw = format_event(RecordedEvent(time_s, report)) + ("\n" if lf else "")
    assert _LineParser("x").line(1, raw) == RecordedEvent(float(f"{time_s:.6f}"), report)


@settings(max_examples=1000)
@given(st.lists(_TOKENS, max_size=8), st.sampled_from(["E: ", "E:  ", "E:\t"]))
def test_any_event_line_parses_as_the_full_parse_does(tokens: list[str], head: str) -> None:
    raw = head + " ".join(tokens)
    assert _parse_line(raw) == _full_parse(raw)


@pytest.mark.parametrize(
    "raw",
    [
        "E: 0.5 2 0aff",  # one token of four digits: one byte too big, not two
        "E: 0.5 2 0a  ff",  # two spaces: the same two bytes
        "E: 0.5 1 a",  # one digit
        "E: 0.5 1 0x1",
        "E: 0.5 2 0a",  # fewer bytes than said
        "E: -0.5 1 00",
        "E: inf 1 00",
        "E: 0.5 0",
        "E: 0.5 3 0a\tff 01",
    ],
)
def test_lines_not_as_written_take_the_full_parse(raw: str) -> None:
    assert _parse_line(raw) == _full_parse(raw)
