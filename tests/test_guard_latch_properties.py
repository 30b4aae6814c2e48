"""Property tests for the state machines of issue 13: the neutral guard and the tap latch.

Hypothesis drives a NodeTable through random sequences (reports, frames, unplugs, replugs,
two outputs collecting at their own pace) and checks each frame against a small model
written from docs/ICD.md ("Neutral guard", "Taps"), with the wire values from the test
harness's own scaling (daemon_harness.expected_frame), not from the code under test.
"""

from __future__ import annotations

import math
import time

from daemon_harness import (
    T16000M_DESCRIPTOR,
    RecordSource,
    StickState,
    expected_frame,
    stick_record,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from table_reader import TableReader

from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import PRESSES_KEPT, DeviceReader, ReaderRecord
from usb2rc.nodes.binding import default_binding
from usb2rc.nodes.guard import REST_S, GuardedAxis, NeutralGuard
from usb2rc.nodes.table import NodeTable

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)
BINDING = default_binding(LAYOUT, "T.16000M")  # a JOYSTICK: X, Y, Rz guarded at the centre
GUARDED = (0, 1, 6)  # x, y, rz
TOLERANCE = 0.1


def info(key: str) -> DeviceInfo:
    return DeviceInfo(
        key=key, path=key, vid=0x044F, pid=0xB10A, product="T.16000M", port_path="1-1"
    )


def at_rest(state: StickState) -> bool:
    """docs/ICD.md, "Neutral guard": X, Y, Rz within 0.1 of the half range of the centre."""
    axes = expected_frame(state)[0]
    return all(abs((axes[slot] + 32768) * 2 / 65535 - 1) <= TOLERANCE for slot in GUARDED)


# Mostly near the ends and the centre, where the guard decides.
COORD = st.one_of(
    st.sampled_from([0, 16383, 8192, 8191, 7400, 9000, 6000, 10400]),
    st.integers(0, 16383),
)
RZ = st.one_of(st.sampled_from([0, 255, 128, 116, 140]), st.integers(0, 255))
STATES = st.builds(StickState, x=COORD, y=COORD, rz=RZ)
OPS = st.lists(
    st.one_of(
        st.tuples(st.just("report"), STATES),
        st.just(("frame",)),
        st.just(("unplug",)),
        st.just(("replug",)),
    ),
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(OPS)
def test_the_guard_lets_a_device_live_only_after_a_frame_at_rest(ops: list) -> None:
    table = NodeTable()
    plugs = 0
    source = RecordSource(ReaderRecord(LAYOUT.initial_state(), 0))
    table.add_device(0, info("k0"), BINDING, source, "JOYSTICK")
    plugged, state, armed = True, None, False
    held = (0,) * 10  # nothing to hold yet: 0 (docs/ICD.md, "Failsafe")
    for op in ops:
        if op[0] == "report" and plugged:
            state = op[1]
            source.record = stick_record(state)
        elif op[0] == "unplug" and plugged:
            # the unplug takes the device's last values: held if the guard lets them be
            # (armed, or at rest right now), else what was held before stays
            if state is not None and (armed or at_rest(state)):
                held = expected_frame(state)[0]
            table.remove_device(f"k{plugs}")
            plugged, armed = False, False
        elif op[0] == "replug" and not plugged:
            plugs += 1
            source = RecordSource(ReaderRecord(LAYOUT.initial_state(), 0))
            table.add_device(0, info(f"k{plugs}"), BINDING, source, "JOYSTICK")
            plugged, state = True, None
        elif op[0] == "frame":
            frame = table.frames()[0]
            if plugged and state is not None and not armed and at_rest(state):
                armed = True
            assert frame.failsafe == (not armed)
            if armed:
                assert state is not None
                assert (frame.axes, frame.group1) == expected_frame(state)[:2]
            else:
                assert frame.axes == held and frame.group1 == 0


@given(
    st.sampled_from(["centre", "low", "high"]),
    st.floats(0.0, 1.0),
    st.floats(-0.5, 0.5),
    st.integers(-32768, 32767),
)
def test_an_axis_rests_within_its_tolerance_of_its_rest_point(
    arm: str, tolerance: float, trim: float, wire: int
) -> None:
    """`centre` is symmetric around centre + trim, `low` / `high` one-sided; tolerance 1
    accepts the whole centre side, 0 only the point itself."""
    axis = GuardedAxis(0, "X", arm, tolerance, False, trim)
    x = (wire + 32768) * 2 / 65535 - 1
    rest = max(-1.0, min(1.0, {"centre": 0.0, "low": -1.0, "high": 1.0}[arm] + trim))
    expected = {
        "centre": abs(x - rest) <= tolerance,
        "low": x <= rest + tolerance,
        "high": x >= rest - tolerance,
    }[arm]
    assert axis.at_rest(wire) == expected
    guard = NeutralGuard((axis,))
    assert guard.waiting_for([wire] + [None] * 9) == ([] if expected else [f"X {arm}"])


# --- the tap latch --------------------------------------------------------------------------


class NoDevice:
    info = info("tap")


BUTTON_MASKS = st.integers(0, 0xF)  # HID buttons 1-4
TAP_OPS = st.lists(
    st.one_of(
        st.tuples(st.just("report"), BUTTON_MASKS),
        st.tuples(st.just("collect"), st.integers(0, 1)),
    ),
    max_size=60,
)


@settings(max_examples=300, deadline=None)
@given(TAP_OPS)
def test_every_press_shows_in_the_next_frame_of_each_output(ops: list) -> None:
    """Two outputs collect at their own pace; each frame of an output shows the buttons held
    now plus every button pressed (a rising edge) since that output's previous frame, and
    nothing else."""
    reader = DeviceReader(NoDevice(), LAYOUT.make_decoder(), lambda r, c: None)  # type: ignore[arg-type]
    table = NodeTable(clock=lambda: time.monotonic() + REST_S)  # frames after the guard's rest
    outputs = [TableReader(table), TableReader(table)]
    table.add_device(0, NoDevice.info, BINDING, reader, "JOYSTICK")
    buttons = 0
    pressed_since = [0, 0]  # per output: rising edges since its last frame (the model)
    presses_since = [0, 0]
    for op in ops:
        if op[0] == "report":
            rising = op[1] & ~buttons
            buttons = op[1]
            for k in range(2):
                pressed_since[k] |= rising
                presses_since[k] += bool(rising)
            reader._handle(StickState(buttons=buttons).report())
            reader._publish()
        else:
            k = op[1]
            frame = outputs[k].frames()[0]
            if presses_since[k] <= PRESSES_KEPT:  # the press log's bound (docs/ICD.md, "Taps")
                assert frame.group1 & 0xF == buttons | pressed_since[k]
            pressed_since[k], presses_since[k] = 0, 0


# --- trims --------------------------------------------------------------------------------

TRIM_OPS = st.lists(  # fewer presses between two frames than the press log keeps
    st.one_of(st.tuples(st.just("press"), st.sampled_from([1, 2])), st.just(("frame",))),
    max_size=PRESSES_KEPT,
)


@settings(max_examples=200, deadline=None)
@given(TRIM_OPS, st.sampled_from([0.01, 0.05, 0.3]), st.sampled_from([0.0, 0.1, 0.25]))
def test_a_trim_steps_once_per_press_and_never_leaves_its_limit(
    ops: list, step: float, limit: float
) -> None:
    """Button 1 steps down, 2 up; presses between two frames all count (the press log);
    the value is the steps summed and clamped at each step (docs/CONFIG.md, "Trims")."""
    from usb2rc.nodes.trims import TrimSwitch

    switch = TrimSwitch(0, step, limit, minus=1, plus=2)
    binding = default_binding(LAYOUT, "T.16000M")
    binding.trim_switches = (switch,)
    table = NodeTable()
    centred = stick_record(StickState())
    source = RecordSource(centred)
    table.add_device(0, info("k"), binding, source, "JOYSTICK")
    table.frames()  # live: trims step from now on
    presses: tuple[int, ...] = ()
    serial = 0
    model = 0.0
    for op in ops:
        if op[0] == "press":
            serial += 1
            presses = (*presses, 1 << (op[1] - 1))[-PRESSES_KEPT:]
            source.record = ReaderRecord(centred.state, 1 + serial, 0, None, presses, serial)
            model = max(-limit, min(limit, model + (step if op[1] == 2 else -step)))
        else:
            frame = table.frames()[0]
            trim = table.describe()["0"]["trims"].get("x", 0.0)
            assert abs(trim - model) < 1e-6 and abs(trim) <= limit
            offset = math.floor(trim * 32767.5 + 0.5)  # docs/CONFIG.md, "Trims"
            assert frame.axes[0] == expected_frame(StickState())[0][0] + offset
