"""The X52 Pro's MFD, LED and brightness requests against libx52's documented ones, its
change-only writes, and the writes through a fake pyusb device.

The requests, as libx52 documents them (github.com/nirenjan/libx52, docs/specs/vendor_api.md
"X52Pro Vendor API"; the constants in libx52/commands.h): a vendor request to the device,
bRequest 0x91, no data, the function in wIndex and its argument in wValue.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pyusb_fake import FakeUsbDevice

from usb2rc.feedback.vendor import x52
from usb2rc.hid.outputs import REST, OutputState, UsbControl

VENDOR_OUT = 0x40  # vendor request type, device recipient, host to device
X52_REQUEST = 0x91

# vendor_api.md, as (wIndex, wValue) of each documented request
DOC_LED = 0xB8  # "the index must be 0xb8": value = LED number << 8 | S
DOC_LED_NUMBERS = {
    "fire": 1,  # "1 - Launch LED"
    "a red": 2,
    "a green": 3,
    "b red": 4,
    "b green": 5,
    "d red": 6,
    "d green": 7,
    "e red": 8,
    "e green": 9,
    "t1 red": 10,
    "t1 green": 11,
    "t2 red": 12,
    "t2 green": 13,
    "t3 red": 14,
    "t3 green": 15,
    "pov red": 16,
    "pov green": 17,
    "clutch red": 18,  # "Clutch (i) button Red LED"
    "clutch green": 19,
    "throttle": 20,
}
DOC_CLEAR = (0xD9, 0xDA, 0xDC)  # "Line 1 - 0xd9 ..." with value 0
DOC_APPEND = (0xD1, 0xD2, 0xD4)
DOC_SHIFT, DOC_SHIFT_ON, DOC_SHIFT_OFF = 0xFD, 0x51, 0x50
DOC_MFD_BRIGHTNESS, DOC_LED_BRIGHTNESS, DOC_BRIGHTNESS_MAX = 0xB1, 0xB2, 0x80


def request(w_index: int, w_value: int) -> UsbControl:
    return UsbControl(VENDOR_OUT, X52_REQUEST, w_value, w_index)


def bit(name: str) -> int:
    return 1 << x52.INDICATOR_NAMES.index(name)


def test_the_leds_are_named_and_numbered_as_libx52_documents() -> None:
    names = x52.CAPABILITIES.indicator_names
    assert names[0] == "shift"
    assert {name: names.index(name) for name in names[1:]} == DOC_LED_NUMBERS
    assert x52.CAPABILITIES.indicators == len(names) == 21
    assert (x52.CAPABILITIES.text_lines, x52.CAPABILITIES.text_width) == (3, 16)


# (what changed, the state before, the state after, the documented requests, in order)
DOCUMENTED = [
    (
        "vendor_api.md's own example: ABCD on line 1 is a clear, then 0x4241, then 0x4443",
        REST,
        OutputState(texts=("ABCD",)),
        [request(0xD9, 0), request(0xD1, 0x4241), request(0xD1, 0x4443)],
    ),
    (
        "an odd length: libx52 pads the line with spaces, so the last pair is 'C '",
        REST,
        OutputState(texts=("", "", "ABC")),
        [request(0xDC, 0), request(0xD4, 0x4241), request(0xD4, 0x2043)],
    ),
    (
        "a line that empties is only cleared",
        OutputState(texts=("", "LQ 99")),
        REST,
        [request(0xDA, 0)],
    ),
    (
        "16 characters are 8 pairs; the 17th is cut",
        REST,
        OutputState(texts=("0123456789ABCDEFG",)),
        [request(0xD9, 0)]
        + [
            request(0xD1, ord(a) | ord(b) << 8) for a, b in zip("02468ACE", "13579BDF", strict=True)
        ],
    ),
    (
        "the fire LED on: LED number 1, S = 1",
        REST,
        OutputState(indicators=bit("fire")),
        [request(DOC_LED, 0x0101)],
    ),
    (
        "A amber is its red and green LEDs on, in LED number order",
        REST,
        OutputState(indicators=bit("a red") | bit("a green")),
        [request(DOC_LED, 0x0201), request(DOC_LED, 0x0301)],
    ),
    (
        "the throttle LED off again",
        OutputState(indicators=bit("throttle")),
        REST,
        [request(DOC_LED, 0x1400)],
    ),
    (
        "the shift indicator on",
        REST,
        OutputState(indicators=bit("shift")),
        [request(DOC_SHIFT, DOC_SHIFT_ON)],
    ),
    (
        "half brightness: 0x40 to the MFD, then to the LEDs",
        REST,
        OutputState(analog=(("brightness", 0.5),)),
        [request(DOC_MFD_BRIGHTNESS, 0x40), request(DOC_LED_BRIGHTNESS, 0x40)],
    ),
    (
        "several changes at once go in libx52_update's order: shift, LEDs, lines, brightness",
        REST,
        OutputState(
            indicators=bit("pov green") | bit("shift"),
            analog=(("brightness", 0.0),),
            texts=("", "AB"),
        ),
        [
            request(DOC_SHIFT, DOC_SHIFT_ON),
            request(DOC_LED, 17 << 8 | 1),
            request(0xDA, 0),
            request(0xD2, 0x4241),
            request(DOC_MFD_BRIGHTNESS, 0),
            request(DOC_LED_BRIGHTNESS, 0),
        ],
    ),
]


@pytest.mark.parametrize(
    ("before", "state", "documented"),
    [case[1:] for case in DOCUMENTED],
    ids=[case[0] for case in DOCUMENTED],
)
def test_writes_are_libx52s_documented_requests(
    before: OutputState, state: OutputState, documented: list[UsbControl]
) -> None:
    assert list(x52.X52ProDriver().writes(state, before)) == documented


def test_after_a_plug_everything_is_written_once() -> None:
    writes = x52.X52ProDriver().writes(REST, None)
    assert writes == (
        request(DOC_SHIFT, DOC_SHIFT_OFF),
        *(request(DOC_LED, number << 8) for number in range(1, 21)),
        *(request(clear, 0) for clear in DOC_CLEAR),
        request(DOC_MFD_BRIGHTNESS, DOC_BRIGHTNESS_MAX),
        request(DOC_LED_BRIGHTNESS, DOC_BRIGHTNESS_MAX),
    )


def test_characters_the_mfd_lacks_show_as_its_box() -> None:
    writes = x52.X52ProDriver().writes(OutputState(texts=("~\\é",)), REST)
    assert writes[1:] == (request(0xD1, 0xDB | 0xDB << 8), request(0xD1, 0xDB | ord(" ") << 8))


@dataclass
class DocumentedX52:
    """What an X52 Pro shows after a series of requests, as vendor_api.md describes them:
    a clear empties a line, an append adds two characters (beyond 16 ignored)."""

    leds: dict[int, int] = field(default_factory=dict)
    shift: int | None = None
    lines: list[bytes] = field(default_factory=lambda: [b"?"] * 3)
    brightness: dict[int, int] = field(default_factory=dict)

    def apply(self, write: UsbControl) -> None:
        assert (write.request_type, write.request, write.data) == (VENDOR_OUT, X52_REQUEST, b"")
        assert 0 <= write.w_value <= 0xFFFF
        index, value = write.w_index, write.w_value
        if index == DOC_LED:
            assert value & 0xFE == 0 and 1 <= value >> 8 <= 20
            self.leds[value >> 8] = value & 1
        elif index == DOC_SHIFT:
            assert value in (DOC_SHIFT_ON, DOC_SHIFT_OFF)
            self.shift = value
        elif index in DOC_CLEAR:
            assert value == 0
            self.lines[DOC_CLEAR.index(index)] = b""
        elif index in DOC_APPEND:
            line = DOC_APPEND.index(index)
            self.lines[line] = (self.lines[line] + value.to_bytes(2, "little"))[:16]
        else:
            assert index in (DOC_MFD_BRIGHTNESS, DOC_LED_BRIGHTNESS)
            assert 0 <= value <= DOC_BRIGHTNESS_MAX
            self.brightness[index] = value


def shown(writes: tuple[object, ...], start: DocumentedX52 | None = None) -> DocumentedX52:
    device = start if start is not None else DocumentedX52()
    for write in writes:
        assert isinstance(write, UsbControl)
        device.apply(write)
    return device


text_lines = st.lists(st.text(max_size=20), max_size=4).map(tuple)
states = st.builds(
    OutputState,
    indicators=st.integers(0, (1 << 64) - 1),
    analog=st.lists(
        st.tuples(st.sampled_from(["brightness", "red", "rumble_strong"]), st.floats()),
        max_size=3,
    ).map(tuple),
    texts=text_lines,
)


@given(states, states)
def test_change_only_writes_leave_the_device_as_a_full_write_would(
    first: OutputState, second: OutputState
) -> None:
    driver = x52.X52ProDriver()
    after_changes = shown(driver.writes(second, first), shown(driver.writes(first, None)))
    assert after_changes == shown(driver.writes(second, None))


@given(states)
def test_the_same_state_twice_writes_nothing(state: OutputState) -> None:
    driver = x52.X52ProDriver()
    assert driver.writes(state, state) == ()
    assert driver.writes(state, OutputState(state.indicators, state.analog, state.texts)) == ()


@given(states)
def test_every_write_is_a_documented_request(state: OutputState) -> None:
    device = shown(x52.X52ProDriver().writes(state, None))
    assert all(len(line) <= 16 for line in device.lines)
    assert set(device.leds) == set(range(1, 21))


def test_the_writes_reach_a_pyusb_device_as_libx52s_transfers() -> None:
    device = FakeUsbDevice(0x06A3, 0x0762)
    for write in x52.X52ProDriver().writes(OutputState(texts=("ABCD",)), REST):
        assert isinstance(write, UsbControl)
        written = device.ctrl_transfer(
            write.request_type, write.request, write.w_value, write.w_index, write.data
        )
        assert written == 0  # pyusb's answer to an OUT transfer: the data bytes written
    sent = [(t.request_type, t.request, t.w_value, t.w_index, t.data) for t in device.transfers]
    assert sent == [
        (0x40, 0x91, 0, 0xD9, b""),
        (0x40, 0x91, 0x4241, 0xD1, b""),
        (0x40, 0x91, 0x4443, 0xD1, b""),
    ]
