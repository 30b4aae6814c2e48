"""`GuardedAxis.at_rest` answers from the wire values at rest (two integer comparisons, the
step's hot path while a device waits): the same answer as the rule on the unit value
(docs/ICD.md, "Neutral guard"), at every wire value, the edges of the run included."""

from __future__ import annotations

import dataclasses

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.nodes.guard import GuardedAxis, NeutralGuard, wire_to_unit
from usb2rc.nodes.scaling import INT16_MAX, INT16_MIN, UINT16_MAX

axes = st.builds(
    GuardedAxis,
    slot=st.just(0),
    label=st.just("X"),
    arm=st.sampled_from(["centre", "low", "high"]),
    tolerance=st.one_of(
        st.sampled_from([0.0, 1e-9, 0.1, 0.24, 1.0, 2.5]),
        st.floats(0.0, 2.5, allow_nan=False),
    ),
    unsigned=st.booleans(),
    trim=st.one_of(st.just(0.0), st.floats(-1.5, 1.5, allow_nan=False)),
)


def by_the_rule(axis: GuardedAxis, wire: int, stepped: float = 0.0) -> bool:
    x = wire_to_unit(wire, axis.unsigned)
    rest = min(
        1.0, max(-1.0, {"centre": 0.0, "low": -1.0, "high": 1.0}[axis.arm] + axis.trim + stepped)
    )
    if axis.arm == "low":
        return x <= rest + axis.tolerance
    if axis.arm == "high":
        return x >= rest - axis.tolerance
    return abs(x - rest) <= axis.tolerance


def wire_range(axis: GuardedAxis) -> tuple[int, int]:
    return (0, UINT16_MAX) if axis.unsigned else (INT16_MIN, INT16_MAX)


@settings(max_examples=400, deadline=None)
@given(axis=axes, data=st.data())
def test_at_rest_is_the_rule_at_any_wire_value(axis: GuardedAxis, data: st.DataObject) -> None:
    low, high = wire_range(axis)
    wires = [low, high, *data.draw(st.lists(st.integers(low, high), max_size=20))]
    run = axis._wire_run
    if run is not None:  # the run's edges and their neighbours
        wires += [w for w in (run[0] - 1, run[0], run[1], run[1] + 1) if low <= w <= high]
    for wire in wires:
        assert axis.at_rest(wire) == by_the_rule(axis, wire), (axis, wire, run)


@settings(max_examples=100, deadline=None)
@given(axis=axes, stepped=st.floats(-0.5, 0.5, allow_nan=False), data=st.data())
def test_a_stepped_trim_moves_the_rest_as_the_rule_says(
    axis: GuardedAxis, stepped: float, data: st.DataObject
) -> None:
    low, high = wire_range(axis)
    for wire in data.draw(st.lists(st.integers(low, high), min_size=1, max_size=20)):
        assert axis.at_rest(wire, stepped) == by_the_rule(axis, wire, stepped)


def test_the_run_of_a_centred_stick_is_its_tolerance_around_zero() -> None:
    axis = GuardedAxis(0, "X", "centre", 0.1)
    first, last = axis._wire_run or (0, 0)
    assert axis.at_rest(first) and axis.at_rest(last)
    assert not axis.at_rest(first - 1) and not axis.at_rest(last + 1)
    assert abs(first + 3277) <= 2 and abs(last - 3276) <= 2  # ±0.1 of the half range


@settings(max_examples=300, deadline=None)
@given(
    guarded=st.lists(axes, min_size=1, max_size=4),
    data=st.data(),
)
def test_a_guards_waiting_axes_are_those_the_rule_finds_off_their_rest(
    guarded: list[GuardedAxis], data: st.DataObject
) -> None:
    """`NeutralGuard.waiting_for` without a stepped trim (its runs of wire values, the
    step's hot path) names the axes the rule finds off their rest, in the guard's order; an
    axis with no value (None) waits for nothing."""
    guard = NeutralGuard(tuple(dataclasses.replace(axis, slot=k) for k, axis in enumerate(guarded)))
    for _ in range(5):
        wire_axes: list[int | None] = [
            data.draw(st.none() | st.integers(*wire_range(axis))) for axis in guard.axes
        ]
        wire_axes += [None] * (10 - len(wire_axes))
        want = [
            axis.describe()
            for axis in guard.axes
            if (wire := wire_axes[axis.slot]) is not None and not by_the_rule(axis, wire)
        ]
        assert guard.waiting_for(wire_axes) == want
        assert guard.waiting_for(wire_axes, {}) == want
