"""Mapping: exact wire values for every option, default layout, hats, buttons, SUMD."""

from __future__ import annotations

from fractions import Fraction

import pytest

from usb2rc.configfile import Config, load_config_text
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import DeviceLayout, InputField, InputState
from usb2rc.nodes.binding import MappingError, NodeInputs, default_axis_fields
from usb2rc.nodes.mapping import ChannelSource, compile_mapping
from usb2rc.nodes.scaling import hat_direction, scale_linear, to_wire
from usb2rc.protocols.sumd.channels import sumd_value

X, Y, Z, RX, RY, RZ, SLIDER, DIAL, WHEEL, HAT = (
    0x10030, 0x10031, 0x10032, 0x10033, 0x10034, 0x10035, 0x10036, 0x10037, 0x10038, 0x10039,
)  # fmt: skip
RUDDER, THROTTLE = 0x200BA, 0x200BB
STICK = DeviceInfo("k1", "p1", 0x044F, 0xB10A, serial="S1", product="T.16000M", port_path="1-1")
OTHER = DeviceInfo("k2", "p2", 0x1234, 0x5678, product="Saitek Pad", port_path="1-2")


def layout(*fields: tuple[int, int, int], buttons: int = 16) -> DeviceLayout:
    """Fields as (usage, logical_min, logical_max); occurrences counted per usage."""
    seen: dict[int, int] = {}
    inputs = []
    for i, (usage, lo, hi) in enumerate(fields):
        inputs.append(InputField(i, 0, usage, 16 * i, 16, lo, hi, usage == HAT, seen.get(usage, 0)))
        seen[usage] = seen.get(usage, 0) + 1
    return DeviceLayout(0x10004, False, tuple(inputs), buttons, {0: 2 * len(fields) + 8})


def bind_one(yaml_axes: str, fields: list[tuple[int, int, int]], extra: str = ""):
    text = f"""
devices:
  - name: stick
    match: {{vid: 0x044f}}
    node_id: 1
    axes:
{yaml_axes}
{extra}
"""
    mapping = compile_mapping(load_config_text(text, "t.yaml"))
    return mapping.bind(STICK, layout(*fields))


def exact(v: int, lo: int, hi: int) -> int:
    """docs/ICD.md, "Axis scaling", in exact rationals (Python's round: halves to even)."""
    v = min(max(v, lo), hi)
    return round(Fraction((v - lo) * 65535, hi - lo)) - 32768


# --------------------------------------------------------------------------- linear scaling


@pytest.mark.parametrize(
    ("lo", "hi"),
    [(0, 255), (0, 1023), (0, 16383), (0, 65535), (-512, 511), (-32768, 32767), (-127, 127)],
)
def test_linear_ends_are_exact(lo: int, hi: int) -> None:
    assert scale_linear(lo, lo, hi) == -32768
    assert scale_linear(hi, lo, hi) == 32767
    assert scale_linear(lo, lo, hi, unsigned=True) == 0
    assert scale_linear(hi, lo, hi, unsigned=True) == 65535
    assert scale_linear(lo - 5, lo, hi) == -32768  # clamped
    assert scale_linear(hi + 5, lo, hi) == 32767


@pytest.mark.parametrize(("lo", "hi"), [(0, 255), (0, 1023), (-512, 511), (0, 16383)])
def test_linear_every_value_matches_formula(lo: int, hi: int) -> None:
    assert all(scale_linear(v, lo, hi) == exact(v, lo, hi) for v in range(lo, hi + 1))


def test_linear_known_values() -> None:
    assert scale_linear(128, 0, 255) == 128  # 128 * 257 - 32768
    assert scale_linear(512, 0, 1023) == 32  # round(32799.97) - 32768
    assert scale_linear(0, -512, 511) == 32  # round(512 * 65535 / 1023) - 32768
    assert scale_linear(12345, 0, 65535) == 12345 - 32768
    assert scale_linear(12345, 0, 65535, unsigned=True) == 12345  # 0..65535 held
    assert scale_linear(-5, -32768, 32767) == -5


def test_to_wire_ends_and_centre() -> None:
    assert to_wire(-1.0) == -32768
    assert to_wire(0.0) == 0
    assert to_wire(1.0) == 32767
    assert to_wire(0.5) == 16383
    assert to_wire(-0.5) == -16384
    assert to_wire(2.0) == 32767
    assert (to_wire(-1.0, True), to_wire(0.0, True), to_wire(1.0, True)) == (0, 32768, 65535)


# --------------------------------------------------------------------------- axis pipeline


def values_x(binding, *raws: int) -> list[int]:
    return [binding.apply(InputState((v,), 0)).axes[0] for v in raws]


def test_unconfigured_options_use_exact_formula_through_binding() -> None:
    b = bind_one("      x: {usage: X}", [(X, 0, 1023)])
    assert values_x(b, 0, 512, 1023, 2000) == [-32768, 32, 32767, 32767]


def test_invert_alone_stays_exact() -> None:
    b = bind_one("      x: {usage: X, invert: true}", [(X, 0, 255)])
    assert values_x(b, 0, 255, 127, 128) == [32767, -32768, 128, -129]  # mirrored raw


def test_deadband_zero_inside_and_rescaled_outside() -> None:
    b = bind_one("      x: {usage: X, deadband: 0.1}", [(X, 0, 1000)])
    # x = (v - 500) / 500: 550 -> 0.1 (edge, 0); 775 -> 0.55 -> (0.55 - 0.1) / 0.9 = 0.5
    assert values_x(b, 500, 550, 450, 775, 225, 1000, 0) == [
        0, 0, 0, 16383, -16384, 32767, -32768,
    ]  # fmt: skip


def test_expo() -> None:
    b = bind_one("      x: {usage: X, expo: 0.5}", [(X, 0, 1000)])
    # x = 0.5 -> 0.5 * 0.5 + 0.5 * 0.125 = 0.3125 -> floor(43007.84) - 32768 = 10239
    assert values_x(b, 750, 250, 500, 1000, 0) == [10239, -10240, 0, 32767, -32768]


def test_trim_added_after_invert_and_clamped() -> None:
    b = bind_one("      x: {usage: X, trim: 0.25, invert: true}", [(X, 0, 1000)])
    # centre -> 0.25; raw 1000 -> -1 + 0.25 = -0.75; raw 0 -> +1 + 0.25 clamps to +1
    assert values_x(b, 500, 1000, 0) == [8191, -24576, 32767]  # floor(40959.875)


def test_calibration_min_center_max() -> None:
    cal = "      x: {usage: X, calibration: {min: 12, center: 128, max: 250}}"
    b = bind_one(cal, [(X, 0, 255)])
    # 70 -> (70 - 128) / 116 = -0.5; 189 -> (189 - 128) / 122 = 0.5
    assert values_x(b, 0, 12, 70, 128, 189, 250, 255) == [
        -32768, -32768, -16384, 0, 16383, 32767, 32767,
    ]  # fmt: skip


def test_pipeline_order_calibration_deadband_expo_invert() -> None:
    axis = (
        "      x: {usage: X, calibration: {min: 0, center: 100, max: 300}, deadband: 0.2,"
        " expo: 1.0, invert: true}"
    )
    b = bind_one(axis, [(X, 0, 1023)])
    # raw 250 -> 0.75 -> deadband (0.75 - 0.2) / 0.8 = 0.6875 -> expo 0.6875^3 -> invert
    expected = to_wire(-(0.6875**3))
    assert values_x(b, 250, 120, 300) == [expected, 0, -32768]


def test_unsigned_shaped_and_linear() -> None:
    b = bind_one("      x: {usage: X, unsigned: true, deadband: 0.1}", [(X, 0, 1000)])
    assert values_x(b, 0, 500, 1000) == [0, 32768, 65535]
    b = bind_one("      x: {usage: X, unsigned: true}", [(X, 0, 65535)])
    assert values_x(b, 0, 40000, 65535) == [0, 40000, 65535]


def test_failsafe_configured_or_held_buttons_clear() -> None:
    axes = "      x: {usage: X, failsafe: -32768}\n      y: Y"
    b = bind_one(axes, [(X, 0, 255), (Y, 0, 255)], '    buttons: {"1-4": "1-4"}')
    last = b.apply(InputState((255, 0), 0b1111))
    assert last == NodeInputs((32767, -32768, *[None] * 8), 0b1111, 0)
    assert b.failsafe(last) == NodeInputs((-32768, -32768, *[None] * 8), 0, 0)
    assert b.failsafe(None).axes[:2] == (-32768, 0)


# --------------------------------------------------------------------------- hats


HAT8 = [(HAT, 0, 7)]
BITS = [1 << (24 + d) for d in range(8)]


def hat_binding(to: str, fields=None):
    text = f"""
devices:
  - name: stick
    match: {{vid: 0x044f}}
    hats: [{{usage: HatSwitch, to: {to}}}]
"""
    return compile_mapping(load_config_text(text, "t.yaml")).bind(STICK, layout(*(fields or HAT8)))


def test_hat1_every_direction_and_null() -> None:
    b = hat_binding("hat1")
    assert [b.apply(InputState((v,), 0)).group1 for v in range(8)] == BITS
    assert b.apply(InputState((8,), 0)).group1 == 0
    assert b.apply(InputState((15,), 0)).group1 == 0
    assert b.group1_mask == 0xFF000000


def test_hat_one_based_and_four_way() -> None:
    b = hat_binding("hat1", [(HAT, 1, 8)])
    assert [b.apply(InputState((v,), 0)).group1 for v in range(1, 9)] == BITS
    assert b.apply(InputState((0,), 0)).group1 == 0
    b = hat_binding("hat1", [(HAT, 0, 3)])
    assert [b.apply(InputState((v,), 0)).group1 for v in range(4)] == [BITS[0], *BITS[2:7:2]]


def test_hat_direction_rule() -> None:
    assert [hat_direction(v, 0, 239) for v in (0, 30, 60, 90, 120, 150, 180, 210)] == [
        0, 1, 2, 3, 4, 5, 6, 7,
    ]  # fmt: skip
    assert hat_direction(240, 0, 239) is None
    assert hat_direction(-1, 0, 7) is None


def test_hat_to_eight_node_buttons_across_groups() -> None:
    b = hat_binding("[20, 21, 22, 23, 24, 25, 26, null]")
    out = [b.apply(InputState((v,), 0)) for v in range(9)]
    assert [(o.group1, o.group2) for o in out] == [
        (1 << 19, 0), (1 << 20, 0), (1 << 21, 0), (1 << 22, 0), (1 << 23, 0),
        (0, 1), (0, 2), (0, 0), (0, 0),
    ]  # fmt: skip


def test_hat_axis_sources() -> None:
    axes = "      x: {hat: HatSwitch, axis: x}\n      y: {hat: HatSwitch, axis: y}"
    b = bind_one(axes, HAT8)
    got = [b.apply(InputState((v,), 0)).axes[:2] for v in range(9)]
    lo, hi = -32768, 32767
    assert got == [
        (0, hi), (hi, hi), (hi, 0), (hi, lo), (0, lo), (lo, lo), (lo, 0), (lo, hi), (0, 0),
    ]  # fmt: skip


def test_button_pair_three_position() -> None:
    b = bind_one("      aux1: {buttons: [3, 4]}", [(X, 0, 255)])
    got = [b.apply(InputState((0,), m)).axes[8] for m in (0, 0b100, 0b1000, 0b1100)]
    assert got == [0, -32768, 32767, 0]
    b = bind_one("      aux1: {buttons: [3, 4], invert: true, unsigned: true}", [(X, 0, 255)])
    got = [b.apply(InputState((0,), m)).axes[8] for m in (0, 0b100, 0b1000)]
    assert got == [32768, 65535, 0]


# --------------------------------------------------------------------------- buttons


def test_default_buttons_follow_the_icd() -> None:
    b = compile_mapping(Config.default()).bind(OTHER, layout((X, 0, 255), buttons=60))
    press = lambda n: b.apply(InputState((0,), 1 << (n - 1)))  # noqa: E731
    assert (press(1).group1, press(1).group2) == (1, 0)
    assert (press(24).group1, press(24).group2) == (1 << 23, 0)
    assert (press(25).group1, press(25).group2) == (0, 1)
    assert (press(56).group1, press(56).group2) == (0, 1 << 31)
    assert (press(57).group1, press(57).group2) == (0, 0)
    assert b.node_id is None
    assert (b.group1_mask, b.group2_mask) == (0x00FFFFFF, 0xFFFFFFFF)


def test_button_ranges_and_single_buttons() -> None:
    extra = '    buttons: {"1-14": "41-54", "15": 1, "20-30": "20-30"}'
    b = bind_one("      x: X", [(X, 0, 255)], extra)
    out = b.apply(InputState((0,), (1 << 14) - 1))  # HID 1..14 -> node 41..54: group 2 bits 16..29
    assert (out.group1, out.group2) == (0, 0x3FFF << 16)
    out = b.apply(InputState((0,), 1 << 14))
    assert (out.group1, out.group2) == (1, 0)
    out = b.apply(InputState((0,), ((1 << 11) - 1) << 19))  # HID 20..30 across the groups
    assert (out.group1, out.group2) == (0b11111 << 19, 0b111111)
    assert (b.group1_mask, b.group2_mask) == (1 | 0b11111 << 19, 0x3FFF << 16 | 0b111111)


# --------------------------------------------------------------------------- default layout


def test_default_axes_same_name_then_aux() -> None:
    lay = layout(
        (Y, 0, 255), (X, 0, 255), (THROTTLE, 0, 255), (SLIDER, 0, 255), (WHEEL, 0, 255),
        (SLIDER, 0, 255), (DIAL, 0, 255), (RZ, 0, 255), (RX, 0, 1), (HAT, 0, 7),
    )  # fmt: skip
    got = [(slot, f.index) for slot, f in default_axis_fields(lay)]
    assert got == [
        ("x", 1), ("y", 0), ("slider", 3), ("rx", 8), ("rz", 7), ("dial", 6),
        ("aux1", 4), ("aux2", 5),
    ]  # fmt: skip


def test_default_simulation_usages_fill_free_aux() -> None:
    lay = layout((X, 0, 255), (RUDDER, 0, 1023), (THROTTLE, 0, 255), (Z, 0, 3))
    assert [(s, f.index) for s, f in default_axis_fields(lay)] == [
        ("x", 0), ("z", 3), ("aux1", 1), ("aux2", 2),
    ]  # fmt: skip
    b = compile_mapping(Config.default()).bind(OTHER, lay)
    assert b.apply(InputState((0, 1023, 0, 3), 0)).axes == (
        -32768, None, 32767, None, None, None, None, None, 32767, -32768,
    )  # fmt: skip


# --------------------------------------------------------------------------- bind


def test_bind_matches_in_order_and_defaults_false() -> None:
    text = """
defaults: false
devices:
  - name: by-serial
    match: {vid: 0x044f, serial: S2}
    node_id: 3
  - name: by-port
    match: {port: "1-1"}
    node_id: 4
  - name: by-product
    match: {product: "t.16*"}
    node_id: 5
"""
    mapping = compile_mapping(load_config_text(text, "t.yaml"))
    b = mapping.bind(STICK, layout((X, 0, 255)))
    assert (b.name, b.node_id) == ("by-port", 4)
    assert mapping.bind(OTHER, layout((X, 0, 255))) is None
    assert mapping.pinned_node_ids() == {3, 4, 5}


def test_bind_missing_usage_names_the_line() -> None:
    with pytest.raises(MappingError, match=r"^t\.yaml:8: devices\[0\]\.axes\.z: usage Z"):
        bind_one("      x: X\n      z: Z", [(X, 0, 255)])


def test_binding_exposes_what_it_feeds() -> None:
    b = bind_one(
        "      x: X\n      rz: {usage: Rz, unsigned: true, failsafe: 0}",
        [(X, 0, 255), (RZ, 0, 1023)],
    )
    assert b.axis_slots == frozenset({"x", "rz"})
    info = b.axis_info[6]
    assert (info.source, info.unsigned, info.failsafe, info.raw_max) == ("Rz", True, 0, 1023)
    assert info.wire_range == (0, 65535)


# --------------------------------------------------------------------------- SUMD


def test_sumd_values() -> None:
    axes = (-32768, 0, 32767, None, 0, 65535, 0, 0, 0, 0)
    ax = lambda i, u=False: ChannelSource(1, "axis", i, u)  # noqa: E731
    assert [sumd_value(ax(i), axes, 0, 0) for i in range(3)] == [8800, 12000, 15200]
    assert [sumd_value(ax(i), axes, 0, 0, True) for i in range(3)] == [7200, 12000, 16800]
    assert sumd_value(ax(3), axes, 0, 0) == 12000
    assert sumd_value(ax(0), (16384,), 0, 0) == 13600  # 8800 + round(49152 * 6400 / 65535)
    assert sumd_value(ax(4, True), axes, 0, 0) == 8800
    assert sumd_value(ax(5, True), axes, 0, 0) == 15200
    button = lambda n: ChannelSource(1, "button", n)  # noqa: E731
    assert sumd_value(button(1), axes, 1, 0) == 15200
    assert sumd_value(button(25), axes, 1, 0) == 8800
    assert sumd_value(button(56), axes, 0, 1 << 31) == 15200


def test_sumd_channels_default_and_listed() -> None:
    text = """
outputs:
  - protocol: sumd
  - protocol: sumd
    channels: [node2.rz, node2.button3]
devices:
  - name: a
    match: {vid: 1}
    node_id: 2
    axes: {rz: {usage: Rz, unsigned: true}}
    buttons: {1-3: 1-3}
  - name: b
    match: {vid: 2}
    node_id: 5
"""
    mapping = compile_mapping(load_config_text(text, "t.yaml"))
    default = mapping.sumd_channels(mapping.config.outputs[0])
    assert [c.name for c in default] == [
        f"node2.{s}" for s in ("x", "y", "z", "rz", "slider", "rx", "ry", "dial")
    ]
    listed = mapping.sumd_channels(mapping.config.outputs[1])
    assert [(c.node_id, c.kind, c.index, c.unsigned) for c in listed] == [
        (2, "axis", 6, True), (2, "button", 3, False),
    ]  # fmt: skip
    zero = compile_mapping(Config.default())
    assert (
        zero.sumd_channels(load_config_text("outputs: [{protocol: sumd}]").outputs[0])[0].node_id
        == 0
    )


def test_compile_mapping_compiles_each_entry_once() -> None:
    """The matcher, button runs, unsigned slots and failsafe values of an entry are
    compiled with the mapping; a bind only adds what the device's layout decides."""
    text = """
devices:
  - name: stick
    match: {product: "T.16*"}
    node_id: 1
    axes: {x: X, rz: {usage: Rz, unsigned: true, failsafe: 100}}
    buttons: {1-4: 5-8}
"""
    mapping = compile_mapping(load_config_text(text, "t.yaml"))
    (entry,) = mapping.entries
    assert entry.matches(STICK) and not entry.matches(OTHER)
    assert (entry.unsigned_slots, entry.failsafe.axes[0], entry.failsafe.axes[6]) == (64, 0, 100)
    b = mapping.bind(STICK, layout((X, 0, 255), (RZ, 0, 1023)))
    assert b.button_runs is entry.button_runs and b.unsigned_slots == entry.unsigned_slots
