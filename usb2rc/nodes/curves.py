"""Curves and mixes: the arithmetic of docs/CONFIG.md "Mixes and curves", on values in -1..1.

A source's value x is normalised to -1..1 (`normalised`); a mix line gives
`weight × rate × curve(x) + offset`; the channel is the lines' sum clamped to -1..1, then an
int16 (`to_int16`) that the output's own scale puts on the wire, so a mix is always in range.
"""

from __future__ import annotations

from collections.abc import Sequence

from usb2rc.config.controls_model import Curve
from usb2rc.nodes.scaling import apply_expo

INT16_MIN, INT16_MAX = -32768, 32767


def normalised(value: int) -> float:
    """An int16 onto -1..1 (-32768 and -32767 are both -1)."""
    return max(-1.0, min(1.0, value / INT16_MAX))


def to_int16(x: float) -> int:
    """-1..1 onto the int16 range: -1 is -32768 (the wire's low end), 1 is 32767."""
    if x <= -1.0:
        return INT16_MIN
    return min(INT16_MAX, round(x * INT16_MAX))


def position_value(position: int, positions: int) -> int:
    """A switch's position spread over the int16 range: 2 positions are low and high, 3 are
    low, centre and high, N evenly spaced."""
    if positions < 2:
        return 0
    return round(INT16_MIN + position * (INT16_MAX - INT16_MIN) / (positions - 1))


def points_curve(x: float, points: Sequence[float]) -> float:
    """Linear interpolation through `points`, evenly spaced from x=-1 to x=1."""
    segments = len(points) - 1
    at = (max(-1.0, min(1.0, x)) + 1.0) / 2.0 * segments
    k = min(int(at), segments - 1)
    frac = at - k
    return points[k] + (points[k + 1] - points[k]) * frac


def apply_curve(x: float, curve: Curve | None) -> float:
    if curve is None:
        return x
    if curve.expo is not None:
        return apply_expo(x, curve.expo)
    return points_curve(x, curve.points)


def mix_line(x: float, weight: float, offset: float, curve: Curve | None) -> float:
    return weight * apply_curve(x, curve) + offset


def clamp(x: float) -> float:
    return max(-1.0, min(1.0, x))
