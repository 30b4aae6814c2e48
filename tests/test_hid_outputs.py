"""Output reports from the descriptor (usb2rc.hid.descriptor.parse_outputs) and the driver that
builds them (usb2rc.feedback.hid_outputs), against hid-tools (an independent parser): the real
descriptors that have outputs, LED-page descriptors built here, and random ones (hypothesis)
whose reports hid-tools reads back."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import hidtools.hid
import pytest
from hypothesis import given
from hypothesis import strategies as st
from umockdev_harness import LED_STICK_DESCRIPTOR, LED_STICK_OUTPUT_BYTES

from usb2rc.feedback.hid_outputs import ANALOG_USAGES, HidOutputDriver, output_usage_name
from usb2rc.hid.descriptor import DescriptorError, OutputLayout, parse_descriptor, parse_outputs
from usb2rc.hid.outputs import HidReport, OutputState

DEVICES = json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
LED, ORDINAL, BUTTON, GDC, VENDOR, GD = 0x08, 0x0A, 0x09, 0x06, 0xFF00, 0x01


# --- a small descriptor writer (the test's own, not usb2rc's) ----------------------------------


def short(prefix: int, value: int, size: int | None = None) -> bytes:
    """A short item: `prefix` (tag and type, size bits 0) with `value` in 1, 2 or 4 bytes."""
    if size is None:  # the value fits as signed: a logical maximum reads as meant either way
        size = 1 if -128 <= value <= 127 else 2 if -32768 <= value <= 32767 else 4
    code = {1: 1, 2: 2, 4: 3}[size]
    return bytes([prefix | code]) + (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


@dataclass(frozen=True)
class Item:
    """One Output main item as the test writes it."""

    report_id: int
    page: int
    usages: tuple[int, ...]  # usage IDs; () for padding
    size: int
    count: int
    low: int = 0
    high: int = 1
    constant: bool = False
    variable: bool = True

    def encode(self) -> bytes:
        out = short(0x84, self.report_id) if self.report_id else b""
        out += short(0x04, self.page, 2 if self.page > 0xFF else 1)
        if self.usages and list(self.usages) == list(range(self.usages[0], self.usages[-1] + 1)):
            out += short(0x18, self.usages[0]) + short(0x28, self.usages[-1])
        else:
            out += b"".join(short(0x08, u) for u in self.usages)
        out += short(0x14, self.low) + short(0x24, self.high)
        out += short(0x74, self.size) + short(0x94, self.count)
        flags = (0x01 if self.constant else 0) | (0x02 if self.variable else 0)
        return out + short(0x90, flags, 1)


def descriptor(items: list[Item]) -> bytes:
    """A joystick with one 8-bit input and `items` as its outputs."""
    first_id = items[0].report_id if items else 0
    head = bytes.fromhex("05010904a101") + (short(0x84, first_id) if first_id else b"")
    inputs = bytes.fromhex("093015002501750895018102")
    return head + inputs + b"".join(i.encode() for i in items) + b"\xc0"


# --- hid-tools' reading ----------------------------------------------------------------------


def ref_outputs(data: bytes) -> dict[int, hidtools.hid.HidReport]:
    """hid-tools' output reports by report ID (0: none; hid-tools says -1)."""
    rdesc = hidtools.hid.ReportDescriptor.from_bytes(list(data))
    return {max(rid, 0): report for rid, report in rdesc.output_reports.items()}


def my_elements(layout: OutputLayout) -> set[tuple[object, ...]]:
    """Each non-constant value as (report ID, start with the ID byte, size, usage, min, max),
    an array as one (report ID, start, size, count, usages, min, max)."""
    id_bits = 8 if layout.uses_report_ids else 0
    elements: set[tuple[object, ...]] = set()
    for f in layout.fields:
        if f.constant:
            continue
        start = f.bit_offset + id_bits
        if not f.variable:
            key = (f.report_id, start, f.bit_size, f.count, f.usages, f.logical_min)
            elements.add((*key, f.logical_max))
            continue
        for i, usage in enumerate(f.usages):
            at = start + i * f.bit_size
            elements.add((f.report_id, at, f.bit_size, usage, f.logical_min, f.logical_max))
    return elements


def ref_elements(refs: dict[int, hidtools.hid.HidReport]) -> set[tuple[object, ...]]:
    elements: set[tuple[object, ...]] = set()
    for rid, report in refs.items():
        for f in report.fields:
            if f.is_const:
                continue
            if f.is_array:
                usages = tuple(f.usages or ())
                elements.add((rid, f.start, f.size, f.count, usages, f.logical_min, f.logical_max))
            else:
                elements.add((rid, f.start, f.size, f.usage, f.logical_min, f.logical_max))
    return elements


def assert_layout_like_hidtools(data: bytes) -> OutputLayout:
    layout = parse_outputs(data)
    refs = ref_outputs(data)
    id_byte = 1 if layout.uses_report_ids else 0
    lengths = {rid: (r.bitsize + 7) // 8 - (1 if rid else 0) for rid, r in refs.items()}
    assert layout.report_lengths == lengths
    assert all(r.numbered == bool(id_byte) for r in refs.values())
    assert my_elements(layout) == ref_elements(refs)
    return layout


WITH_OUTPUTS = [d for d in DEVICES if ref_outputs(bytes.fromhex(d["hex"]))]


@pytest.mark.parametrize("device", WITH_OUTPUTS, ids=lambda d: d["name"].split("(")[0].strip())
def test_real_output_layouts_match_hidtools(device: dict) -> None:
    assert_layout_like_hidtools(bytes.fromhex(device["hex"]))


def test_the_real_descriptors_with_outputs_are_the_expected_ones() -> None:
    """The check above covers arrays, signed ranges, vendor pages and 9 report IDs."""
    assert len(WITH_OUTPUTS) >= 8
    for d in DEVICES:
        if d not in WITH_OUTPUTS:
            assert parse_outputs(bytes.fromhex(d["hex"])) == OutputLayout((), {})


LED_DESCRIPTORS = {
    "keyboard LEDs, no ID": descriptor(
        [Item(0, LED, (1, 2, 3, 4, 5), 1, 5), Item(0, LED, (), 3, 1, constant=True)]
    ),
    "LED stick": LED_STICK_DESCRIPTOR,
    "RGB and intensity": descriptor(
        [
            Item(3, LED, (0x53, 0x54, 0x55), 8, 3, 0, 255),
            Item(3, LED, (0x56,), 16, 1, 0, 1000),
            Item(4, LED, (0x4B,), 1, 3),  # the last usage repeats
            Item(4, LED, (), 5, 1, constant=True),
        ]
    ),
    "usage list, not a range": descriptor([Item(7, LED, (0x61, 0x63, 0x62, 0x64), 1, 4)]),
    "signed value and an array": descriptor(
        [
            Item(9, GD, (0x30,), 8, 1, -127, 127),
            Item(9, LED, (0x3D, 0x3E, 0x3F), 8, 2, 1, 3, variable=False),
            Item(9, LED, (0x4B,), 1, 8),
        ]
    ),
}


@pytest.mark.parametrize("name", sorted(LED_DESCRIPTORS))
def test_built_output_layouts_match_hidtools(name: str) -> None:
    assert_layout_like_hidtools(LED_DESCRIPTORS[name])


def test_the_input_layout_is_the_same_with_outputs_in_the_descriptor() -> None:
    """Outputs are a pass of their own: the input layout does not see them."""
    with_outputs = parse_descriptor(LED_STICK_DESCRIPTOR)
    assert with_outputs.input_report_lengths == {1: 5}
    assert [f.usage & 0xFFFF for f in with_outputs.inputs] == [0x30, 0x31]


def test_a_broken_descriptor_raises_descriptor_error_only() -> None:
    with pytest.raises(DescriptorError):
        parse_outputs(bytes.fromhex("05010904a101"))  # a collection never closed
    with pytest.raises(DescriptorError):
        parse_outputs(descriptor([Item(0, LED, (1,), 1, 1)])[:-1] + b"\x85\x02\x91\x02\xc0")
    assert HidOutputDriver.from_descriptor(b"\x05") is None


# --- the driver ------------------------------------------------------------------------------


def ref_values(data: bytes, report: bytes) -> dict[tuple[int, int], int]:
    """hid-tools' reading of one written report: (report ID, start bit) -> value, every
    non-constant variable value."""
    refs = ref_outputs(data)
    rid = report[0]
    body = list(report if refs[rid].numbered else report[1:])
    return {
        (rid, f.start): int(f.get_values(body)[0])
        for f in refs[rid].fields
        if not f.is_const and not f.is_array
    }


def test_led_stick_capabilities_names_and_report() -> None:
    driver = HidOutputDriver.from_descriptor(LED_STICK_DESCRIPTOR)
    assert driver is not None
    caps = driver.capabilities
    assert caps.indicator_names == (
        "LED Num Lock",
        "LED Caps Lock",
        "LED Scroll Lock",
        "LED Compose",
        "LED Kana",
        "Instance 1",
        "Instance 2",
        "0xFF000001",
    )
    assert caps.indicators == 8 and caps.analog == ("brightness",)
    (write,) = driver.writes(OutputState(0b1010_0101, (("brightness", 0.5),)), None)
    assert isinstance(write, HidReport)
    assert len(write.data) == 1 + LED_STICK_OUTPUT_BYTES
    values = ref_values(LED_STICK_DESCRIPTOR, write.data)
    # starts with the ID byte: LEDs at 8..12, intensity at 16, ordinals at 24, 25, vendor 26
    leds = [values[(2, 8 + k)] for k in range(5)] + [values[(2, s)] for s in (24, 25, 26)]
    assert leds == [1, 0, 1, 0, 0, 1, 0, 1]
    assert values[(2, 16)] == 128  # 0.5 of 0..255, rounded


def test_writes_are_only_the_reports_that_changed() -> None:
    data = LED_DESCRIPTORS["RGB and intensity"]
    driver = HidOutputDriver.from_descriptor(data)
    assert driver is not None
    assert driver.capabilities.analog == ("brightness", "red", "green", "blue")
    rest = OutputState()
    assert [w.data[0] for w in driver.writes(rest, None)] == [3, 4]  # every report, ID order
    assert driver.writes(rest, rest) == ()
    lit = OutputState(indicators=0b10)
    assert [w.data[0] for w in driver.writes(lit, rest)] == [4]
    green = OutputState(indicators=0b10, analog=(("green", 1.0),))
    (write,) = driver.writes(green, lit)
    values = ref_values(data, write.data)
    # HUT: 0x53 red, 0x54 blue, 0x55 green
    assert (values[(3, 8)], values[(3, 16)], values[(3, 24)]) == (0, 0, 255)
    bright = driver.writes(OutputState(analog=(("brightness", 0.25),)), None)[0]
    assert ref_values(data, bright.data)[(3, 32)] == 250  # 0.25 of 0..1000


def test_indicator_pages_and_usage_names() -> None:
    data = descriptor(
        [
            Item(0, BUTTON, (3,), 1, 1),
            Item(0, GDC, (0x20,), 1, 1),
            Item(0, VENDOR, (7,), 1, 2),  # the same usage twice: the names stay apart
            Item(0, GD, (0x30,), 1, 1),  # Generic Desktop: not an indicator page
            Item(0, LED, (0x62,), 1, 1),
            Item(0, LED, (), 2, 1, constant=True),
        ]
    )
    driver = HidOutputDriver.from_descriptor(data)
    assert driver is not None
    names = driver.capabilities.indicator_names
    assert names == ("Button 3", "BatteryStrength", "0xFF000007", "0xFF000007 (2)", "LED Player 2")


def test_led_names_agree_with_hidtools_usage_tables() -> None:
    """hid-tools' HUT copy names 0x01..0x51 as this table does (spacing and case aside); it
    misnames 0x54 "Greed LEDChannel" and puts green before blue, against HUT 1.5 §11.7."""
    led_page = hidtools.hid.HUT[LED]
    for number in range(1, 0x52):
        theirs = led_page[number].name
        mine = output_usage_name((LED << 16) | number).removeprefix("LED ")
        assert mine.replace(" ", "").lower() == theirs.replace(" ", "").lower(), number
    assert {u & 0xFFFF: n for u, n in ANALOG_USAGES.items()} == {
        0x53: "red",
        0x54: "blue",
        0x55: "green",
        0x56: "brightness",
    }


def test_no_driver_without_something_to_drive() -> None:
    """Only constants, arrays and values it cannot name: nothing is ever written (a force
    feedback device's effect reports stay untouched)."""
    for d in DEVICES:
        data = bytes.fromhex(d["hex"])
        driver = HidOutputDriver.from_descriptor(data)
        if "Asus" in d["name"]:
            assert driver is not None and driver.capabilities.indicators == 4
        else:
            assert driver is None, d["name"]
    only_pad = descriptor([Item(0, LED, (), 8, 1, constant=True)])
    assert HidOutputDriver.from_descriptor(only_pad) is None


def test_a_report_without_driven_values_is_never_written() -> None:
    data = descriptor(
        [
            Item(1, LED, (1,), 1, 1),
            Item(1, LED, (), 7, 1, constant=True),
            Item(2, 0x0F, (0x25,), 8, 1, 0, 255),  # a Physical Interface value
        ]
    )
    driver = HidOutputDriver.from_descriptor(data)
    assert driver is not None
    assert [w.data for w in driver.writes(OutputState(indicators=1), None)] == [b"\x01\x01"]


def test_rest_values_are_zero_within_the_logical_range() -> None:
    data = descriptor(
        [
            Item(5, LED, (1,), 1, 1),
            Item(5, GD, (0x30,), 8, 1, -100, 100),  # signed: 0
            Item(5, GD, (0x31,), 8, 1, 10, 20),  # above 0: the minimum
            Item(5, LED, (0x3D, 0x3E), 8, 1, 1, 2, variable=False),  # array: selects nothing
        ]
    )
    driver = HidOutputDriver.from_descriptor(data)
    assert driver is not None
    (write,) = driver.writes(OutputState(), None)
    values = ref_values(data, write.data)
    assert (values[(5, 8)], values[(5, 9)], values[(5, 17)]) == (0, 0, 10)
    assert write.data[4] == 0


# --- property: what hid-tools reads back is what was asked ----------------------------------

INDICATOR_PAGES = (LED, ORDINAL, BUTTON, GDC, VENDOR, 0xFFA0)
MAPPED = sorted(u & 0xFFFF for u in ANALOG_USAGES)


@st.composite
def output_items(draw: st.DrawFn) -> list[Item]:
    ids = draw(st.sampled_from([(0,), (1,), (2, 6)]))
    items = []
    for _ in range(draw(st.integers(1, 8))):
        rid = draw(st.sampled_from(ids))
        kind = draw(st.sampled_from(["bits", "bits", "pad", "mapped", "other"]))
        if kind == "bits":
            first = draw(st.integers(1, 40))
            count = draw(st.integers(1, 9))
            page = draw(st.sampled_from(INDICATOR_PAGES))
            items.append(Item(rid, page, tuple(range(first, first + count)), 1, count))
        elif kind == "pad":
            items.append(Item(rid, LED, (), draw(st.integers(1, 9)), 1, constant=True))
        else:
            size = draw(st.integers(2, 16))
            high = draw(st.integers(1, (1 << size) - 1))
            if kind == "mapped":
                usage = draw(st.sampled_from(MAPPED))
                items.append(Item(rid, LED, (usage,), size, 1, 0, high))
            else:
                low = draw(st.integers(-(1 << (size - 1)), 0))
                high = min(high, (1 << (size - 1)) - 1) if low < 0 else high
                items.append(Item(rid, GD, (0x30,), size, 1, low, max(high, low)))
    return items


def expected_indicators(items: list[Item]) -> list[tuple[int, int]]:
    """(report ID, the k-th indicator value of that report) in descriptor order."""
    seen: dict[int, int] = {}
    out = []
    for item in items:
        if item.size == 1 and not item.constant:
            for _ in range(item.count):
                out.append((item.report_id, seen.get(item.report_id, 0)))
                seen[item.report_id] = seen.get(item.report_id, 0) + 1
    return out


@given(
    items=output_items(),
    mask=st.integers(0, (1 << 80) - 1),
    levels=st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
)
def test_hidtools_reads_back_the_indicators_and_levels_asked(
    items: list[Item], mask: int, levels: list[float]
) -> None:
    data = descriptor(items)
    driver = HidOutputDriver.from_descriptor(data)
    indicators = expected_indicators(items)
    mapped = [i for i in items if i.usages and i.usages[0] in MAPPED and i.size > 1]
    if not indicators and not mapped:
        assert driver is None
        return
    assert driver is not None
    assert driver.capabilities.indicators == len(indicators)
    names = ("red", "blue", "green", "brightness")
    analog = tuple(zip(names, levels, strict=True))
    writes = driver.writes(OutputState(mask, analog), None)
    refs = ref_outputs(data)
    got_bits: dict[int, list[int]] = {}
    got_levels: list[tuple[int, int, int, int]] = []
    for w in writes:
        rid = w.data[0]
        body = list(w.data if refs[rid].numbered else w.data[1:])
        for f in refs[rid].fields:
            if f.is_const:
                continue
            value = int(f.get_values(body)[0])
            if f.size == 1:
                got_bits.setdefault(rid, []).append(value)
            elif f.usage >> 16 == LED:
                got_levels.append((f.usage & 0xFFFF, value, f.logical_min, f.logical_max))
            else:
                assert value == min(max(0, f.logical_min), f.logical_max)  # at rest
    asked = [(rid, mask >> k & 1) for k, (rid, _) in enumerate(indicators)]
    for rid in {rid for rid, _ in asked}:
        assert got_bits[rid] == [bit for r, bit in asked if r == rid]
    level_of = dict(zip((0x53, 0x54, 0x55, 0x56), levels, strict=True))
    for usage, value, low, high in got_levels:
        assert abs(value - (low + level_of[usage] * (high - low))) <= 0.5


# A variable output field with no usage before it (the usage went to the input before it).
NO_USAGE_OUTPUT = bytes.fromhex(
    "05010904a101"  # Generic Desktop, Joystick
    "09301500250f750495018102"  # X in (4 bits)
    "9102"  # a variable 4-bit output with no usage of its own (X went to the input)
    "05080901250175019501910295079101"  # LED Num Lock out, padding
    "c0"
)


def test_an_output_value_without_a_usage_rests_and_the_others_are_driven() -> None:
    """Seen in the fuzzed daemon: an output field whose usages ran out crashed the driver's
    build. It rests; what has a usage is driven."""
    driver = HidOutputDriver.from_descriptor(NO_USAGE_OUTPUT)
    assert driver is not None
    assert driver.capabilities.indicator_names == ("LED Num Lock",)
    # bits 0-3 the field without a usage (at rest), bit 4 Num Lock
    assert driver.reports(OutputState(indicators=1)) == {0: bytes([0, 0x10, 0x00])}


@given(st.binary(max_size=200), st.integers(0, 12), st.binary(min_size=1, max_size=4))
def test_any_descriptor_gives_a_driver_or_none_never_an_error(
    noise: bytes, which: int, patch: bytes
) -> None:
    """Random bytes, and the real descriptors with a few bytes overwritten: a driver whose
    reports build for any indicators, or None; nothing raises."""
    real = [bytes.fromhex(d["hex"]) for d in DEVICES]
    base = bytearray(real[which % len(real)])
    at = len(noise) % max(1, len(base))
    base[at : at + len(patch)] = patch
    for descriptor in (noise, bytes(base)):
        driver = HidOutputDriver.from_descriptor(descriptor)
        if driver is not None:
            for report in driver.reports(OutputState(indicators=(1 << 64) - 1)).values():
                assert isinstance(report, bytes)
