"""Hand-written report descriptors: one test per quirk of real devices, broken descriptors, and
a seeded fuzz run (random and mutated descriptors give a layout or DescriptorError only)."""

from __future__ import annotations

import json
import random
from pathlib import Path

import hid_encoder
import pytest

from usb2rc.hid import usages as u
from usb2rc.hid.descriptor import (
    DescriptorError,
    DeviceLayout,
    InputState,
    parse_descriptor,
)

DEVICES = {
    d["name"].split()[0] + " " + d["name"].split()[1]: bytes.fromhex(d["hex"])
    for d in json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
}

# -- a tiny descriptor builder: one function per HID item ----------------------------------


def _item(prefix: int, value: int | None = None, size: int | None = None) -> bytes:
    if value is None:
        return bytes([prefix])
    if size is None:
        size = next(n for n in (1, 2, 4) if -(1 << (8 * n - 1)) <= value < (1 << (8 * n - 1)))
    code = {0: 0, 1: 1, 2: 2, 4: 3}[size]
    return bytes([prefix | code]) + (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


def usage_page(v: int) -> bytes:
    return _item(0x04, v)


def usage(v: int, size: int | None = None) -> bytes:
    return _item(0x08, v, size)


def usage_min(v: int) -> bytes:
    return _item(0x18, v)


def usage_max(v: int) -> bytes:
    return _item(0x28, v)


def logical_min(v: int, size: int | None = None) -> bytes:
    return _item(0x14, v, size)


def logical_max(v: int, size: int | None = None) -> bytes:
    return _item(0x24, v, size)


def report_size(v: int) -> bytes:
    return _item(0x74, v)


def report_count(v: int) -> bytes:
    return _item(0x94, v)


def report_id(v: int) -> bytes:
    return _item(0x84, v)


DATA_VAR, CONST, DATA_ARRAY, DATA_VAR_NULL = 0x02, 0x03, 0x00, 0x42


def input_(flags: int = DATA_VAR) -> bytes:
    return _item(0x80, flags)


def output(flags: int = DATA_VAR) -> bytes:
    return _item(0x90, flags)


def feature(flags: int = DATA_VAR) -> bytes:
    return _item(0xB0, flags)


def collection(kind: int = 1) -> bytes:
    return _item(0xA0, kind)


END = b"\xc0"
PUSH = b"\xa4"
POP = b"\xb4"


def joystick(*body: bytes, application: int = 0x04, page: int = 0x01) -> bytes:
    return usage_page(page) + usage(application) + collection(1) + b"".join(body) + END


def buttons(first: int, last: int, count: int | None = None) -> bytes:
    n = last - first + 1 if count is None else count
    return (
        usage_page(0x09)
        + usage_min(first)
        + usage_max(last)
        + logical_min(0)
        + logical_max(1)
        + report_size(1)
        + report_count(n)
        + input_()
    )


def axes(names: list[int], bits: int, lo: int, hi: int, page: int = 0x01) -> bytes:
    return (
        usage_page(page)
        + b"".join(usage(n) for n in names)
        + logical_min(lo)
        + logical_max(hi)
        + report_size(bits)
        + report_count(len(names))
        + input_()
    )


def pad(bits: int) -> bytes:
    return report_size(bits) + report_count(1) + input_(CONST)


def decode(layout: DeviceLayout, report: bytes) -> InputState:
    decoder = layout.make_decoder()
    assert decoder.feed(report)
    return decoder.state()


def by_usage(layout: DeviceLayout, usage_: int, occurrence: int = 0) -> int:
    return next(f.index for f in layout.inputs if (f.usage, f.occurrence) == (usage_, occurrence))


def ref(descriptor: bytes, rid: int = 0) -> hid_encoder.RefReport:
    return hid_encoder.ref_reports(descriptor)[rid]


# -- quirks of real devices ---------------------------------------------------------------


def test_11_bit_x_y_beside_10_bit_rz() -> None:
    desc = joystick(axes([0x30, 0x31], 11, 0, 2047), axes([0x35], 10, 0, 1023), buttons(1, 2))
    layout = parse_descriptor(desc)
    x, y, rz = layout.inputs
    assert (x.bit_offset, y.bit_offset, rz.bit_offset) == (0, 11, 22)
    assert (x.bit_size, rz.bit_size, rz.logical_max) == (11, 10, 1023)
    assert layout.input_report_lengths == {0: 5}
    values = {(u.GD_X, 0): 2047, (u.GD_Y, 0): 1, (u.GD_RZ, 0): 513}
    state = decode(layout, hid_encoder.encode(ref(desc), values, {2}))
    assert state.values == (2047, 1, 513)
    assert state.buttons == 0b10


def test_14_bit_axes_with_pad_bits() -> None:
    desc = joystick(
        axes([0x30], 14, 0, 16383), pad(2), axes([0x31], 14, 0, 16383), pad(2), buttons(1, 16)
    )
    layout = parse_descriptor(desc)
    assert [f.bit_offset for f in layout.inputs] == [0, 16]
    report = hid_encoder.encode(ref(desc), {(u.GD_X, 0): 16383, (u.GD_Y, 0): 8192}, {1, 16})
    state = decode(layout, report)
    assert state.values == (16383, 8192)
    assert state.buttons == 0x8001


def test_pad_bits_never_leak_into_values() -> None:
    desc = joystick(axes([0x30], 14, 0, 16383), pad(2))
    assert decode(parse_descriptor(desc), b"\xff\xff").values == (16383,)


def test_16_bit_0_to_65535_from_a_4_byte_item() -> None:
    desc = joystick(usage_page(1), usage(0x30), logical_min(0), logical_max(65535, 4))
    desc = desc[:-1] + report_size(16) + report_count(1) + input_() + END
    layout = parse_descriptor(desc)
    (x,) = layout.inputs
    assert (x.logical_min, x.logical_max) == (0, 65535)
    assert decode(layout, b"\xff\xff").values == (65535,)
    assert layout.initial_state().values == (32768,)


def test_xbox_logical_max_ffff_with_minimum_0_is_unsigned() -> None:
    # 15 00 26 FF FF: read as signed the maximum would be -1; hid-core reads it unsigned.
    desc = joystick(
        usage(0x30), logical_min(0), bytes.fromhex("26ffff"), report_size(16), report_count(1)
    )
    layout = parse_descriptor(desc[:-1] + input_() + END)
    assert layout.inputs[0].logical_max == 65535
    assert decode(layout, b"\x00\x80").values == (32768,)


def test_negative_minimum_makes_the_field_signed() -> None:
    desc = joystick(axes([0x30, 0x31], 16, -32768, 32767), axes([0x32], 8, -127, 127))
    layout = parse_descriptor(desc)
    assert [(f.logical_min, f.logical_max) for f in layout.inputs] == [
        (-32768, 32767),
        (-32768, 32767),
        (-127, 127),
    ]
    assert decode(layout, bytes.fromhex("0080ffff81")).values == (-32768, -1, -127)
    assert layout.initial_state().values == (0, 0, 0)


def test_report_count_larger_than_usage_range_buttons() -> None:
    # Raptor: Usage Min 1, Max 29, Report Count 128. Bits past the range repeat button 29;
    # only its first bit counts, so a stray bit never presses a button.
    desc = joystick(buttons(1, 4, count=16))
    layout = parse_descriptor(desc)
    assert layout.button_count == 4
    assert layout.input_report_lengths == {0: 2}
    assert decode(layout, b"\xf0\xff").buttons == 0
    assert decode(layout, b"\x09\x00").buttons == 0b1001


def test_report_count_larger_than_usage_list_values() -> None:
    desc = joystick(axes([0x30, 0x31], 8, 0, 255)[:-4] + report_count(3) + input_())
    layout = parse_descriptor(desc)
    assert [(u.usage_name(f.usage), f.occurrence, f.bit_offset) for f in layout.inputs] == [
        ("X", 0, 0),
        ("Y", 0, 8),
        ("Y", 1, 16),
    ]
    assert decode(layout, b"\x01\x02\x03").values == (1, 2, 3)


def test_raptor_real_descriptor_128_button_bits_29_buttons() -> None:
    layout = parse_descriptor(DEVICES["Sanmos Group"])
    assert layout.button_count == 29
    assert layout.buttons[0].count == 29
    hat = layout.hat_fields()[0]
    assert (hat.bit_size, hat.logical_min, hat.logical_max, hat.has_null) == (16, 0, 239, True)


def test_hat_1_to_8_with_null() -> None:
    desc = joystick(
        usage(0x39),
        logical_min(1),
        logical_max(8),
        report_size(4),
        report_count(1),
        input_(DATA_VAR_NULL),
        pad(4),
    )
    layout = parse_descriptor(desc)
    (hat,) = layout.hat_fields()
    assert hat.has_null and (hat.logical_min, hat.logical_max) == (1, 8)
    (null,) = layout.initial_state().values
    assert not 1 <= null <= 8 and 0 <= null <= 15
    assert decode(layout, b"\x03").values == (3,)
    assert decode(layout, b"\x00").values == (0,)


def test_hat_0_to_7_with_null() -> None:
    desc = (
        joystick(usage(0x39), logical_min(0), logical_max(7), report_size(4), report_count(1))[:-1]
        + input_(DATA_VAR_NULL)
        + pad(4)
        + END
    )
    layout = parse_descriptor(desc)
    assert layout.initial_state().values == (8,)
    assert decode(layout, b"\xff").values == (15,)


def test_report_ids_split_inputs_and_merge_state() -> None:
    desc = joystick(
        report_id(1),
        axes([0x30], 8, 0, 255),
        buttons(1, 8),
        report_id(2),
        axes([0x31], 16, 0, 1023),
        buttons(9, 16),
    )
    layout = parse_descriptor(desc)
    assert layout.uses_report_ids
    assert layout.input_report_lengths == {1: 2, 2: 3}
    assert [(f.report_id, f.bit_offset) for f in layout.inputs] == [(1, 0), (2, 0)]
    decoder = layout.make_decoder()
    assert decoder.feed(bytes([1, 200, 0x81]))
    assert decoder.feed(bytes([2, 0xFF, 0x03, 0x02]))
    assert decoder.state() == InputState((200, 1023), 0x0281)
    assert decoder.feed(bytes([1, 5, 0]))  # report 1 releases its buttons only
    assert decoder.state() == InputState((5, 1023), 0x0200)
    assert not decoder.feed(bytes([3, 0, 0, 0]))
    assert not decoder.feed(bytes([2, 0]))
    assert decoder.feed(bytes([2, 1, 0, 0, 99, 99]))  # longer than needed is fine
    assert decoder.bad_reports == 2 and decoder.reports == 4


def test_output_and_feature_items_do_not_move_input_offsets() -> None:
    desc = joystick(
        usage(0x30),
        logical_min(0),
        logical_max(255),
        report_size(8),
        report_count(4),
        output(),
        feature(),
        usage(0x30),
        report_count(1),
        input_(),
    )
    layout = parse_descriptor(desc)
    assert layout.inputs[0].bit_offset == 0
    assert layout.input_report_lengths == {0: 1}


def test_simulation_page_collection_and_usages() -> None:
    desc = joystick(axes([0xBA, 0xBB], 8, 0, 255, page=0x02), application=0x01, page=0x02)
    layout = parse_descriptor(desc)
    assert layout.application == u.SIM_FLIGHT_SIMULATION
    assert [f.usage for f in layout.inputs] == [u.SIM_RUDDER, u.SIM_THROTTLE]
    assert u.is_joystick_like(layout.application)
    assert u.device_type_name(layout.application) == "FLIGHTSIM"


def test_extended_4_byte_usages_keep_their_page() -> None:
    desc = joystick(
        usage_page(0x09),
        usage(0x00010030, size=4),
        usage(0x00010031, size=4),
        logical_min(0),
        logical_max(65535, 4),
        report_size(16),
        report_count(2),
        input_(),
        usage_page(0xFF00),
        usage(0x00090001, size=4),
        logical_max(1),
        report_size(1),
        report_count(1),
        input_(),
        pad(7),
    )
    layout = parse_descriptor(desc)
    assert [f.usage for f in layout.inputs] == [u.GD_X, u.GD_Y]
    assert layout.button_count == 1
    assert decode(layout, bytes.fromhex("3412ffff01")) == InputState((0x1234, 0xFFFF), 1)


def test_usage_page_after_usages_applies_to_them() -> None:
    # hid-core and hid-tools: the last Usage Page before the Main item completes 1/2-byte usages
    desc = (
        joystick(usage(0xBB), usage_page(0x02), logical_min(0), logical_max(255), report_size(8))[
            :-1
        ]
        + report_count(1)
        + input_()
        + END
    )
    assert parse_descriptor(desc).inputs[0].usage == u.SIM_THROTTLE


def test_zero_size_items_have_value_0() -> None:
    # Saitek / DFP: 0x14 (Logical Minimum, no data) and 0x34; Report Size 0 on a constant.
    desc = joystick(
        logical_min(-127),
        b"\x14",
        b"\x34",
        axes([0x30], 8, 0, 255)[: -len(logical_min(0) + logical_max(255))],
    )
    desc = joystick(
        usage(0x30),
        logical_min(-127),
        b"\x14",
        b"\x34",
        logical_max(255),
        report_size(8),
        report_count(1),
        input_(),
        b"\x74",  # Report Size, no data: 0
        report_count(3),
        input_(CONST),
    )
    layout = parse_descriptor(desc)
    assert (layout.inputs[0].logical_min, layout.inputs[0].logical_max) == (0, 255)
    assert layout.input_report_lengths == {0: 1}
    assert decode(layout, b"\xff").values == (255,)


def test_saitek_real_descriptor() -> None:
    layout = parse_descriptor(DEVICES["Saitek P-series"])
    usages_ = {f.usage for f in layout.inputs if f.report_id == 1}
    assert {u.GD_X, u.GD_Y, u.SIM_RUDDER, u.SIM_THROTTLE, u.GD_HAT_SWITCH} <= usages_
    assert layout.button_count == 12


def test_xbox_real_descriptor() -> None:
    layout = parse_descriptor(DEVICES["Xbox 360"])
    x = layout.inputs[by_usage(layout, u.GD_X)]
    assert (x.logical_min, x.logical_max, x.bit_size) == (0, 65535, 16)
    hat = layout.hat_fields()[0]
    assert (hat.logical_min, hat.logical_max) == (1, 8)


def test_kernel_fixed_dfp_descriptor() -> None:
    layout = parse_descriptor(DEVICES["Logitech Driving"])
    x = layout.inputs[by_usage(layout, u.GD_X)]
    assert (x.bit_offset, x.bit_size, x.logical_max) == (0, 14, 16383)
    assert layout.button_count == 14
    assert {f.usage for f in layout.inputs} == {u.GD_X, u.GD_Y, u.GD_RZ, u.GD_HAT_SWITCH}


def test_x52_more_than_32_buttons() -> None:
    layout = parse_descriptor(DEVICES["Saitek/Logitech X52"])
    assert layout.button_count == 34
    report = bytearray(14)
    report[12] = 0x02  # bit 97 -> button 34 (buttons start at bit 64)
    assert decode(layout, bytes(report)).buttons == 1 << 33


def test_switch_pro_extended_usages() -> None:
    layout = parse_descriptor(DEVICES["Nintendo Switch"])
    assert {u.GD_X, u.GD_Y, u.GD_Z, u.GD_RZ} <= {f.usage for f in layout.inputs}


def test_push_pop_restore_globals() -> None:
    desc = joystick(
        logical_min(0),
        logical_max(255),
        report_size(8),
        report_count(1),
        PUSH,
        report_size(4),
        logical_max(15),
        usage(0x39),
        input_(),
        pad(4),
        POP,
        usage(0x30),
        input_(),
    )
    layout = parse_descriptor(desc)
    assert [(f.bit_offset, f.bit_size, f.logical_max) for f in layout.inputs] == [
        (0, 4, 15),
        (8, 8, 255),
    ]


def test_button_array_sets_button_bits() -> None:
    desc = joystick(
        usage_page(9),
        usage_min(1),
        usage_max(8),
        logical_min(1),
        logical_max(8),
        report_size(4),
        report_count(2),
        input_(DATA_ARRAY),
        usage_page(7),  # keyboard keys: an array usb2rc does not read
        usage_min(0),
        usage_max(0x65),
        logical_max(0x65),
        report_size(8),
        report_count(1),
        input_(DATA_ARRAY),
        axes([0x30], 8, 0, 255),
    )
    layout = parse_descriptor(desc)
    assert layout.button_count == 8
    assert layout.inputs[0].bit_offset == 16
    assert decode(layout, bytes([0x43, 0x00, 7])) == InputState((7,), 0b1100)
    assert decode(layout, bytes([0x90, 0x00, 7])).buttons == 0  # 0 and 9 are outside 1..8
    report = hid_encoder.encode(ref(desc), {(u.GD_X, 0): 9}, {2, 8})
    assert decode(layout, report) == InputState((9,), 0b10000010)


def test_constant_and_usageless_fields_are_padding() -> None:
    desc = joystick(
        usage(0x30),
        logical_min(0),
        logical_max(255),
        report_size(8),
        report_count(1),
        input_(CONST),
        input_(),  # no usage left: padding
        usage(0x31),
        input_(),
    )
    layout = parse_descriptor(desc)
    assert [(f.usage, f.bit_offset) for f in layout.inputs] == [(u.GD_Y, 16)]


def test_application_is_first_top_level_application_collection() -> None:
    desc = (
        usage_page(1)
        + usage(0x01)
        + collection(0)  # physical, not an application
        + END
        + joystick(usage(0x02), collection(1), END, axes([0x30], 8, 0, 255), application=0x05)
        + joystick(axes([0x31], 8, 0, 255))
    )
    layout = parse_descriptor(desc)
    assert layout.application == u.GD_GAMEPAD
    assert [f.usage for f in layout.inputs] == [u.GD_X, u.GD_Y]


def test_long_items_and_delimiters() -> None:
    long_item = bytes([0xFE, 2, 0x10, 0xAA, 0xBB])
    delimited = b"\xa9\x01" + usage(0x30) + usage(0x31) + b"\xa9\x00"
    desc = joystick(long_item, delimited, axes([], 8, 0, 255)[1:])
    desc = joystick(
        long_item,
        b"\xa9\x01",
        usage(0x30),
        b"\xa9\x00",
        b"\xa9\x01",
        usage(0x31),  # second delimited alternative: ignored (as hid-core)
        b"\xa9\x00",
        logical_min(0),
        logical_max(255),
        report_size(8),
        report_count(1),
        input_(),
    )
    layout = parse_descriptor(desc)
    assert [f.usage for f in layout.inputs] == [u.GD_X]


def test_initial_state_centres_axes_and_nulls_hats() -> None:
    desc = joystick(
        axes([0x30], 8, 0, 255),
        axes([0x31], 10, 0, 1023),
        axes([0x32], 8, -127, 127),
        usage(0x39),
        logical_min(0),
        logical_max(7),
        report_size(8),
        report_count(1),
        input_(DATA_VAR_NULL),
    )
    layout = parse_descriptor(desc)
    assert layout.initial_state() == InputState((128, 512, 0, 8), 0)
    assert layout.make_decoder().state() == layout.initial_state()


def test_feed_never_raises_on_odd_input() -> None:
    decoder = parse_descriptor(DEVICES["Thrustmaster TWCS"]).make_decoder()
    for report in (b"", b"\x01", bytes(200), bytearray(64), memoryview(bytes([1] * 64))):
        decoder.feed(report)
    assert decoder.bad_reports == 4  # empty, short, and report ID 0 twice


# -- broken descriptors --------------------------------------------------------------------


BROKEN = {
    "truncated item": (joystick(axes([0x30], 8, 0, 255))[:-1] + b"\x26\xff", "byte"),
    "truncated long item": (b"\xfe\x05\x00\x01", "long item at byte 0"),
    "end collection without collection": (b"\xc0" + joystick(), "byte 0"),
    "unbalanced collections": (joystick(axes([0x30], 8, 0, 255))[:-1], "open"),
    "pop without push": (joystick(POP, axes([0x30], 8, 0, 255)), "Pop without Push at byte 6"),
    "report size 0 on data": (joystick(usage(0x30), report_count(2), input_()), "Report Size 0"),
    "report size absurd": (joystick(_item(0x74, 300), axes([0x30], 8, 0, 255)), "Report Size"),
    "report count absurd": (joystick(_item(0x94, 20000)), "Report Count"),
    "report id 0": (joystick(report_id(0), axes([0x30], 8, 0, 255)), "Report ID 0"),
    "no inputs": (joystick(axes([0x30], 8, 0, 255)[:-2] + output()), "no usable inputs"),
    "max below min": (joystick(axes([0x30], 8, 10, 5)), "maximum below minimum"),
    "mixed report ids": (
        joystick(axes([0x30], 8, 0, 255), report_id(1), axes([0x31], 8, 0, 255)),
        "report ID",
    ),
    "unknown global item": (joystick(b"\xc4\x01", axes([0x30], 8, 0, 255)), "global item 0xC4"),
    "report too long": (
        joystick(usage(0x30), report_size(255), _item(0x94, 12000), input_()),
        "longer than",
    ),
    "push overflow": (joystick(PUSH * 40, axes([0x30], 8, 0, 255)), "Push"),
    "empty": (b"", "no usable inputs"),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_broken_descriptors_raise_descriptor_error(name: str) -> None:
    data, message = BROKEN[name]
    with pytest.raises(DescriptorError, match=message):
        parse_descriptor(data)


# -- fuzz (seeded, fast; a longer run belongs to the slow suite) ---------------------------


def _check_any(data: bytes) -> None:
    try:
        layout = parse_descriptor(data)
    except DescriptorError:
        return
    decoder = layout.make_decoder()
    rng = random.Random(data)
    for rid, length in layout.input_report_lengths.items():
        prefix = bytes([rid]) if layout.uses_report_ids else b""
        assert decoder.feed(prefix + rng.randbytes(length))
    state = decoder.state()
    assert len(state.values) == len(layout.inputs)
    assert state.buttons >> layout.button_count == 0


def _mutate(data: bytes, rng: random.Random) -> bytes:
    buf = bytearray(data)
    for _ in range(rng.randint(1, 6)):
        action = rng.random()
        pos = rng.randrange(len(buf) + 1)
        if action < 0.5 and buf:
            buf[min(pos, len(buf) - 1)] = rng.randrange(256)
        elif action < 0.75:
            buf[pos:pos] = rng.randbytes(rng.randint(1, 4))
        else:
            del buf[pos : pos + rng.randint(1, 4)]
    return bytes(buf)


def test_fuzz_random_bytes() -> None:
    rng = random.Random(1)
    for _ in range(1500):
        _check_any(rng.randbytes(rng.randint(0, 120)))


def test_fuzz_mutated_real_descriptors() -> None:
    rng = random.Random(2)
    seeds = list(DEVICES.values())
    for _ in range(1500):
        _check_any(_mutate(rng.choice(seeds), rng))


@pytest.mark.slow
def test_fuzz_long() -> None:
    rng = random.Random(3)
    seeds = list(DEVICES.values())
    for _ in range(50000):
        _check_any(_mutate(rng.choice(seeds), rng))
        _check_any(rng.randbytes(rng.randint(0, 300)))
