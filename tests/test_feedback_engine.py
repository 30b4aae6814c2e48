"""The feedback engine (docs/CONFIG.md, "Feedback"): layering, blinking, pulses on an edge
only, staleness, the zero-config rule and the downlink across a node's devices."""

from __future__ import annotations

import math

import pytest

from usb2rc.config.model import FeedbackRule
from usb2rc.configfile import load_config_text
from usb2rc.feedback.engine import (
    DOWNLINK_STALE_S,
    TELEMETRY_STALE_S,
    DeviceSlot,
    FeedbackEngine,
    FeedbackResult,
    NodeFacts,
    Sources,
    blink_phase,
    telemetry_values,
)
from usb2rc.feedback.model import CrsfTelemetry, Downlink, MavlinkTelemetry
from usb2rc.hid.outputs import ANALOG_NAMES, REST, Capabilities, OutputState

PAD_CAPS = Capabilities(
    indicators=0,
    analog=("rumble_strong", "rumble_weak", "red", "green", "blue", "brightness"),
)
STICK_CAPS = Capabilities(indicators=3, indicator_names=("fire", "LED Num Lock", "mode"))
MFD_CAPS = Capabilities(
    indicators=2,
    indicator_names=("fire", "throttle"),
    analog=("brightness", "force_x", "force_y"),
    text_lines=3,
    text_width=16,
)
PAD = DeviceSlot("pad-1", 0, "pad", 0x054C, 0x09CC, True, PAD_CAPS)
STICK = DeviceSlot("stick-1", 0, "stick", 0x044F, 0xB10A, False, STICK_CAPS)
MFD = DeviceSlot("x52-1", 1, None, 0x06A3, 0x0762, False, MFD_CAPS)
MOUSE = DeviceSlot("plain-1", 0, None, 0x1234, 0x5678, False, Capabilities())

ENTRIES = """devices:
  - name: pad
    match: {vid: 0x054c}
  - name: stick
    match: {vid: 0x044f}
"""


def rules(feedback: str) -> tuple[FeedbackRule, ...]:
    config = load_config_text(ENTRIES + "feedback:\n" + feedback, "fb.yaml")
    assert config.feedback is not None
    return config.feedback


def engine(feedback: str) -> FeedbackEngine:
    return FeedbackEngine(rules(feedback))


def states(result: FeedbackResult) -> dict[str, OutputState]:
    return dict(result.states)


def crsf(lq: int, at: float) -> Sources:
    return Sources(crsf=CrsfTelemetry(link_quality=lq, at=at))


def downlink(node: int, at: float, indicators: int = 0, axes: tuple[int, ...] = ()) -> Downlink:
    return Downlink(node, indicators, axes + (0,) * (10 - len(axes)), at)


# --------------------------------------------------------------------------- downlink layer


def test_the_downlink_lights_a_nodes_indicators_across_its_devices_in_order() -> None:
    node0_second = DeviceSlot("stick-2", 0, None, 0x044F, 0xB10A, False, STICK_CAPS)
    slots = (PAD, STICK, MOUSE, node0_second, MFD)
    frame = downlink(0, 10.0, indicators=0b101_110)  # bits 0..2: STICK, 3..5: the second
    result = FeedbackEngine(()).step(10.2, Sources(downlinks=(frame,)), slots)
    got = states(result)
    assert set(got) == {"pad-1", "stick-1", "stick-2", "x52-1"}  # the mouse has no outputs
    assert got["stick-1"].indicators == 0b110 and got["stick-2"].indicators == 0b101
    assert got["pad-1"] == REST and got["x52-1"] == REST  # node 1 has no downlink
    assert result.next_change_at == pytest.approx(10.0 + DOWNLINK_STALE_S)


def test_the_downlink_axes_drive_the_analog_outputs_in_order() -> None:
    # rumble_strong, rumble_weak, force_x, force_y, brightness, red, green, blue
    axes = (32767, -5, -32768, 16384, 16384, 32767, 0, 8192)
    slots = (PAD, MFD)
    sources = Sources(downlinks=(downlink(0, 5.0, axes=axes), downlink(1, 5.0, axes=axes)))
    got = states(FeedbackEngine(()).step(5.0, sources, slots))
    assert dict(got["pad-1"].analog) == pytest.approx(
        {"rumble_strong": 1.0, "brightness": 0.5, "red": 1.0, "blue": 0.25}, abs=1e-4
    )
    assert dict(got["x52-1"].analog) == pytest.approx(
        {"force_x": -1.0, "force_y": 0.5, "brightness": 0.5}, abs=1e-4
    )


def test_a_stale_downlink_returns_the_outputs_to_rest_after_1_s() -> None:
    fb = FeedbackEngine(())
    sources = Sources(downlinks=(downlink(0, 100.0, indicators=0b1, axes=(32767,)),))
    fresh = fb.step(100.0 + DOWNLINK_STALE_S - 0.001, sources, (PAD, STICK))
    assert states(fresh)["stick-1"].indicators == 1 and states(fresh)["pad-1"].value(
        "rumble_strong"
    ) == pytest.approx(1.0)
    assert fresh.next_change_at == pytest.approx(100.0 + DOWNLINK_STALE_S)
    stale = fb.step(100.0 + DOWNLINK_STALE_S, sources, (PAD, STICK))
    assert states(stale) == {"pad-1": REST, "stick-1": REST}
    assert stale.next_change_at is None


def test_the_newest_downlink_of_a_node_counts() -> None:
    frames = (downlink(0, 9.5, indicators=0b1), downlink(0, 9.9, indicators=0b10))
    got = states(FeedbackEngine(()).step(10.0, Sources(downlinks=frames), (STICK,)))
    assert got["stick-1"].indicators == 0b10


# --------------------------------------------------------------------------- layering


def test_layering_indicators_ored_analog_max_forces_and_texts_the_last_rules() -> None:
    fb = engine(
        "  - {when: downlink, led: fire, rumble: {strong: 0.25}, force: {x: 0.5}}\n"
        "  - {led: 1, rumble: {strong: 0.75, weak: 0.1}, force: {y: -0.5}, brightness: 0.2}\n"
        "  - {text: {line: 1, text: first}}\n"
        "  - {text: {line: 1, text: second}, color: [255, 0, 0]}\n"
        "  - {text: {line: 3, text: third}, color: [0, 51, 0]}\n"
    )
    axes = (8192, 16384, 32767, 32767, 32767)  # strong .25, weak .5, forces 1, brightness 1
    sources = Sources(downlinks=(downlink(0, 0.0, 0b100, axes), downlink(1, 0.0, 0, axes)))
    got = states(fb.step(0.5, sources, (PAD, STICK, MFD)))
    assert got["stick-1"].indicators == 0b111  # downlink bit 2, fire (0), led 1
    pad = dict(got["pad-1"].analog)
    assert pad == pytest.approx(
        {"rumble_strong": 0.75, "rumble_weak": 0.5, "brightness": 1.0, "red": 1.0, "green": 0.2},
        abs=1e-4,
    )
    mfd = got["x52-1"]
    assert mfd.indicators == 0b11  # fire and led 1; the downlink of node 1 lights none
    assert mfd.value("force_x") == 0.0 and mfd.value("force_y") == -0.5  # the last rule's
    assert mfd.texts == ("second", "", "third")


def test_a_rule_drives_only_its_device_and_only_what_it_has() -> None:
    fb = engine(
        "  - {device: stick, led: [mode, 0, LED NUM LOCK, nothere, 40]}\n"
        '  - {device: "06a3:0762", text: {line: 4, text: "no such line"}, brightness: 1}\n'
        '  - {device: "06a3:0762", text: {line: 2, text: "a line longer than sixteen"}}\n'
    )
    got = states(fb.step(0.0, Sources(), (PAD, STICK, MFD, MOUSE)))
    assert got["stick-1"].indicators == 0b111 and got["pad-1"] == REST
    assert got["x52-1"] == OutputState(0, (("brightness", 1.0),), ("", "a line longer th"))
    assert "plain-1" not in got


# --------------------------------------------------------------------------- blink


def test_blinking_follows_the_clock_so_every_device_blinks_together() -> None:
    other = DeviceSlot("stick-2", 3, "stick", 0x044F, 0xB10A, False, STICK_CAPS)
    fb = engine("  - {when: crsf.link_quality < 50, led: 0, blink: 2}\n")
    sources = crsf(20, 10.0)
    seen = []
    for now in (10.0, 10.1, 10.25, 10.3, 10.5, 10.74):
        result = fb.step(now, sources, (STICK, other))
        lit = {key: state.indicators for key, state in result.states}
        assert lit["stick-1"] == lit["stick-2"]
        seen.append((lit["stick-1"], result.next_change_at))
    assert seen == [
        (1, pytest.approx(10.25)),
        (1, pytest.approx(10.25)),
        (0, pytest.approx(10.5)),
        (0, pytest.approx(10.5)),
        (1, pytest.approx(10.75)),
        (1, pytest.approx(10.75)),
    ]


def test_the_next_change_is_always_after_now_at_a_blink_boundary() -> None:
    fb = engine("  - {led: 0, blink: 3}\n")
    now = 1 / 6 * 7  # a boundary, as the worker would wake at
    for _ in range(20):
        result = fb.step(now, Sources(), (STICK,))
        assert result.next_change_at is not None and result.next_change_at > now
        now = result.next_change_at


def test_a_blink_changes_only_at_the_moment_it_announced() -> None:
    """Just before a boundary, now / half-period may round up to the next half: the phase
    must still be the one that ends at the announced change."""
    half_period = 0.5 / 3.0
    boundary = 196608 * half_period
    before = math.nextafter(boundary, 0)
    assert math.floor(before / half_period) == 196608  # the division rounds across it
    lit_before, change = blink_phase(before, 3.0)
    assert change == boundary and (lit_before, blink_phase(boundary, 3.0)[0]) == (False, True)


# --------------------------------------------------------------------------- pulses


LQ_PULSE = (
    "  - {when: crsf.link_quality < 50, device: pad, rumble: {strong: 1, weak: 0.5, ms: 300}}\n"
)


def test_a_pulse_starts_on_a_rising_edge_only() -> None:
    fb = engine(LQ_PULSE)
    assert states(fb.step(0.0, crsf(90, 0.0), (PAD,)))["pad-1"] == REST
    edge = fb.step(1.0, crsf(30, 1.0), (PAD,))
    assert states(edge)["pad-1"].value("rumble_strong") == 1.0
    assert states(edge)["pad-1"].value("rumble_weak") == 0.5
    assert edge.next_change_at == pytest.approx(1.3)
    assert edge.actions[0].text == "rumble pulse 300 ms on pad" and edge.actions[0].at == 1.0
    held = fb.step(1.2, crsf(20, 1.2), (PAD,))
    assert states(held)["pad-1"].value("rumble_strong") == 1.0
    over = fb.step(1.3, crsf(20, 1.3), (PAD,))  # the condition holds on: no new pulse
    assert states(over)["pad-1"] == REST
    assert fb.step(2.0, crsf(80, 2.0), (PAD,)).states[0][1] == REST
    again = fb.step(3.0, crsf(40, 3.0), (PAD,))
    assert states(again)["pad-1"].value("rumble_strong") == 1.0


def test_a_condition_true_at_the_first_step_is_no_edge() -> None:
    fb = engine(LQ_PULSE)
    assert states(fb.step(0.0, crsf(30, 0.0), (PAD,)))["pad-1"] == REST
    assert states(fb.step(0.1, crsf(30, 0.1), (PAD,)))["pad-1"] == REST


def test_a_device_plugged_while_the_condition_holds_does_not_pulse() -> None:
    fb = engine("  - {when: crsf.link_quality < 50, rumble: {strong: 1, ms: 300}}\n")
    other = DeviceSlot("pad-2", 1, None, 0x054C, 0x0CE6, True, PAD_CAPS)
    fb.step(0.0, crsf(90, 0.0), (PAD,))
    fb.step(1.0, crsf(30, 1.0), (PAD,))  # pad-1 pulses until 1.3
    got = states(fb.step(1.1, crsf(30, 1.1), (PAD, other)))
    assert got["pad-1"].value("rumble_strong") == 1.0 and got["pad-2"] == REST


def test_unplugged_and_plugged_again_is_a_new_device() -> None:
    fb = engine(LQ_PULSE)
    fb.step(0.0, crsf(90, 0.0), (PAD,))
    fb.step(0.5, crsf(90, 0.5), ())
    assert states(fb.step(1.0, crsf(30, 1.0), (PAD,)))["pad-1"] == REST


# --------------------------------------------------------------------------- telemetry


def test_stale_telemetry_makes_a_condition_false_and_a_field_unknown() -> None:
    fb = engine(
        "  - {when: crsf.link_quality < 50, led: 0}\n"
        '  - {device: "06a3:0762", text: {line: 1, text: "LQ {crsf.link_quality}%"}}\n'
    )
    slots = (STICK, MFD)
    fresh = fb.step(10.0 + TELEMETRY_STALE_S - 0.01, crsf(20, 10.0), slots)
    assert states(fresh)["stick-1"].indicators == 1
    assert states(fresh)["x52-1"].texts == ("LQ 20%",)
    assert fresh.next_change_at == pytest.approx(10.0 + TELEMETRY_STALE_S)
    stale = fb.step(10.0 + TELEMETRY_STALE_S, crsf(20, 10.0), slots)
    assert states(stale)["stick-1"].indicators == 0
    assert states(stale)["x52-1"].texts == ("LQ --%",)
    assert stale.next_change_at is None
    assert stale.actions[0].text == "ended on stick, 06a3:0762"  # every device with a led


def test_a_pulse_after_unknown_telemetry_comes_back_low() -> None:
    fb = engine(LQ_PULSE)
    fb.step(0.0, crsf(90, 0.0), (PAD,))
    fb.step(5.0, crsf(90, 0.0), (PAD,))  # stale: unknown
    assert states(fb.step(6.0, crsf(30, 6.0), (PAD,)))["pad-1"].value("rumble_strong") == 1.0


def test_conditions_on_each_kind_of_source() -> None:
    fb = engine(
        "  - {when: mavlink.armed, led: 0}\n"
        "  - {when: mavlink.mode == loiter, led: 1}\n"
        "  - {when: mavlink.battery_voltage <= 10.5, led: 2}\n"
        '  - {device: "06a3:0762", text: {line: 1, text: "{mavlink.mode} {mavlink.armed}'
        ' {mavlink.battery_voltage:.1f}V"}}\n'
        '  - {device: "06a3:0762", text: {line: 2, text: "{mavlink.battery_remaining}%"}}\n'
    )
    vehicle = MavlinkTelemetry(armed=True, mode="LOITER", battery_v=10.5, at=1.0)
    got = states(fb.step(1.0, Sources(mavlink=vehicle), (STICK, MFD)))
    assert got["stick-1"].indicators == 0b111 and got["x52-1"].indicators == 0b11
    assert got["x52-1"].texts == ("LOITER yes 10.5V", "--%")
    vehicle = vehicle._replace(armed=False, mode="RTL", battery_v=12.6)
    assert states(fb.step(1.5, Sources(mavlink=vehicle), (STICK,)))["stick-1"] == REST


def test_node_sources_the_devices_own_node_and_a_named_one() -> None:
    fb = engine("  - {when: node.waiting, led: 0}\n  - {when: node1.failsafe, led: 1}\n")
    other = DeviceSlot("stick-2", 1, None, 0x044F, 0xB10A, False, STICK_CAPS)
    nodes = (NodeFacts(0, False, True), NodeFacts(1, True, False))
    got = states(fb.step(0.0, Sources(nodes=nodes), (STICK, other)))
    assert got["stick-1"].indicators == 0b11 and got["stick-2"].indicators == 0b10


# --------------------------------------------------------------------------- zero config


def test_zero_config_pulses_the_gamepads_rumble_once_per_failsafe_entry() -> None:
    fb = FeedbackEngine(None)
    slots = (PAD, STICK)

    def step(now: float, failsafe: bool) -> FeedbackResult:
        return fb.step(now, Sources(nodes=(NodeFacts(0, failsafe, False),)), slots)

    plugged = step(0.0, True)  # a node is in failsafe when its device plugs: no entry
    assert states(plugged)["pad-1"] == REST
    assert states(step(1.0, False))["pad-1"] == REST
    entry = step(2.0, True)
    assert states(entry)["pad-1"].analog == (("rumble_strong", 1.0), ("rumble_weak", 1.0))
    assert states(entry)["stick-1"] == REST  # not a gamepad
    assert entry.next_change_at == pytest.approx(2.3)
    assert entry.actions[0].text == "rumble pulse 300 ms on pad"
    assert states(step(2.29, True))["pad-1"].value("rumble_weak") == 1.0
    assert states(step(2.3, True))["pad-1"] == REST  # once, however long the failsafe lasts
    assert states(step(10.0, True))["pad-1"] == REST
    step(11.0, False)
    assert states(step(12.0, True))["pad-1"].value("rumble_strong") == 1.0  # a new entry


def test_a_feedback_key_replaces_the_zero_config_rule() -> None:
    fb = FeedbackEngine(())
    fb.step(0.0, Sources(nodes=(NodeFacts(0, False, False),)), (PAD,))
    entry = fb.step(1.0, Sources(nodes=(NodeFacts(0, True, False),)), (PAD,))
    assert states(entry)["pad-1"] == REST and entry.actions == ()


def test_a_node_unknown_at_the_first_step_enters_nothing_when_it_appears_in_failsafe() -> None:
    fb = FeedbackEngine(None)
    fb.step(0.0, Sources(), (PAD,))  # the node not in the snapshot yet: unknown
    got = fb.step(0.1, Sources(nodes=(NodeFacts(0, True, False),)), (PAD,))
    assert states(got)["pad-1"] == REST


# --------------------------------------------------------------------------- for monitor


def test_telemetry_values_are_flat_with_ages_and_unknown_when_stale() -> None:
    sources = Sources(
        downlinks=(downlink(2, 9.5),),
        crsf=CrsfTelemetry(link_quality=87, rssi_dbm=-70, flight_mode="ACRO", at=9.0),
        mavlink=MavlinkTelemetry(armed=True, mode="LOITER", at=5.0),
        nodes=(NodeFacts(2, False, True),),
    )
    values = telemetry_values(10.0, sources)
    assert values["crsf.link_quality"] == 87 and values["crsf.rssi"] == -70
    assert values["crsf.flight_mode"] == "ACRO" and values["crsf.battery_voltage"] is None
    assert values["crsf.age"] == pytest.approx(1.0)
    assert values["mavlink.armed"] is None and values["mavlink.age"] == pytest.approx(5.0)
    assert values["node2.waiting"] is True and values["node2.failsafe"] is False
    assert values["node2.downlink"] is True and values["node2.downlink_age"] == pytest.approx(0.5)
    assert telemetry_values(0.0, Sources())["crsf.age"] is None


def test_each_rules_last_action_for_the_monitor() -> None:
    fb = engine(
        "  - {when: downlink, led: 0, blink: 2}\n"
        '  - {device: "06a3:0762", text: {line: 1, text: hi}, brightness: 0.5}\n'
    )
    first = fb.step(3.0, Sources(downlinks=(downlink(0, 3.0),)), (STICK, MFD))
    assert [(a.rule, a.text, a.at) for a in first.actions] == [
        (0, "led 0 blink 2 Hz on stick", 3.0),
        (1, "brightness 0.5, text line 1 on 06a3:0762", 3.0),
    ]
    later = fb.step(4.5, Sources(downlinks=(downlink(0, 3.0),)), (STICK, MFD))
    assert later.actions[0] == first.actions[0]._replace(text="ended on stick", at=4.5)
    assert later.actions[1] == first.actions[1]


def test_every_analog_output_name_is_known() -> None:
    for caps in (PAD_CAPS, MFD_CAPS):
        assert set(caps.analog) <= set(ANALOG_NAMES)
