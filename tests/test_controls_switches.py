"""Switches and throttle cuts in the node step (usb2rc.nodes.switches, docs/CONFIG.md
"Switches", "Throttle cut"): each kind from the readers' press logs, failsafe values, the
state kept across a replug and a reload, and the cut that releases only at low throttle."""

from __future__ import annotations

from dataclasses import dataclass

from daemon_harness import T16000M_DESCRIPTOR, RecordSource, StickState
from table_reader import TableReader

from usb2rc.config.controls_model import SwitchConfig, ThrottleCut
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.configfile import ChannelRef
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.nodes.binding import default_binding
from usb2rc.nodes.curves import position_value
from usb2rc.nodes.guard import REST_S
from usb2rc.nodes.step import BASE_PERIOD_S, TableSnapshot
from usb2rc.nodes.table import NodeTable

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)
BINDING = default_binding(LAYOUT, "T.16000M")  # HID button k -> node button k
INFO = DeviceInfo(key="k0", path="k0", vid=0x044F, pid=0xB10A, product="T.16000M", port_path="1-1")
LOW, MID, HIGH = position_value(0, 3), position_value(1, 3), position_value(2, 3)


def button(k: int) -> ChannelRef:
    ref = ChannelRef.parse(f"node0.button{k}")
    assert ref is not None
    return ref


@dataclass
class Clock:
    now: float = 100.0

    def __call__(self) -> float:
        return self.now


class Pilot:
    """A T.16000M on node 0 of a table, pressed and released through its reader's record
    (with its press log, as DeviceReader publishes it)."""

    def __init__(self, switches: list[SwitchConfig], cuts: tuple[ThrottleCut, ...] = ()) -> None:
        self.clock = Clock()
        self.table = NodeTable(clock=self.clock)
        self.table.set_controls(switches, list(cuts))
        self.state = StickState()
        self.reports = 1  # the state is known from the first report
        self.presses: tuple[int, ...] = ()
        self.serial = 0  # the newest press's
        self.source = RecordSource(self._record())
        self.plug()

    def plug(self) -> None:
        self.source = RecordSource(self._record())
        self.table.add_device(0, INFO, BINDING, self.source, "JOYSTICK")
        self.step()  # the rest begins
        self.clock.now += REST_S + BASE_PERIOD_S  # the guard arms
        snapshot = self.step()
        assert not snapshot.frames[0].failsafe, snapshot.nodes[0].waiting_for

    def _record(self) -> ReaderRecord:
        decoder = LAYOUT.make_decoder()
        decoder.feed(self.state.report())
        return ReaderRecord(
            decoder.state(), self.reports, 0, self.clock.now, self.presses, self.serial
        )

    def report(self, **changes: int) -> None:
        before = self.state.buttons
        self.state = StickState(**{**self.state.__dict__, **changes})
        rising = self.state.buttons & ~before
        if rising:
            self.presses, self.serial = (*self.presses, rising)[-32:], self.serial + 1
        self.reports += 1
        self.source.record = self._record()

    def tap(self, k: int) -> None:
        """Button k down and up again, both before the next step."""
        self.report(buttons=self.state.buttons | 1 << (k - 1))
        self.report(buttons=self.state.buttons & ~(1 << (k - 1)))

    def step(self) -> TableSnapshot:
        self.clock.now += BASE_PERIOD_S
        return self.table.step_if_due()

    def switches(self) -> tuple[int, ...]:
        return tuple(value for _, value in self.step().frames[0].switches)


def test_a_toggle_flips_once_per_tap_even_between_steps() -> None:
    pilot = Pilot([SwitchConfig("gear", "toggle", (button(3),))])
    assert pilot.switches() == (position_value(0, 2),)
    pilot.tap(3)
    assert pilot.switches() == (position_value(1, 2),)
    assert pilot.switches() == (position_value(1, 2),)  # no second flip on a later step
    pilot.tap(3)
    pilot.tap(3)  # two taps between two steps: two flips
    assert pilot.switches() == (position_value(1, 2),)
    pilot.tap(3)
    assert pilot.step().switches == (("gear", 0),)


def test_a_latch_is_on_while_held_and_a_tap_shows_for_one_step() -> None:
    pilot = Pilot([SwitchConfig("horn", "latch", (button(2),))])
    pilot.report(buttons=2)
    assert pilot.switches() == (32767,)
    assert pilot.switches() == (32767,)
    pilot.report(buttons=0)
    assert pilot.switches() == (-32768,)
    pilot.tap(2)
    assert [pilot.switches(), pilot.switches()] == [(32767,), (-32768,)]


def test_steps_with_two_buttons_go_down_and_up_without_wrapping() -> None:
    pilot = Pilot([SwitchConfig("mode", "steps", (button(4), button(5)), positions=3)])
    seen = [pilot.switches()[0]]
    for k in (5, 5, 5, 4, 4, 4):
        pilot.tap(k)
        seen.append(pilot.switches()[0])
    assert seen == [LOW, MID, HIGH, HIGH, MID, LOW, LOW]


def test_steps_with_one_button_cycle() -> None:
    pilot = Pilot([SwitchConfig("mode", "steps", (button(4),), positions=3, initial=1)])
    seen = [pilot.switches()[0]]
    for _ in range(3):
        pilot.tap(4)
        seen.append(pilot.switches()[0])
    assert seen == [MID, HIGH, LOW, MID]


def test_a_hat_switch_holds_the_last_direction() -> None:
    """Its buttons are the hat's directions routed to node buttons; here plain buttons."""
    pilot = Pilot([SwitchConfig("view", "hat_switch", (button(6), button(7), button(8)), 3)])
    pilot.report(buttons=1 << 7)  # button 8 held
    assert pilot.switches() == (HIGH,)
    pilot.report(buttons=0)
    assert pilot.switches() == (HIGH,)  # released: held where it was
    pilot.tap(7)
    assert pilot.switches() == (MID,)


def test_a_reset_button_returns_to_initial() -> None:
    switch = SwitchConfig("mode", "steps", (button(4),), positions=3, reset=button(9))
    pilot = Pilot([switch])
    pilot.tap(4)
    pilot.tap(4)
    assert pilot.switches() == (HIGH,)
    pilot.tap(9)
    assert pilot.switches() == (LOW,)


def test_failsafe_sends_the_failsafe_position_and_a_replug_keeps_the_state() -> None:
    gear = SwitchConfig("gear", "toggle", (button(3),), failsafe=1)
    mode = SwitchConfig("mode", "steps", (button(4), button(5)), positions=3)
    pilot = Pilot([gear, mode])
    pilot.tap(5)
    pilot.tap(5)
    assert pilot.switches() == (position_value(0, 2), HIGH)
    pilot.table.remove_device("k0")
    frame = pilot.step().frames[0]
    assert frame.failsafe
    assert frame.switches == (("gear", position_value(1, 2)), ("mode", HIGH))  # failsafe 1; held
    pilot.tap(4)  # pressed while the node is in failsafe: never applied
    pilot.plug()
    assert pilot.switches() == (position_value(0, 2), HIGH)


def test_a_reload_keeps_positions_by_name_and_clamps_to_fewer_positions() -> None:
    mode = SwitchConfig("mode", "steps", (button(4), button(5)), positions=3)
    pilot = Pilot([mode, SwitchConfig("gear", "toggle", (button(3),))])
    pilot.tap(5)
    pilot.tap(5)
    pilot.tap(3)
    assert pilot.switches() == (HIGH, 32767)
    pilot.table.set_controls([SwitchConfig("gear", "toggle", (button(3),)), mode], [])
    assert pilot.switches() == (32767, HIGH)  # same names, new order: same positions
    pilot.table.set_controls([SwitchConfig("mode", "steps", (button(4),), positions=2)], [])
    assert pilot.switches() == (32767,)  # clamped to position 1 of 2
    assert pilot.step().switches == (("mode", 1),)


def test_a_switch_slot_feeds_the_node_axis_and_survives_a_tap_latch() -> None:
    pilot = Pilot([SwitchConfig("gear", "toggle", (button(3),), slot="aux1")])
    output = TableReader(pilot.table)  # an output's own tap latch over the snapshots
    aux1 = AXIS_NAMES.index("aux1")
    pilot.tap(3)
    pilot.tap(1)  # a tap the output's latch recomposes the frame for
    pilot.clock.now += BASE_PERIOD_S
    frame = output.frames()[0]
    assert frame.axes[aux1] == 32767
    assert frame.switches == (("gear", 32767),)


def test_throttle_cut_holds_low_and_releases_only_at_low_throttle() -> None:
    slider = AXIS_NAMES.index("slider")
    cut = ThrottleCut("cut", ChannelRef.axis(0, "slider"))
    pilot = Pilot([SwitchConfig("cut", "toggle", (button(1),))], [cut])
    pilot.report(slider=200)
    live = pilot.step().frames[0].axes[slider]
    pilot.tap(1)  # cut on
    frame = pilot.step().frames[0]
    low = 0 if frame.unsigned_slots >> slider & 1 else -32768
    assert frame.axes[slider] == low != live
    pilot.tap(1)  # cut off, throttle still high: held low
    assert pilot.step().frames[0].axes[slider] == low
    pilot.report(slider=0)  # throttle low: released
    pilot.step()
    pilot.report(slider=120)
    assert pilot.step().frames[0].axes[slider] != low
