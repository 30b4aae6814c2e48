"""A held button is not a press (usb2rc.nodes.presses, docs/ICD.md "A held button is not a
press"): the press gate against a model of its rule, and in the node table (trims, switches,
handover, a reload)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from daemon_harness import HAT_NULL, T16000M_DESCRIPTOR, RecordSource, StickState
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.config.controls_model import SwitchConfig
from usb2rc.configfile import load_config_text
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.nodes.binding import DeviceBinding, default_binding
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.presses import PressGate
from usb2rc.nodes.step import DeviceView
from usb2rc.nodes.table import ExpectedEntry, NodeTable

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)
BINDING = default_binding(LAYOUT, "stick")  # HID buttons 1-16 -> node buttons 1-16
INFO = DeviceInfo(key="k0", path="k0", vid=0x044F, pid=0xB10A, product="T.16000M")
ENTRY = """devices:
  - name: stick
    match: {vid: 0x044f}
    node_id: 0
"""
AXES = "    axes: {x: X, y: Y, rz: Rz}\n"


def bound(entry: str) -> DeviceBinding:
    """The stick's binding under a config whose entry is ENTRY plus `entry`."""
    axes = "" if "axes:" in entry else AXES
    binding = compile_mapping(load_config_text(ENTRY + axes + entry, "c.yaml")).bind(INFO, LAYOUT)
    assert binding is not None
    return binding


@dataclass
class Reader:
    """A T.16000M's reader: its reports decoded by the device's descriptor, and the press
    log as usb2rc.hid.reader.DeviceReader keeps it (each report's rising edges get the next
    serial)."""

    buttons: int = 0
    reports: int = 0
    presses: tuple[int, ...] = ()
    serial: int = 0
    decoder: Any = field(default_factory=LAYOUT.make_decoder)

    def report(self, buttons: int, hat: int = HAT_NULL) -> None:
        self.decoder.feed(StickState(buttons=buttons, hat=hat).report())
        rising = buttons & ~self.buttons
        self.buttons, self.reports = buttons, self.reports + 1
        if rising:
            self.serial += 1
            self.presses = (*self.presses, rising)[-64:]

    def record(self) -> ReaderRecord:
        state = self.decoder.state()
        return ReaderRecord(state, self.reports, 0, 0.0, self.presses, self.serial)


def view_of(reader: Reader, gate: PressGate, binding: DeviceBinding = BINDING) -> DeviceView:
    record = reader.record()
    inputs = binding.apply(record.state)
    return DeviceView(
        1, binding, inputs, True, True, record, (), gate.held_groups, gate.counts_from
    )


EVENTS = st.lists(
    st.one_of(
        st.tuples(st.just("report"), st.integers(0, 7)),  # HID buttons 1-3
        st.tuples(st.just("step"), st.booleans()),  # a node step: is the node live
    ),
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(EVENTS)
def test_a_button_is_pressed_only_after_a_rising_edge_seen_while_live(events: list) -> None:
    """At every live step, a button counts as pressed exactly when it is held and it went
    down in a report after the node's first live step of this run (the reports between two
    steps included: a release and a press between them count)."""
    reader, gate = Reader(), PressGate()
    opened_at: int | None = None  # reports seen when the current live run began
    edges: list[tuple[int, int]] = []  # (report number, rising HID buttons)
    for kind, value in events:
        if kind == "report":
            rising = value & ~reader.buttons
            reader.report(value)
            edges.append((reader.reports, rising))
            continue
        view, _ = gate.step(view_of(reader, gate), value)
        if not value:
            opened_at = None
        elif opened_at is None:
            opened_at = reader.reports
        since = 0
        if opened_at is not None:
            for number, rising in edges:
                if number > opened_at:
                    since |= rising
        if value:  # a node in failsafe presses nothing (its frame's `pressed` is empty)
            assert view.pressed == (reader.buttons & since, 0)
        assert (view.inputs.group1, view.inputs.group2) == (reader.buttons, 0)  # shown held


def test_the_gate_opens_with_one_note_naming_the_held_buttons() -> None:
    reader, gate = Reader(), PressGate()
    reader.report(0b10010)
    _, note = gate.step(view_of(reader, gate), True)
    assert note == "stick: buttons 2, 5 held since the plug: release them first (not a press)"
    _, again = gate.step(view_of(reader, gate), True)
    assert again is None
    gate.step(view_of(reader, gate), False)
    _, after = gate.step(view_of(reader, gate), True)
    assert after is not None and "held since the failsafe" in after


def button_ref(name: str) -> ChannelRef:
    ref = ChannelRef.parse(name)
    assert ref is not None
    return ref


class Stick:
    """A T.16000M on node 0 of a table, with its reader's press log."""

    def __init__(self, table: NodeTable, binding: DeviceBinding = BINDING) -> None:
        self.reader = Reader()
        self.source = RecordSource(self.reader.record())
        self.table = table
        table.add_device(0, INFO, binding, self.source, "JOYSTICK")

    def report(self, buttons: int, hat: int = HAT_NULL) -> None:
        self.reader.report(buttons, hat)
        self.source.record = self.reader.record()


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def live_stick(buttons: int, binding: DeviceBinding = BINDING) -> tuple[NodeTable, Stick, Clock]:
    """A table whose stick was plugged with `buttons` held and went live (it rested)."""
    clock = Clock()
    table = NodeTable(clock=clock)
    stick = Stick(table, binding)
    stick.report(buttons)
    for _ in range(30):
        clock.now += 0.004
        stick.report(buttons)  # the guard: reports at rest for REST_S
        table.step_if_due()
    assert not table.snapshot().frames[0].failsafe
    return table, stick, clock


def step(table: NodeTable, clock: Clock) -> object:
    clock.now += 0.004
    return table.step_if_due().nodes[0]


def test_a_toggle_and_a_latch_held_at_the_plug_do_not_move_until_pressed_again() -> None:
    toggle = SwitchConfig("gear", "toggle", (button_ref("node0.button3"),))
    latch = SwitchConfig("flaps", "latch", (button_ref("node0.button5"),))
    clock = Clock()
    table = NodeTable(clock=clock)
    table.set_controls([toggle, latch], [])
    stick = Stick(table)
    for _ in range(30):
        clock.now += 0.004
        stick.report(0b10100)  # buttons 3 and 5 held from the plug
        table.step_if_due()
    node = table.snapshot().nodes[0]
    assert not node.frame.failsafe and node.frame.group1 == 0b10100  # shown held
    assert dict(table.snapshot().switches) == {"gear": 0, "flaps": 0}
    assert node.frame.pressed_switches == ()
    stick.report(0)
    stick.report(0b10100)  # released and pressed again between two steps
    node = step(table, clock)
    assert dict(table.snapshot().switches) == {"gear": 1, "flaps": 1}
    assert set(node.frame.pressed_switches) == {"gear", "flaps"}


def test_a_trim_button_held_at_the_plug_does_not_step_the_trim() -> None:
    trimmed = bound(
        '    buttons: {"1-10": "1-10"}\n'
        "    axes: {x: {usage: X, trim_switch: {buttons: [11, 12], step: 0.1}}, y: Y, rz: Rz}\n"
    )
    table, stick, clock = live_stick(1 << 11, trimmed)  # "trim up" (12) held from the plug
    for _ in range(5):
        step(table, clock)
    assert table.describe()["0"]["trims"] == {}
    stick.report(0)
    step(table, clock)
    stick.report(1 << 11)
    step(table, clock)
    assert table.describe()["0"]["trims"] == {"x": 0.1}


def test_a_handover_button_held_at_the_plug_asks_for_nothing_until_pressed_again() -> None:
    with_handover = bound("    handover: {button: 4, destination: 9}\n")
    table, stick, clock = live_stick(1 << 3, with_handover)
    assert step(table, clock).frame.handover is None
    stick.report(0)
    stick.report(1 << 3)
    handover = step(table, clock).frame.handover
    assert handover is not None and handover.destination == 9


def test_a_missing_device_that_comes_back_holds_over_what_is_held() -> None:
    clock = Clock()
    entry = ExpectedEntry(BINDING.failsafe(), match="the throttle")
    table = NodeTable({0: {"throttle": entry}}, clock=clock)
    stick = Stick(table)
    for _ in range(30):  # the stick rests; node 0 waits for the throttle
        clock.now += 0.004
        stick.report(0)
        table.step_if_due()
    stick.report(0b10)  # button 2 pressed while node 0 is in failsafe
    node = step(table, clock)
    assert node.frame.failsafe and node.frame.pressed == (0, 0)
    table.rebind(lambda info: None, {})  # the throttle's entry is gone: node 0 goes live
    node = step(table, clock)
    assert not node.frame.failsafe
    assert (node.frame.group1, node.frame.pressed) == (0b10, (0, 0))


def test_a_reload_that_remaps_the_buttons_holds_over_one_that_does_not_keeps_the_press() -> None:
    table, stick, clock = live_stick(0, bound('    buttons: {"1-16": "1-16"}\n'))
    stick.report(0b10)
    assert step(table, clock).frame.pressed == (0b10, 0)
    same = bound('    buttons: {"1-16": "1-16"}\n')
    table.rebind(lambda info: same, {})  # the same map
    assert step(table, clock).frame.pressed == (0b10, 0)
    remapped = bound('    buttons: {"1-8": "1-8", "9-16": "25-32"}\n')
    table.rebind(lambda info: remapped, {})
    node = step(table, clock)
    assert (node.frame.group1 & 0b10, node.frame.pressed) == (0b10, (0, 0))


def test_a_hat_pushed_at_the_plug_moves_no_hat_switch_until_centred_and_pushed_again() -> None:
    """A hat routed to node buttons 41-48 (UP first) feeds a hat switch; pushed UP from the
    plug: shown held, no position; centred and pushed UP again: position 0 -> the push."""
    hat = bound("    hats: [{usage: HatSwitch, to: [41, 42, 43, 44, 45, 46, 47, 48]}]\n")
    view = SwitchConfig(
        "view", "hat_switch", tuple(button_ref(f"node0.button{b}") for b in (41, 45))
    )
    clock = Clock()
    table = NodeTable(clock=clock)
    table.set_controls([view], [])
    stick = Stick(table, hat)
    down = 4  # the T.16000M's hat: 0 UP .. 7 UP-LEFT, 4 DOWN
    for _ in range(30):
        clock.now += 0.004
        stick.report(0, hat=down)
        table.step_if_due()
    node = table.snapshot().nodes[0]
    assert not node.frame.failsafe and node.frame.group2 != 0  # DOWN shown held
    assert dict(table.snapshot().switches) == {"view": 0} and node.frame.pressed == (0, 0)
    stick.report(0)  # centred
    step(table, clock)
    stick.report(0, hat=down)
    node = step(table, clock)
    assert dict(table.snapshot().switches) == {"view": 1}
    assert node.frame.pressed_switches == ("view",)


def test_a_mavlink_action_reads_only_presses_and_switches_a_press_moved() -> None:
    """The MAVLink output's triggers (usb2rc.protocols.mavlink.session.trigger_value): a
    button shown held but held over is not active; a switch at the action's position is
    active only once a press moved it there."""
    from usb2rc.nodes.mapping import ChannelSource
    from usb2rc.nodes.step import NodeFrame
    from usb2rc.protocols.mavlink.session import trigger_value

    button = trigger_value(ChannelSource(0, "button", 2, False, "node0.button2"), None)
    switch = trigger_value(ChannelSource(0, "switch", -1, False, "switch.gear", 0), 32767)
    axes = (0,) * 10
    held_over = NodeFrame(0, False, axes, 0b10, 0, switches=(("gear", 32767),))
    pressed = NodeFrame(
        0,
        False,
        axes,
        0b10,
        0,
        switches=(("gear", 32767),),
        pressed=(0b10, 0),
        pressed_switches=("gear",),
    )
    assert (button({0: held_over}), switch({0: held_over})) == ((False, False), (False, False))
    assert (button({0: pressed}), switch({0: pressed})) == ((True, False), (True, False))
