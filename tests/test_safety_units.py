"""Issue 13 in one process: the sessions' `stopping()`, the new config options and their
errors, trims (stepping, limits, reload, replug), the guard's defaults per device type."""

from __future__ import annotations

import pytest
from daemon_harness import T16000M_DESCRIPTOR, RecordSource, StickState, scale, stick_record

from usb2rc.configfile import ConfigError, load_config_text
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.hid.usages import GD_GAMEPAD, GD_MULTI_AXIS, GD_RZ, GD_X, GD_Z, SIM_THROTTLE
from usb2rc.nodes.binding import DeviceBinding, default_binding
from usb2rc.nodes.guard import default_arm
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import EventKind, NodeFrame, NodeTable, ServiceEvent
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Engine, C2Settings
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.sumd import codec as sumd
from usb2rc.protocols.sumd.session import SumdSession

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)
STICK = DeviceInfo(key="k", path="k", vid=0x044F, pid=0xB10A, product="T.16000M", port_path="1-1")


# --- stopping: the sessions ---------------------------------------------------------------


def live_session(nodes: int, baudrate: int = 115200) -> tuple[C2Engine, list[NodeFrame]]:
    """A C2 session whose nodes are announced and `>` on an open line."""
    session = C2Engine(C2Settings(baudrate=baudrate))
    session.line_opened()
    events = [ServiceEvent(EventKind.CONNECTED, n, STICK, "JOYSTICK") for n in range(nodes)]
    frames = [NodeFrame(n, False, (0,) * 10, 0, 0) for n in range(nodes)]
    for _ in range(40):  # every connect sequence out, every node's `>` on the line
        out = session.tick(events, frames)
        session.wrote(len(out))
        events = []
    return session, frames


def statuses(data: bytes) -> dict[int, int]:
    return {
        f.node_id: f.status for f in c2_16b.Decoder().feed(data) if isinstance(f, c2_16b.DataFrame)
    }


def test_c2_stopping_sends_failsafe_for_every_node_though_the_table_says_live() -> None:
    session, frames = live_session(3)
    assert set(statuses(session.tick([], frames)).values()) == {c2_16b.LIVE}
    session.wrote(0)
    session.line_drained()
    session.stopping()
    assert not session.stop_done
    out = session.tick([], frames)
    assert statuses(out) == dict.fromkeys(range(3), c2_16b.FAILSAFE)
    session.wrote(len(out))
    assert session.stop_done


def test_c2_stopping_with_round_robin_takes_ticks_until_every_node_had_its_failsafe() -> None:
    session, frames = live_session(8, baudrate=57600)  # 3 frames a tick: round-robin
    session.stopping()
    seen: dict[int, int] = {}
    ticks = 0
    while not session.stop_done:
        out = session.tick([], frames)
        session.wrote(len(out))
        seen.update(statuses(out))
        ticks += 1
        assert ticks < 10
    assert seen == dict.fromkeys(range(8), c2_16b.FAILSAFE) and ticks >= 3


def test_c2_stopping_on_a_stalled_or_closed_line_is_done_at_once() -> None:
    session, frames = live_session(2)
    out = session.tick([], frames)
    session.wrote(len(out) // 2)  # the far end stopped reading
    session.stopping()
    assert session.line.stalled and session.stop_done
    closed = C2Engine(C2Settings())
    closed.stopping()
    assert closed.stop_done


def test_sumd_stopping_sets_the_failsafe_bit() -> None:
    session = SumdSession("sumd", OutputChannels([]), sumd.frame_length(2), 100.0)
    session.line_opened()
    assert session.frame([12000, 12000], failsafe=False)[1] == 0x01
    session.wrote(0)
    session.line_drained()
    session.stopping()
    assert not session.stop_done
    frame = session.frame([12000, 12000], failsafe=False)
    assert frame[1] == 0x81
    assert sumd.SumdDecoder().feed(frame)[0].failsafe
    session.wrote(len(frame))
    assert session.stop_done
    stalled = SumdSession("sumd", OutputChannels([]), sumd.frame_length(2), 100.0)
    stalled.line_opened()
    stalled.frame([12000, 12000], failsafe=False)
    stalled.wrote(3)  # the far end stopped reading
    stalled.stopping()
    assert stalled.stalled and stalled.stop_done  # a far end that does not read: no wait


# --- stopping: the table ------------------------------------------------------------------


def test_table_stop_makes_every_node_failsafe_with_its_values_held_and_no_event() -> None:
    table = NodeTable()
    table.add_device(
        0,
        STICK,
        default_binding(LAYOUT, "T.16000M"),
        RecordSource(stick_record(StickState(x=9000, buttons=1))),
        "JOYSTICK",
    )
    cursor = table.step_if_due().log.end
    live = table.frames()[0]
    assert not live.failsafe and live.group1 == 1
    table.stop()
    stopped = table.step_if_due()
    events, frames = stopped.log.since(cursor), stopped.frames
    assert events == ()  # not unplugged: no `2`
    assert frames[0].failsafe and frames[0].axes == live.axes and frames[0].group1 == 0


# --- config -------------------------------------------------------------------------------

STICK_ENTRY = "devices:\n  - match: {vid: 0x044f}\n    axes:\n"


def problems(axes_yaml: str) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config_text(STICK_ENTRY + axes_yaml, "t.yaml")
    return info.value.errors


def test_arm_and_trim_switch_errors_name_the_line_and_key() -> None:
    assert problems("      x: {usage: X, arm: middle}\n") == [
        "t.yaml:4: devices[0].axes.x.arm: 'middle' is not valid "
        "(allowed: centre, center, low, high, any)"
    ]
    assert problems("      x: {usage: X, arm_tolerance: 2}\n") == [
        "t.yaml:4: devices[0].axes.x.arm_tolerance: 2 is out of range (allowed: 0.0..1.0)"
    ]
    [missing] = problems("      x: {usage: X, trim_switch: {step: 0.1}}\n")
    assert "devices[0].axes.x.trim_switch: trim switch missing" in missing
    [both] = problems("      x: {usage: X, trim_switch: {hat: HatSwitch, buttons: [1, 2]}}\n")
    assert "hat and buttons both given" in both
    assert problems("      x: {usage: X, trim_switch: {buttons: [1, 2], stpe: 0.1}}\n") == [
        "t.yaml:4: devices[0].axes.x.trim_switch.stpe: unknown key 'stpe'; did you mean 'step'? "
        "(allowed: hat, axis, occurrence, buttons, step, limit)"
    ]
    [no_axis] = problems("      x: {usage: X, trim_switch: {hat: HatSwitch}}\n")
    assert "trim_switch.axis: missing" in no_axis


def test_trim_switch_hat_missing_from_the_device_is_a_mapping_error() -> None:
    config = load_config_text(
        STICK_ENTRY
        + "      x: {usage: X, trim_switch: {hat: HatSwitch, occurrence: 1, axis: x}}\n",
        "t.yaml",
    )
    with pytest.raises(ValueError, match=r"t\.yaml:4: .*trim switch hat HatSwitch #2 is not in"):
        compile_mapping(config).bind(STICK, LAYOUT)


def test_guard_defaults_by_usage_and_device_type() -> None:
    assert default_arm(GD_X, GD_GAMEPAD) == "centre"
    assert default_arm(GD_RZ, GD_MULTI_AXIS) == "any"  # a space mouse: not a stick
    assert default_arm(GD_Z, GD_GAMEPAD) == "any"
    assert default_arm(SIM_THROTTLE, GD_MULTI_AXIS) == "low"
    assert default_binding(LAYOUT, "t").guard.describe() == "X centre, Y centre, Rz centre"
    config = load_config_text(
        STICK_ENTRY + "      x: X\n      y: {usage: Y, arm: any}\n"
        "      slider: {usage: Slider, arm: high, arm_tolerance: 0.2}\n",
        "t.yaml",
    )
    binding = compile_mapping(config).bind(STICK, LAYOUT)
    assert binding is not None and binding.guard.describe() == "X centre, Slider high"
    assert binding.guard.axes[1].tolerance == 0.2


# --- trims --------------------------------------------------------------------------------

TRIM_ENTRY = """
devices:
  - name: stick
    match: {{vid: 0x044f}}
    node_id: 1
    axes:
      x: {{usage: X, trim_switch: {{buttons: [3, 4], step: 0.05, limit: {limit}}}}}
"""


def trim_binding(limit: float = 0.2) -> DeviceBinding:
    config = load_config_text(TRIM_ENTRY.format(limit=limit), "t.yaml")
    binding = compile_mapping(config).bind(STICK, LAYOUT)
    assert binding is not None
    return binding


class Presses:
    """A reader record source whose buttons are pressed one report at a time."""

    def __init__(self) -> None:
        self.serial = 0
        self.presses: tuple[int, ...] = ()
        self.record = stick_record(StickState())

    def pull(self) -> None:
        """The step's pull: `press` sets the record itself."""

    def press(self, hid_button: int) -> None:
        self.serial += 1
        self.presses = (*self.presses, 1 << (hid_button - 1))
        base = stick_record(StickState())
        self.record = ReaderRecord(base.state, self.serial + 1, 0, None, self.presses, self.serial)


def x_of(table: NodeTable) -> int:
    return next(f for f in table.frames() if f.node_id == 1).axes[0]


def test_trim_steps_per_press_within_its_limit_and_survives_reload_and_replug() -> None:
    binding = trim_binding()
    centre = scale(8192, 0, 16383)
    table = NodeTable()
    source = Presses()
    table.add_device(1, STICK, binding, source, "JOYSTICK")
    assert x_of(table) == centre  # armed: centred
    for _ in range(3):
        source.press(4)  # three taps up between two frames: every one counts
    assert x_of(table) == centre + 4915  # 0.15 of 32767.5
    for _ in range(3):
        source.press(4)
    assert x_of(table) == centre + 6554  # held at the limit, 0.2
    assert table.describe()["1"]["trims"] == {"x": 0.2}
    # a replug: the trim belongs to the node and slot
    table.remove_device(STICK.key)
    again = Presses()
    table.add_device(1, STICK, binding, again, "JOYSTICK")
    assert x_of(table) == centre + 6554
    # a reload with a lower limit clamps it; one without the switch drops it
    tighter = trim_binding(limit=0.1)
    table.rebind(lambda _info: tighter, {})
    assert x_of(table) == centre + 3277
    again.press(3)
    assert x_of(table) == centre + 1638  # one step down: 0.05
    plain = load_config_text(
        "devices:\n  - match: {vid: 0x044f}\n    node_id: 1\n    axes: {x: X}\n", "p.yaml"
    )
    table.rebind(lambda _info: compile_mapping(plain).bind(STICK, LAYOUT), {})
    assert x_of(table) == centre and table.describe()["1"]["trims"] == {}


def test_a_trim_moves_the_rest_point_of_the_guard() -> None:
    """A stick trimmed +0.2 that comes back centred sends +0.2: it rests there."""
    binding = trim_binding()
    table = NodeTable()
    source = Presses()
    table.add_device(1, STICK, binding, source, "JOYSTICK")
    assert not table.frames()[0].failsafe  # live: trims step only now
    for _ in range(4):
        source.press(4)
    assert x_of(table) == scale(8192, 0, 16383) + 6554
    table.remove_device(STICK.key)
    table.add_device(1, STICK, binding, RecordSource(stick_record(StickState())), "JOYSTICK")
    frame = next(f for f in table.frames() if f.node_id == 1)
    assert not frame.failsafe  # centred plus its trim: at rest


# --- the guard: reload, merged nodes -------------------------------------------------------

MERGED = """
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    node_id: 1
    axes: {x: X}
  - name: throttle
    match: {vid: 0x044f, pid: 0xb687}
    node_id: 1
    axes: {slider: {usage: Slider, arm: low}}
"""
THROTTLE = DeviceInfo(key="t", path="t", vid=0x044F, pid=0xB687, product="TWCS", port_path="1-2")


def test_each_device_of_a_merged_node_guards_its_own_axes() -> None:
    mapping = compile_mapping(load_config_text(MERGED, "m.yaml"))
    stick, throttle = (mapping.bind(i, LAYOUT) for i in (STICK, THROTTLE))
    assert stick is not None and throttle is not None
    table = NodeTable()
    # the stick rests, its slider (not guarded: not in its entry) is up; the throttle's is up
    stick_source = RecordSource(stick_record(StickState(slider=255)))
    throttle_source = RecordSource(stick_record(StickState(x=0, slider=255)))
    table.add_device(1, STICK, stick, stick_source, "JOYSTICK")
    table.add_device(1, THROTTLE, throttle, throttle_source, "JOYSTICK")
    assert table.frames()[0].failsafe
    assert table.describe()["1"]["waiting_for"] == ["Slider low (TWCS)"]
    throttle_source.record = stick_record(StickState(x=0, slider=0))  # its X is not its guard
    assert not table.frames()[0].failsafe


def test_a_reload_never_makes_an_armed_device_wait_and_a_waiting_one_takes_the_new_guard() -> None:
    armed_x = "devices:\n  - match: {vid: 0x044f}\n    node_id: 1\n    axes: {x: X}\n"
    any_x = (
        "devices:\n  - match: {vid: 0x044f}\n    node_id: 1\n    axes: {x: {usage: X, arm: any}}\n"
    )
    guarded = compile_mapping(load_config_text(armed_x, "a.yaml")).bind(STICK, LAYOUT)
    free = compile_mapping(load_config_text(any_x, "b.yaml")).bind(STICK, LAYOUT)
    table = NodeTable()
    source = RecordSource(stick_record(StickState()))
    table.add_device(1, STICK, guarded, source, "JOYSTICK")
    assert not table.frames()[0].failsafe
    source.record = stick_record(StickState(x=16383))  # in flight, full right
    table.rebind(lambda _i: guarded, {})
    assert not table.frames()[0].failsafe  # armed stays armed
    # replugged at full right: waits; a reload to `arm: any` lets it go
    table.remove_device(STICK.key)
    table.add_device(1, STICK, guarded, RecordSource(stick_record(StickState(x=16383))), "JOYSTICK")
    assert table.frames()[0].failsafe
    table.rebind(lambda _i: free, {})
    assert not table.frames()[0].failsafe and table.frames()[0].axes[0] == 32767


HAT_TRIM = """
devices:
  - match: {vid: 0x044f}
    node_id: 1
    axes:
      y: {usage: Y, trim_switch: {hat: HatSwitch, axis: y, step: 0.02}}
"""


def test_a_hat_trim_steps_once_per_push() -> None:
    binding = compile_mapping(load_config_text(HAT_TRIM, "h.yaml")).bind(STICK, LAYOUT)
    table = NodeTable()
    source = RecordSource(stick_record(StickState()))
    table.add_device(1, STICK, binding, source, "JOYSTICK")
    centre = scale(8192, 0, 16383)
    assert not table.frames()[0].failsafe  # live: trims step only now
    for hat in (0, 0, 0, 8, 1, 8, 4):  # UP held 3 frames, released, UP-RIGHT, released, DOWN
        source.record = stick_record(StickState(hat=hat))
        table.frames()
    assert table.describe()["1"]["trims"] == {"y": 0.02}  # +1 +1 -1 steps
    assert table.frames()[0].axes[1] == centre + 655  # 0.02 of 32767.5


# --- stopping: the other channel outputs --------------------------------------------------


def test_sbus_and_crsf_stopping_send_their_failsafe() -> None:

    from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
    from usb2rc.protocols.sbus import codec as sbus
    from usb2rc.protocols.sbus.session import SbusSession

    sbus_line = SbusSession("sbus", OutputChannels([]), 100.0)
    sbus_line.line_opened()
    sbus_line.stopping()
    frame = sbus_line.frame([992] * 16, failsafe=False)
    assert sbus.parse_frame(frame).failsafe and sbus.parse_frame(frame).frame_lost
    sbus_line.wrote(len(frame))
    assert sbus_line.stop_done
    crsf_line = CrsfSession("crsf", OutputChannels([]), CrsfModule(0.004))
    crsf_line.line_opened()
    assert crsf_line.frame([992] * 16, failsafe=False)  # live: an RC frame
    crsf_line.wrote(26)
    crsf_line.stopping()
    assert crsf_line.frame([992] * 16, failsafe=False) == b""  # its failsafe is silence
    assert crsf_line.stop_done


def test_mavlink_stopping_releases_the_override_in_one_tick() -> None:

    from usb2rc.config.mavlink import MavlinkOptions
    from usb2rc.protocols.mavlink.codec import MavlinkDecoder
    from usb2rc.protocols.mavlink.session import ControlValues, MavlinkEngine

    session = MavlinkEngine(MavlinkOptions())
    session.line_opened()
    for message in session.tick(0.0, ControlValues(False, channels=(1500,) * 8)):
        session.wrote(len(message))
    session.stopping()
    assert not session.stop_done
    messages = session.tick(0.02, ControlValues(False, channels=(1500,) * 8))
    decoded = MavlinkDecoder().feed(b"".join(messages))
    override = [m for m in decoded if m.get_type() == "RC_CHANNELS_OVERRIDE"]
    assert override and override[-1].chan1_raw == 0  # 0: released to the radio
    for message in messages:
        session.wrote(len(message))
    assert session.stop_done


def test_icd_says_what_each_device_must_rest_at_and_its_trim_switches() -> None:
    from usb2rc.commands import icd

    config = load_config_text(
        TRIM_ENTRY.format(limit=0.2)
        + "      slider: {usage: Slider, arm: low, arm_tolerance: 0.05}\n"
        + "      rz: {usage: Rz, arm: any}\n",
        "t.yaml",
    )
    text = "\n".join(icd.document(config, "markdown"))
    assert (
        "Neutral guard of stick: x centre on a Joystick or Game Pad (±0.1), slider low (±0.05)."
        in text
    )
    assert "Trim switch of x (stick): HID buttons 3 (-) / 4 (+), step 0.05, limit ±0.2." in text
