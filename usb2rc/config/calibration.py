"""The calibration wizard's logic, sans-IO: raw samples and key presses in, results out.

`usb2rc calibrate` (commands/calibrate.py) owns the terminal, the devices and the file; this
module only decides. For each axis, two steps:

1. range: the user moves the axis through its whole travel; the lowest and highest raw values
   seen become `min` and `max`. Enter goes on once the axis has moved.
2. rest: the user lets go; the median raw value seen becomes `center`, and the spread around
   it the suggested `deadband`. Enter takes it once REST_SAMPLES samples are in; `m` takes the
   midpoint instead (a throttle or slider has no centre to rest on).

Keys, in any step: `s` skips the axis (left as it is), `r` starts it again, `q` quits
without writing. After the last axis a summary: Enter writes, `q` quits.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum

from usb2rc.config.model import Calibration

REST_SAMPLES = 20  # samples at rest before Enter takes the centre (1 s at the 20 Hz view)
MIN_TRAVEL = 0.05  # the axis must move over this fraction of its logical range
DEADBAND_MARGIN = 2.0  # the suggestion is this many times the spread seen at rest
MAX_SUGGESTED_DEADBAND = 0.25  # a spread needing more: the axis was not resting


class Step(Enum):
    RANGE = "range"
    REST = "rest"
    SUMMARY = "summary"
    WRITE = "write"  # finished: write the results
    QUIT = "quit"  # finished: write nothing


@dataclass(frozen=True)
class AxisTarget:
    """One axis to calibrate: where it is in the config and what the device says of it."""

    device: int  # index in the config's devices list
    entry: str  # the entry's name
    slot: str
    source: str  # the usage, "X" or "Slider #2"
    field_index: int  # InputState.values index on the device
    logical_min: int
    logical_max: int
    deadband: float = 0.0  # the axis's deadband now


@dataclass(frozen=True)
class AxisResult:
    target: AxisTarget
    calibration: Calibration
    noise: float  # spread at rest, as a fraction of the half range (0 with `m`)
    suggested_deadband: float  # 0: none

    @property
    def deadband(self) -> float | None:
        """What to write: the suggestion when it is above the axis's deadband, else None
        (a deadband the user chose is never lowered)."""
        return self.suggested_deadband if self.suggested_deadband > self.target.deadband else None


def suggest_deadband(noise: float) -> float:
    """DEADBAND_MARGIN times the spread at rest, rounded up to 0.01."""
    if noise <= 0:
        return 0.0
    return math.ceil(noise * DEADBAND_MARGIN * 100 - 1e-9) / 100


def rest_noise(low: int, high: int, cal: Calibration) -> float:
    """How far from the centre the axis wandered at rest, as `deadband` measures it: a
    fraction of the half range on that side."""
    below = (cal.center - low) / (cal.center - cal.min)
    above = (high - cal.center) / (cal.max - cal.center)
    return max(below, above, 0.0)


@dataclass
class _Seen:
    low: int | None = None
    high: int | None = None
    values: deque[int] = field(default_factory=lambda: deque(maxlen=2000))

    def add(self, value: int, low: int, high: int) -> None:
        self.low = low if self.low is None else min(self.low, low)
        self.high = high if self.high is None else max(self.high, high)
        self.values.append(value)


class Wizard:
    """Feed it `observe()` once per view refresh and `key()` per key press; read `step`,
    `target`, `message` and `results`."""

    def __init__(self, targets: Sequence[AxisTarget]) -> None:
        self.targets = tuple(targets)
        self.results: list[AxisResult] = []
        self.skipped: list[AxisTarget] = []
        self.message = ""
        self._index = 0
        self.step = Step.RANGE if self.targets else Step.SUMMARY
        self.range = _Seen()
        self.rest = _Seen()
        self.value: int | None = None

    @property
    def target(self) -> AxisTarget | None:
        return self.targets[self._index] if self._index < len(self.targets) else None

    @property
    def position(self) -> tuple[int, int]:
        """(this axis's number from 1, how many)."""
        return self._index + 1, len(self.targets)

    @property
    def finished(self) -> bool:
        return self.step in (Step.WRITE, Step.QUIT)

    def observe(self, value: int, low: int | None = None, high: int | None = None) -> None:
        """The axis's raw value now, and the lowest / highest it reported since the last call
        (a quick flick to an end can fall between two refreshes)."""
        self.value = value
        low = value if low is None else min(low, value)
        high = value if high is None else max(high, value)
        if self.step is Step.RANGE:
            self.range.add(value, low, high)
        elif self.step is Step.REST:
            self.rest.add(value, low, high)

    def key(self, key: str) -> None:
        self.message = ""
        if key == "q":
            self.step = Step.QUIT
        elif self.step is Step.SUMMARY:
            if key in ("enter", "w"):
                self.step = Step.WRITE
        elif key == "s":
            assert self.target is not None
            self.skipped.append(self.target)
            self._next()
        elif key == "r":
            self._restart()
        elif key == "enter":
            self._enter()
        elif key == "m" and self.step is Step.REST:
            self._take(midpoint=True)

    # ----------------------------------------------------------------------- steps

    def travel(self) -> float:
        """How much of the logical range the axis has covered in the range step."""
        target = self.target
        if target is None or self.range.low is None or self.range.high is None:
            return 0.0
        span = max(target.logical_max - target.logical_min, 1)
        return (self.range.high - self.range.low) / span

    def _enter(self) -> None:
        if self.step is Step.RANGE:
            if self.travel() < MIN_TRAVEL or self._span() < 2:
                self.message = "move the axis through its whole range first"
                return
            self.step, self.rest = Step.REST, _Seen()
        elif self.step is Step.REST:
            result = self.preview()
            if isinstance(result, str):
                self.message = result
                return
            self.results.append(result)
            self._next()

    def _span(self) -> int:
        if self.range.low is None or self.range.high is None:
            return 0
        return self.range.high - self.range.low

    def preview(self) -> AxisResult | str:
        """What Enter in the rest step would take now, or why it would not."""
        if self.step is not Step.REST:
            return "not resting"
        if len(self.rest.values) < REST_SAMPLES:
            return "let it rest a moment longer"
        return self._result(midpoint=False)

    def _result(self, midpoint: bool) -> AxisResult | str:
        target = self.target
        assert target is not None and self.range.low is not None and self.range.high is not None
        lo, hi = self.range.low, self.range.high
        if midpoint or not self.rest.values:
            center = (lo + hi) // 2
        else:
            center = round(statistics.median(self.rest.values))
        if not lo < center < hi:
            return (
                f"it rests at {center}, an end of its range {lo}..{hi}: "
                "for a throttle or slider press m (midpoint)"
            )
        cal = Calibration(lo, center, hi)
        noise = 0.0
        if not midpoint and self.rest.low is not None and self.rest.high is not None:
            noise = rest_noise(self.rest.low, self.rest.high, cal)
        if noise * DEADBAND_MARGIN > MAX_SUGGESTED_DEADBAND:
            return (
                f"it moved while resting ({noise:.0%} of its half range): let go of it and "
                "press r to start again, or m for the midpoint"
            )
        return AxisResult(target, cal, noise, suggest_deadband(noise))

    def _take(self, midpoint: bool) -> None:
        result = self._result(midpoint)
        if isinstance(result, str):
            self.message = result
            return
        self.results.append(result)
        self._next()

    def _restart(self) -> None:
        if self.step in (Step.RANGE, Step.REST):
            self.step, self.range, self.rest = Step.RANGE, _Seen(), _Seen()

    def _next(self) -> None:
        self._index += 1
        self.value = None  # the next axis's value comes with its first observe()
        self.step = Step.RANGE if self.target is not None else Step.SUMMARY
        self.range, self.rest = _Seen(), _Seen()
