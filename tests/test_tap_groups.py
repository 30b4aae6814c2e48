"""DeviceBinding.tap_groups: where it answers, a tap changes `apply` by those button bits only.

The tap latch (usb2rc.nodes.step.TapLatch) shows a tap as the node-button bits it adds when
`tap_groups` answers, and asks `apply` again when it does not (an axis made of buttons, the
handover button). These tests hold the shortcut to `apply` itself, on every real descriptor's
default binding and on configured bindings with a button-pair axis and a handover button.
"""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.configfile import load_config_text
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import DeviceLayout, InputField, InputState, parse_descriptor
from usb2rc.nodes.binding import DeviceBinding, default_binding
from usb2rc.nodes.mapping import compile_mapping

REAL = [
    (d["name"], parse_descriptor(bytes.fromhex(d["hex"])))
    for d in json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
]
DEFAULTS = [default_binding(layout, name) for name, layout in REAL if layout.inputs]

X, Y, HAT = 0x10030, 0x10031, 0x10039
STICK = DeviceInfo("k1", "p1", 0x044F, 0xB10A, product="stick", port_path="1-1")
STICK_LAYOUT = DeviceLayout(
    0x10004,
    False,
    (
        InputField(0, 0, X, 0, 16, 0, 1023, False, 0),
        InputField(1, 0, Y, 16, 16, 0, 1023, False, 0),
        InputField(2, 0, HAT, 32, 8, 0, 7, True, 0),
    ),
    16,
    {0: 7},
)


def configured(axes: str, extra: str = "") -> DeviceBinding:
    text = f"devices:\n  - name: stick\n    match: {{vid: 0x044f}}\n    axes:\n{axes}\n{extra}\n"
    return compile_mapping(load_config_text(text, "t.yaml")).bind(STICK, STICK_LAYOUT)


PAIR = configured("      x: {usage: X}\n      aux1: {buttons: [3, 4]}")
HANDOVER = configured(
    "      x: {usage: X}", "    handover: {button: 5, destination: 7, frames: 10}"
)
BINDINGS = [*DEFAULTS, PAIR, HANDOVER]


def pressed(state: InputState, taps: int) -> InputState:
    return InputState(state.values, state.buttons | taps)


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(BINDINGS), st.data())
def test_where_tap_groups_answers_apply_changes_by_those_bits_only(
    binding: DeviceBinding, data: st.DataObject
) -> None:
    count = max((info.field_index or 0) for info in binding.axis_info if info) + 3
    values = tuple(data.draw(st.lists(st.integers(-70000, 70000), min_size=count, max_size=64)))
    state = InputState(values, data.draw(st.integers(0, (1 << 40) - 1)))
    taps = data.draw(st.integers(1, (1 << 40) - 1))
    bits = binding.tap_groups(taps)
    if bits is None:
        return
    before, after = binding.apply(state), binding.apply(pressed(state, taps))
    assert after == before._replace(group1=before.group1 | bits[0], group2=before.group2 | bits[1])


def test_an_axis_made_of_buttons_or_the_handover_button_asks_apply() -> None:
    assert PAIR.tap_groups(1 << 2) is None  # button 3 moves aux1
    assert HANDOVER.tap_groups(1 << 4) is None  # button 5 is the handover's
    assert HANDOVER.tap_groups(1 << 0) is not None
    state = InputState((512, 512, 8), 0)
    moved = PAIR.apply(pressed(state, 1 << 3)).axes
    assert moved != PAIR.apply(state).axes  # the shortcut would have missed this
