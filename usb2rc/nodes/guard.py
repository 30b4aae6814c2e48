"""The neutral guard: a (re)connected device's node stays `!` until its guarded axes rest.

A stick replugged while held at full deflection, or a throttle that comes back at full, must
not go live at that value (docs/ICD.md, "Neutral guard"). Each device's binding carries a
`NeutralGuard`: the axis slots it guards and where each must rest (`centre`, `low`, `high`),
with a tolerance. The node table asks it, for each value the device would send, which axes are
not at rest yet; once none is, the device is armed for as long as it stays plugged.

Decisions (docs/CONFIG.md, "Neutral guard"):
- the check is on the value as sent (after calibration, deadband, expo, invert and trim): the
  receiver's view, so an inverted throttle is "low" where it sends its minimum;
- a trim (static `trim:` or stepped by a trim switch) moves the rest point with it: a
  centred stick with trim +0.1 sends +0.1 and rests there;
- the tolerance is a fraction of the half range (as `deadband` and `trim` are): `centre`
  means |x - rest| <= tolerance, `low` x <= -1 + tolerance, on x in [-1, 1];
- without `arm:` an axis is guarded when its usage says what it is: X, Y and Rz of a
  JOYSTICK or GAMEPAD rest at the centre, a Simulation Controls Throttle rests low, every
  other axis (and every hat or button-pair axis) is not guarded (`any`); with zero config a
  device in the device database (usb2rc.nodes.known_devices) rests where its entry says;
- the default tolerance depends on the kind of device: a Game Pad's thumb sticks rest
  looser than a joystick's (GAMEPAD_TOLERANCE, the XInput thumb-stick deadzone);
- "at rest" has a time: every guarded axis inside its tolerance AND still (its values span
  at most REST_SPAN) for REST_S. A stick swept through the centre is inside the tolerance
  for a few ticks but never still (`RestWatch`).

The guard itself is frozen values and pure functions; `RestWatch` is the one mutable part,
one per plugged device, owned by the node table (usb2rc.nodes.table) under its lock. It is fed
the time (`now`, and each report's time), so what it decides does not depend on which
output happens to read the node.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from usb2rc.hid.usages import GD_GAMEPAD, GD_JOYSTICK, GD_RZ, GD_X, GD_Y, SIM_THROTTLE
from usb2rc.nodes.scaling import INT16_MAX, INT16_MIN, UINT16_MAX

DEFAULT_TOLERANCE = 0.1  # of the half range: ±5 % of the travel around the rest point
# A Game Pad's thumb sticks rest loose: a DualShock 3 at rest reads X +0.106, Y -0.129. The
# figure is XInput's documented thumb-stick deadzone, XINPUT_GAMEPAD_LEFT_THUMB_DEADZONE
# 7849 of 32767 (docs/CONFIG.md, "Neutral guard").
GAMEPAD_TOLERANCE = 0.24
REST_S = 0.05  # how long every guarded axis must rest (inside its tolerance, and still)
REST_SPAN = 0.05  # "still": the values seen during the rest span at most this (half range)
END_MARGIN = 0.02  # "at an end": within this of -1 or +1 (a fixed axis, a button box)
FIXED_S = 5.0  # unmoved at an end this long since the plug: fixed, not a hand holding it
REST_POINT = {"centre": 0.0, "low": -1.0, "high": 1.0}
SELF_CENTRING = frozenset({GD_X, GD_Y, GD_RZ})
STICK_APPLICATIONS = frozenset({GD_JOYSTICK, GD_GAMEPAD})


def default_arm(usage: int | None, application: int) -> str:
    """Where an axis rests when the config does not say (`any`: not guarded)."""
    if usage == SIM_THROTTLE:
        return "low"
    if usage in SELF_CENTRING and application in STICK_APPLICATIONS:
        return "centre"
    return "any"


def default_tolerance(application: int, kind: str | None = None) -> float:
    """The tolerance of an axis without `arm_tolerance:`: by the device's kind (its entry in
    the device database), else by its top-level collection."""
    if kind == "gamepad" or (kind is None and application == GD_GAMEPAD):
        return GAMEPAD_TOLERANCE
    return DEFAULT_TOLERANCE


def normalize_arm(arm: str) -> str:
    return "centre" if arm == "center" else arm


@dataclass(frozen=True)
class GuardedAxis:
    """One guarded axis slot: where it must rest before its device goes live."""

    slot: int  # 0..9
    label: str  # what feeds it, for "waits for Throttle low": "X", "Throttle", "Slider #2"
    arm: str  # "centre", "low" or "high"
    tolerance: float = DEFAULT_TOLERANCE
    unsigned: bool = False
    trim: float = 0.0  # the static trim of the axis (a stepped trim is passed at check time)

    def at_rest(self, wire: int, stepped_trim: float = 0.0) -> bool:
        if not stepped_trim and (run := self._wire_run) is not None:
            return run[0] <= wire <= run[1]
        return self._unit_at_rest(wire_to_unit(wire, self.unsigned), stepped_trim)

    def _unit_at_rest(self, x: float, stepped_trim: float) -> bool:
        """The rule on the value as a unit (module docstring): what `at_rest` answers."""
        rest = self.rest_point(stepped_trim)
        if self.arm == "low":
            return x <= rest + self.tolerance
        if self.arm == "high":
            return x >= rest - self.tolerance
        return abs(x - rest) <= self.tolerance

    @cached_property
    def _wire_run(self) -> tuple[int, int] | None:
        """The wire values at rest without a stepped trim, as (first, last): `at_rest` as
        two integer comparisons, the step's hot path while a device waits. The unit value
        never decreases as the wire value grows, so the values at rest are one run, found
        by bisection on the rule itself (the same answer at every value, the edges too).
        None when no value is at rest: the rule then answers."""
        low, high = (0, UINT16_MAX) if self.unsigned else (INT16_MIN, INT16_MAX)

        def rests(wire: int) -> bool:
            return self._unit_at_rest(wire_to_unit(wire, self.unsigned), 0.0)

        nearest = round((self.rest_point() + 1.0) * UINT16_MAX / 2.0) + low
        inside = [w for w in (low, high, nearest - 1, nearest, nearest + 1) if low <= w <= high]
        inside = [w for w in inside if rests(w)]
        if not inside:
            return None
        return _first(rests, low, inside[0]), _last(rests, inside[0], high)

    def rest_point(self, stepped_trim: float = 0.0) -> float:
        return _clamp(REST_POINT[self.arm] + self.trim + stepped_trim)

    def describe(self) -> str:
        return self._text

    @cached_property
    def _text(self) -> str:
        """ "X centre": made once, as a waiting device names its axes at every step."""
        return f"{self.label} {self.arm}"


def _first(rests: Callable[[int], bool], low: int, inside: int) -> int:
    """The smallest value in [low, inside] at rest, `inside` being at rest (bisection)."""
    while low < inside:
        mid = (low + inside) // 2
        if rests(mid):
            inside = mid
        else:
            low = mid + 1
    return inside


def _last(rests: Callable[[int], bool], inside: int, high: int) -> int:
    """The largest value in [inside, high] at rest, `inside` being at rest (bisection)."""
    while inside < high:
        mid = (inside + high + 1) // 2
        if rests(mid):
            inside = mid
        else:
            high = mid - 1
    return inside


def wire_to_unit(wire: int, unsigned: bool) -> float:
    """A wire value onto [-1, 1]: the minimum -1, the maximum +1 (0 is ~0 for int16)."""
    offset = 0 if unsigned else INT16_MIN
    return (wire - offset) * 2.0 / UINT16_MAX - 1.0


def _clamp(x: float) -> float:
    return -1.0 if x < -1.0 else 1.0 if x > 1.0 else x


@dataclass(frozen=True)
class NeutralGuard:
    """The guarded axes of one device's binding (empty: the device goes live at once)."""

    axes: tuple[GuardedAxis, ...] = ()

    def waiting_for(
        self, wire_axes: Sequence[int | None], trims: Mapping[int, float] | None = None
    ) -> list[str]:
        """The guarded axes not at rest in `wire_axes` (a NodeInputs' axes), as "X centre"."""
        if not trims:  # the step's hot path while a device waits: two comparisons an axis
            return [
                text
                for slot, first, last, text in self._runs
                if (value := wire_axes[slot]) is not None and not first <= value <= last
            ]
        waiting = []
        for axis in self.axes:
            value = wire_axes[axis.slot]
            stepped = trims.get(axis.slot, 0.0) if trims else 0.0
            if value is not None and not axis.at_rest(value, stepped):
                waiting.append(axis.describe())
        return waiting

    def describe(self) -> str:
        """For `icd`, `monitor` and the log: "X centre, Throttle low" or "none"."""
        return ", ".join(a.describe() for a in self.axes) or "none"

    @property
    def wire_runs(self) -> tuple[tuple[int, int, int, str], ...]:
        """Each guarded axis as (slot, first, last, text): it rests, without a stepped
        trim, when first <= its wire value <= last."""
        return self._runs

    @cached_property
    def _runs(self) -> tuple[tuple[int, int, int, str], ...]:
        """Each axis as (slot, first, last, text): `at_rest` without a stepped trim is
        first <= wire <= last (`GuardedAxis._wire_run`; an axis no value rests at has an
        empty run)."""
        return tuple(
            (axis.slot, *(axis._wire_run or (1, 0)), axis.describe()) for axis in self.axes
        )


NO_GUARD = NeutralGuard()


@dataclass
class RestWatch:
    """Whether a plugged device's guarded axes have rested long enough: one per device, fed
    each reader record once (a reader publishes each as a new object) with the record's
    time, and the time of the frame that reads it.

    Decisions (docs/ICD.md, "Neutral guard"): the rest starts at the first record in which
    every guarded axis is inside its tolerance; a record with one outside, or one that
    widens an axis's span of values beyond REST_SPAN, starts it again. The device arms once
    REST_S has passed since the rest started (a device that sends no report while it rests
    still arms: nothing moved), or when the report that ends a rest comes REST_S after it
    started and every report since was seen (consecutive report counts: nothing moved
    unseen), so a rest is not lost because no frame read the node during it. A centre
    axis that has not changed in the FIXED_S since the plug and sits at an end of its
    travel is `fixed` (a hand holding a stick moves it before then): it names the fix
    (`arm: any`) in what it waits for.
    """

    since: float | None = None  # when the current rest began (a record's time)
    spans: dict[int, tuple[float, float]] = field(default_factory=dict)  # slot -> (lo, hi)
    first: dict[int, int] = field(default_factory=dict)  # slot -> its first value (wire)
    moved: set[int] = field(default_factory=set)  # slots whose value changed since the plug
    # the reader record last taken (each is a new object; compared by identity only). Any:
    # an `object` field with a None default is what the hot path's compiler cannot keep
    record: Any = None
    reports: int = -1  # its report count
    run_since: float | None = None  # start of the rest seen report by report (no gap)
    plugged: float | None = None  # the time of the first frame that read the device
    fixed: bool = False  # a centre axis stuck at an end since the plug (see above)
    waiting: tuple[str, ...] = ()
    # the guard whose every axis is in `moved` (none yet): its records need no more noting
    moved_all_of: NeutralGuard | None = None

    def check(
        self,
        guard: NeutralGuard,
        wire_axes: Sequence[int | None],
        trims: Mapping[int, float] | None,
        record: tuple[object, int, float | None],
        now: float,
    ) -> tuple[str, ...]:
        """What the device still waits for (empty: it has rested): `record` is the reader
        record, its report count and its time; `now` the time of this frame (same clock)."""
        new, reports, at = record
        outside = None  # the guarded axes not at rest in `wire_axes`, once asked
        if self.plugged is None:
            self.plugged = now
        if new is not self.record:
            gapless = reports == self.reports + 1 and at is not None
            run = self.run_since
            if gapless and at is not None and run is not None and at - run >= REST_S:
                self.waiting = ()  # it rested, report after report, before this one
                return self.waiting
            self.record, self.reports = new, reports
            # a record without a time (made by hand: a reader always stamps its records)
            # cannot show how long the device rested: its rest counts as long enough
            taken_at = -math.inf if at is None else at
            outside = self._take(guard, wire_axes, trims, taken_at)
            self._follow_run(gapless, taken_at)
        if self.rested_by(now):
            self.waiting = ()
        elif self.since is not None:
            self.waiting = (f"{_labels(guard)} still for {REST_S:g} s",)
        else:
            if outside is None:
                outside = guard.waiting_for(wire_axes, trims)
            self.waiting = tuple(self._not_at_rest(guard, wire_axes, outside, now))
        return self.waiting

    def rested_by(self, now: float) -> bool:
        """The current rest has lasted REST_S at `now`: the step then arms the device (the
        node table steps at that time, even inside a base period that had its step)."""
        return self.since is not None and now - self.since >= REST_S

    def _take(
        self,
        guard: NeutralGuard,
        wire_axes: Sequence[int | None],
        trims: Mapping[int, float] | None,
        at: float,
    ) -> list[str]:
        """The record's values taken into the rest; the guarded axes not at rest in them."""
        self._note_moves(guard, wire_axes)
        outside = guard.waiting_for(wire_axes, trims)
        if outside:
            self.since, self.spans = None, {}
            return outside
        units = {a.slot: _unit(a, wire_axes) for a in guard.axes}
        spans = {slot: _widen(self.spans.get(slot), x) for slot, x in units.items()}
        if self.since is None or any(hi - lo > REST_SPAN for lo, hi in spans.values()):
            self.since, spans = at, {slot: (x, x) for slot, x in units.items()}
        self.spans = spans
        return outside

    def _follow_run(self, gapless: bool, at: float) -> None:
        """The rest as seen report by report: it goes on while every report is seen, and
        starts again at a report that follows unseen ones (or that starts the rest)."""
        if self.since is None:
            self.run_since = None
        elif not gapless or self.run_since is None or self.since == at:
            self.run_since = at

    def _note_moves(self, guard: NeutralGuard, wire_axes: Sequence[int | None]) -> None:
        if self.moved_all_of is guard:  # `moved` only grows: a moving stick, after its start
            return
        for axis in guard.axes:
            value = wire_axes[axis.slot]
            if value is None:
                continue
            first = self.first.setdefault(axis.slot, value)
            if value != first:
                self.moved.add(axis.slot)
        if self._all_moved(guard):
            self.moved_all_of = guard

    def _not_at_rest(
        self,
        guard: NeutralGuard,
        wire_axes: Sequence[int | None],
        outside: list[str],
        now: float,
    ) -> list[str]:
        """What it waits for: the axes `outside` their rest, and the hint for a fixed one."""
        waiting = list(outside)
        unmoved_s = now - (now if self.plugged is None else self.plugged)
        # not fixed before FIXED_S; after it, not once every guarded axis has moved
        moving = unmoved_s < FIXED_S or self._all_moved(guard)
        fixed = [] if moving else [a.label for a in guard.axes if self._is_fixed(a, wire_axes)]
        self.fixed = bool(fixed)
        if not self.fixed:
            return waiting
        waiting.append(
            f"{', '.join(fixed)} unmoved at an end since plugged: if fixed (no stick), "
            "set `arm: any` for it in a devices: entry"
        )
        return waiting

    def _all_moved(self, guard: NeutralGuard) -> bool:
        return self.moved_all_of is guard or all([a.slot in self.moved for a in guard.axes])

    def _is_fixed(self, axis: GuardedAxis, wire_axes: Sequence[int | None]) -> bool:
        """A centre axis that has not moved since the plug and sits at an end of its travel
        (a button box's axes at 0): it may never rest. Not said of a low/high axis: a
        throttle plugged at full must be pulled back, never unguarded."""
        value = wire_axes[axis.slot]
        if axis.arm != "centre" or value is None or axis.slot in self.moved:
            return False
        return abs(wire_to_unit(value, axis.unsigned)) >= 1.0 - END_MARGIN


def _widen(span: tuple[float, float] | None, x: float) -> tuple[float, float]:
    """The span of an axis's values during the rest, with `x`."""
    return (x, x) if span is None else (min(span[0], x), max(span[1], x))


def _unit(axis: GuardedAxis, wire_axes: Sequence[int | None]) -> float:
    value = wire_axes[axis.slot]
    return 0.0 if value is None else wire_to_unit(value, axis.unsigned)


def _labels(guard: NeutralGuard) -> str:
    return ", ".join(a.label for a in guard.axes)
