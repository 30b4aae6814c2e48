"""Properties of the feedback engine over random sources, devices and times: its states
depend only on (now, sources, slots) and the rules' history; a device without outputs gets
no state; every value is within what the device has; nothing changes before
`next_change_at` without new input (the worker may sleep until then)."""

from __future__ import annotations

import copy
import math

from hypothesis import given
from hypothesis import strategies as st

from usb2rc.config.model import FeedbackRule
from usb2rc.configfile import load_config_text
from usb2rc.feedback.engine import DeviceSlot, FeedbackEngine, FeedbackResult, NodeFacts, Sources
from usb2rc.feedback.model import CrsfTelemetry, Downlink, MavlinkTelemetry
from usb2rc.hid.outputs import SIGNED_ANALOG, Capabilities

ENTRIES = """devices:
  - name: pad
    match: {vid: 0x054c}
"""
STEADY = """
  - {when: crsf.link_quality < 50, led: [0, fire], blink: 3}
  - {when: node.waiting, led: 2, rumble: {weak: 0.4}, force: {x: -0.3, y: 0.9}}
  - {when: mavlink.armed, device: pad, color: [255, 128, 0], brightness: 0.7}
  - {when: node1.failsafe, force: {x: 1}}
  - {when: downlink, text: {line: 2, text: "LQ {crsf.link_quality} {mavlink.mode}"}}
  - {when: mavlink.mode == rtl, text: {line: 1, text: "RTL {crsf.battery_voltage:.1f}"}}
"""
PULSES = """
  - {when: crsf.link_quality < 50, rumble: {strong: 1, ms: 300}}
  - {when: node.failsafe, device: pad, rumble: {strong: 0.5, weak: 1, ms: 1200}, led: 1}
"""


def rules(text: str) -> tuple[FeedbackRule, ...]:
    feedback = load_config_text(ENTRIES + "feedback:" + text, "p.yaml").feedback
    assert feedback is not None
    return feedback


STEADY_RULES, PULSE_RULES = rules(STEADY), rules(STEADY + PULSES)

CAPABILITIES = (
    Capabilities(),
    Capabilities(analog=("rumble_strong", "rumble_weak", "red", "green", "blue")),
    Capabilities(indicators=3, indicator_names=("fire", "a", "b")),
    Capabilities(
        indicators=5, analog=("force_x", "force_y", "brightness"), text_lines=3, text_width=8
    ),
)
POOL = tuple(
    DeviceSlot(f"dev{i}", i % 3, "pad" if i % 4 == 1 else None, 0x054C, i, i % 2 == 1, caps)
    for i, caps in enumerate(CAPABILITIES * 2)
)

int16 = st.integers(-32768, 32767)


@st.composite
def inputs(draw: st.DrawFn, now: float) -> tuple[Sources, tuple[DeviceSlot, ...]]:
    """Sources as of `now` (news up to 5 s old, or none) and some of the devices."""
    age = st.floats(0, 5)
    downlinks = tuple(
        Downlink(
            node,
            draw(st.integers(0, 2**64 - 1)),
            tuple(draw(st.lists(int16, min_size=10, max_size=10))),
            now - draw(age),
        )
        for node in draw(st.lists(st.integers(0, 3), max_size=3))
    )
    lq = st.none() | st.integers(0, 100)
    crsf = draw(
        st.none()
        | st.builds(
            CrsfTelemetry,
            link_quality=lq,
            battery_v=st.none() | st.floats(0, 30),
            at=st.just(now - draw(age)),
        )
    )
    mode = st.none() | st.sampled_from(("RTL", "LOITER", "rtl"))
    mavlink = draw(
        st.none()
        | st.builds(
            MavlinkTelemetry,
            armed=st.none() | st.booleans(),
            mode=mode,
            at=st.just(now - draw(age)),
        )
    )
    nodes = tuple(
        NodeFacts(node, draw(st.booleans()), draw(st.booleans()))
        for node in draw(st.lists(st.integers(0, 3), max_size=4, unique=True))
    )
    slots = tuple(draw(st.lists(st.sampled_from(POOL), unique=True, max_size=len(POOL))))
    return Sources(downlinks, crsf, mavlink, nodes), slots


Journey = list[tuple[float, Sources, tuple[DeviceSlot, ...]]]


@st.composite
def journeys(draw: st.DrawFn) -> Journey:
    now = draw(st.floats(0, 1e6))
    steps = []
    for _ in range(draw(st.integers(1, 12))):
        now += draw(st.floats(0, 2))
        steps.append((now, *draw(inputs(now))))
    return steps


def check_within_capabilities(result: FeedbackResult, slots: tuple[DeviceSlot, ...]) -> None:
    by_key = {slot.key: slot for slot in slots}
    assert [key for key, _ in result.states] == [s.key for s in slots if s.capabilities.any]
    for key, state in result.states:
        caps = by_key[key].capabilities
        assert 0 <= state.indicators < 2**caps.indicators
        for name, value in state.analog:
            assert name in caps.analog
            assert (-1.0 if name in SIGNED_ANALOG else 0.0) <= value <= 1.0 and value != 0.0
        assert len(state.texts) <= caps.text_lines
        assert all(len(text) <= caps.text_width for text in state.texts)


@given(journeys())
def test_states_stay_within_what_each_device_has(journey: Journey) -> None:
    engine = FeedbackEngine(PULSE_RULES)
    for now, sources, slots in journey:
        result = engine.step(now, sources, slots)
        check_within_capabilities(result, slots)
        assert result.next_change_at is None or result.next_change_at > now


@given(journeys())
def test_the_same_inputs_give_the_same_results(journey: Journey) -> None:
    first, second = FeedbackEngine(PULSE_RULES), FeedbackEngine(PULSE_RULES)
    for now, sources, slots in journey:
        assert first.step(now, sources, slots) == second.step(now, sources, slots)


@given(journeys())
def test_without_pulses_the_states_depend_on_the_inputs_alone(journey: Journey) -> None:
    running = FeedbackEngine(STEADY_RULES)
    for now, sources, slots in journey:
        result = running.step(now, sources, slots)
        fresh = FeedbackEngine(STEADY_RULES).step(now, sources, slots)
        assert (result.states, result.next_change_at) == (fresh.states, fresh.next_change_at)


@given(journeys(), st.floats(0.0, 1.0, exclude_max=True))
def test_nothing_changes_before_next_change_at(journey: Journey, fraction: float) -> None:
    """Stepped again with the same inputs before next_change_at, the states are the same:
    the worker may sleep until then."""
    engine = FeedbackEngine(PULSE_RULES)
    for now, sources, slots in journey:
        result = engine.step(now, sources, slots)
        until = result.next_change_at if result.next_change_at is not None else now + 60
        probe = copy.deepcopy(engine)
        between = min(now + (until - now) * fraction, math.nextafter(until, now))
        assert probe.step(between, sources, slots).states == result.states
