"""Axis, hat and button values: the pure arithmetic of the mapping (no config, no device).

Axis scaling (docs/ICD.md, "Axis scaling"): after clamping,
`out = round((v - lo) * 65535 / (hi - lo)) - 32768`, exact in integers (round half to even, as
Python's `round`). With calibration, deadband, expo or trim set, the value goes through a
normalized x in [-1, 1] and back with
`to_wire(x) = floor((x + 1) * 32767.5 + 0.5) - 32768`: -1 → -32768, 0 → 0, +1 → +32767.
`unsigned: true` drops the `- 32768`. docs/CONFIG.md has the full pipeline. usb2rc.nodes.mapping
compiles a config into closures over these. Each protocol's wire values are its own, beside
its codec (`usb2rc.protocols`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from usb2rc.config.layout import GROUP1_BUTTONS, NODE_BUTTONS
from usb2rc.config.model import AxisConfig

INT16_MIN, INT16_MAX, UINT16_MAX = -32768, 32767, 65535


def round_div(num: int, den: int) -> int:
    """round(num / den) in exact integers, halves to even (Python's round); den > 0."""
    q, r = divmod(num, den)
    if 2 * r > den or (2 * r == den and q & 1):
        q += 1
    return q


def scale_linear(v: int, lo: int, hi: int, unsigned: bool = False) -> int:
    """Clamp to [lo, hi], `round((v - lo) * 65535 / (hi - lo)) - 32768`
    (docs/ICD.md, "Axis scaling")."""
    return linear_field(0, lo, hi, unsigned)((v,), 0)


class LinearField:
    """`scale_linear` of field `index` of a decoded state's values (`invert`: of lo + hi -
    value), as one callable of (values, buttons): the node step calls it for every axis of
    every device at every step, so the range is worked out once and the rounding is inline.
    `terms` says what it computes, for a compiled step that computes it without calling it
    (usb2rc.nodes.steady): it returns `round((v' - lo) * 65535 / (hi - lo)) - offset`, v' the
    field clamped to [lo, hi], or lo + hi - it inverted."""

    __slots__ = ("hi", "index", "invert", "lo", "offset", "span", "terms")

    def __init__(self, index: int, lo: int, hi: int, offset: int, invert: bool) -> None:
        self.index, self.lo, self.hi, self.offset, self.invert = index, lo, hi, offset, invert
        self.span = hi - lo
        self.terms = (index, lo, hi, offset, invert)

    def __call__(self, values: Sequence[int], _buttons: int) -> int:
        lo, hi = self.lo, self.hi
        v = lo + hi - values[self.index] if self.invert else values[self.index]
        v = lo if v < lo else hi if v > hi else v
        q, r = divmod((v - lo) * 65535, self.span)  # round_div inline: halves to even
        if 2 * r > self.span or (2 * r == self.span and q & 1):
            q += 1
        return q - self.offset


def linear_field(
    index: int, lo: int, hi: int, unsigned: bool = False, invert: bool = False
) -> Callable[[Sequence[int], int], int]:
    """A `LinearField` of field `index` (a constant, the centre, for an empty range)."""
    if hi <= lo:
        centre = 32768 if unsigned else 0
        return lambda _values, _buttons: centre
    return LinearField(index, lo, hi, 0 if unsigned else 32768, invert)


def linear_terms(fn: Callable[..., int] | None) -> tuple[int, int, int, int, bool] | None:
    """(index, lo, hi, offset, invert) of a `LinearField` (see there), None for any other
    function."""
    return fn.terms if isinstance(fn, LinearField) else None


def to_wire(x: float, unsigned: bool = False) -> int:
    """A normalized x in [-1, 1] (clamped) onto the wire: -1 → -32768, 0 → 0, +1 → 32767."""
    x = -1.0 if x < -1.0 else 1.0 if x > 1.0 else x
    out = math.floor((x + 1.0) * 32767.5 + 0.5)
    return out if unsigned else out - 32768


def normalize(v: int, lo: int, center: float, hi: int) -> float:
    """Raw v onto [-1, 1]: lo → -1, center → 0, hi → +1, linear on each side, clamped."""
    if v <= lo:
        return -1.0
    if v >= hi:
        return 1.0
    if v < center:
        return (v - center) / (center - lo)
    return (v - center) / (hi - center)


def apply_deadband(x: float, deadband: float) -> float:
    """Zero within ±deadband, then rescaled so ±1 stays ±1 (continuous at the edge)."""
    if deadband <= 0.0:
        return x
    if abs(x) <= deadband:
        return 0.0
    return math.copysign((abs(x) - deadband) / (1.0 - deadband), x)


def apply_expo(x: float, expo: float) -> float:
    """Standard RC expo: (1 - e) * x + e * x³."""
    return (1.0 - expo) * x + expo * x * x * x


def shape(x: float, axis: AxisConfig) -> float:
    """Deadband, expo, invert, trim (in that order) on a normalized value."""
    x = apply_expo(apply_deadband(x, axis.deadband), axis.expo)
    if axis.invert:
        x = -x
    x += axis.trim
    return -1.0 if x < -1.0 else 1.0 if x > 1.0 else x


def add_trim(value: int, trim: float, unsigned: bool = False) -> int:
    """A wire value moved by a trim (a fraction of the half range), clamped to the wire
    range: the same offset `shape` adds before `to_wire` (one wire unit = 1/32767.5)."""
    lo, hi = (0, UINT16_MAX) if unsigned else (INT16_MIN, INT16_MAX)
    out = value + math.floor(trim * 32767.5 + 0.5)
    return lo if out < lo else hi if out > hi else out


def hat_direction(v: int, lo: int, hi: int) -> int | None:
    """DESIGN.md: 0 UP, 1 UP-RIGHT, ... 7 UP-LEFT; None when centred (outside [lo, hi])."""
    n = hi - lo + 1
    if n <= 0 or not lo <= v <= hi:
        return None
    angle = (v - lo) * 360 / n
    return round(angle / 45) % 8


def hat_component(direction: int | None, axis: str) -> int:
    """-1, 0 or +1 along x (left/right) or y (down/up) for a hat direction."""
    if direction is None:
        return 0
    if axis == "x":
        return 1 if direction in (1, 2, 3) else -1 if direction in (5, 6, 7) else 0
    return 1 if direction in (7, 0, 1) else -1 if direction in (3, 4, 5) else 0


def node_button_bit(button: int) -> tuple[int, int]:
    """Node button 1..56 → (group 0 or 1, bit)."""
    if not 1 <= button <= NODE_BUTTONS:
        raise ValueError(f"node button {button} is outside 1..{NODE_BUTTONS}")
    return (0, button - 1) if button <= GROUP1_BUTTONS else (1, button - GROUP1_BUTTONS - 1)
