"""The hid-recorder format: round trip, and timestamps a replay can wait on."""

from __future__ import annotations

import pytest

from usb2rc.hid.recording import (
    RecordedEvent,
    Recording,
    RecordingError,
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
