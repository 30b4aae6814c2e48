"""DeviceBinding.guarded_axes: what a device waiting in the neutral guard is stepped on.

While a device waits, its step computes only the guarded axes (the guard looks at nothing
else) and sends its failsafe values. These tests hold `guarded_axes` to `apply` on every
real descriptor's zero-config binding, and the failsafe memo to a fresh computation.
"""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid.descriptor import InputState, parse_descriptor
from usb2rc.nodes import known_devices
from usb2rc.nodes.binding import DeviceBinding, NodeInputs, default_binding

DEVICES = json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
# (binding, how many values its device's state has)
BINDINGS = [
    (
        default_binding(
            layout, d["name"], known=known_devices.lookup(int(d["vid"], 16), int(d["pid"], 16))
        ),
        len(layout.inputs),
    )
    for d in DEVICES
    if (layout := parse_descriptor(bytes.fromhex(d["hex"]))).inputs
]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(BINDINGS), st.data())
def test_guarded_axes_are_applys_guarded_axes(
    bound: tuple[DeviceBinding, int], data: st.DataObject
) -> None:
    binding, count = bound
    values = tuple(data.draw(st.lists(st.integers(-70000, 70000), min_size=count, max_size=count)))
    state = InputState(values, data.draw(st.integers(0, (1 << 64) - 1)))
    guarded = {axis.slot for axis in binding.guard.axes}
    full, waiting = binding.apply(state), binding.guarded_axes(state)
    assert waiting == [v if k in guarded else None for k, v in enumerate(full.axes)]


def test_most_real_devices_guard_an_axis() -> None:
    assert sum(bool(b.guard.axes) for b, _ in BINDINGS) >= 8


def test_the_failsafe_memo_answers_as_a_fresh_computation() -> None:
    binding = BINDINGS[0][0]
    first = NodeInputs((1, 2, 3, 4, 5, 6, 7, 8, 9, 10), 0, 0)
    second = NodeInputs((10, 9, 8, 7, 6, 5, 4, 3, 2, 1), 0, 0)
    for last in (None, first, first, second, None, second):
        assert binding.failsafe(last) == binding._failsafe_inputs(last)
