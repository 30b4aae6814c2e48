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
  other axis (and every hat or button-pair axis) is not guarded (`any`).

Pure functions and frozen values: no clock, no lock, no device.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from usb2rc.hid.usages import GD_GAMEPAD, GD_JOYSTICK, GD_RZ, GD_X, GD_Y, SIM_THROTTLE
from usb2rc.scaling import INT16_MIN, UINT16_MAX

ARM_CHOICES = ("centre", "center", "low", "high", "any")
DEFAULT_TOLERANCE = 0.1  # of the half range: ±5 % of the travel around the rest point
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
        x = wire_to_unit(wire, self.unsigned)
        rest = _clamp(REST_POINT[self.arm] + self.trim + stepped_trim)
        if self.arm == "low":
            return x <= rest + self.tolerance
        if self.arm == "high":
            return x >= rest - self.tolerance
        return abs(x - rest) <= self.tolerance

    def describe(self) -> str:
        return f"{self.label} {self.arm}"


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


NO_GUARD = NeutralGuard()
