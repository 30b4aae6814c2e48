"""Trims stepped by a hat or a button pair, as every RC transmitter offers (docs/CONFIG.md,
"Trims").

A `TrimSwitch` (compiled into a device's binding from an axis's `trim_switch:`) says which
hat axis or button pair steps which axis slot, by how much and up to which limit. The values
live in a `TrimStore` owned by the node table, keyed by (node, slot), so a trim survives a
config reload (clamped to the new limit) and a replug (the device comes back on its node);
it is not saved across a restart. Pure values and arithmetic: the node table calls them
under its lock.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from usb2rc.config.layout import AXIS_NAMES
from usb2rc.hid.descriptor import InputState
from usb2rc.nodes.scaling import hat_component, hat_direction


@dataclass(frozen=True)
class TrimSwitch:
    """One axis slot's trim switch: a button pair (HID masks) or one axis of a hat."""

    slot: int  # the axis slot it trims, 0..9
    step: float  # per press, a fraction of the half range
    limit: float  # the trim stays within ±limit
    minus: int = 0  # HID button mask that steps down (button pair)
    plus: int = 0  # ... and up
    hat_index: int = -1  # InputState.values index of the hat (hat switch), else -1
    hat_lo: int = 0
    hat_hi: int = -1
    hat_axis: str = "x"

    def position(self, state: InputState) -> int:
        """-1, 0 or +1: where the switch is held now."""
        if self.hat_index >= 0:
            direction = hat_direction(state.values[self.hat_index], self.hat_lo, self.hat_hi)
            return hat_component(direction, self.hat_axis)
        return bool(state.buttons & self.plus) - bool(state.buttons & self.minus)

    def presses(self, rising: Iterable[int]) -> list[int]:
        """The steps of button presses (the reader's rising-edge masks, in order): +1 per
        plus press, -1 per minus press. Every press counts, even a tap between two ticks."""
        steps = (bool(mask & self.plus) - bool(mask & self.minus) for mask in rising)
        return [step for step in steps if step]


def stepped(value: float, steps: int, switch: TrimSwitch) -> float:
    """value + steps * step, within ±limit, rounded to a millionth (no float drift after
    many steps: twenty steps of 0.01 are 0.2 exactly)."""
    result = value + steps * switch.step
    return round(max(-switch.limit, min(switch.limit, result)), 6)


class TrimStore:
    """The stepped trims of every node's axis slots: (node, slot) -> fraction of the half
    range. Owned by the node table (used under its lock)."""

    def __init__(self) -> None:
        self.values: dict[tuple[int, int], float] = {}

    def of_node(self, node_id: int) -> dict[int, float]:
        return {slot: v for (node, slot), v in self.values.items() if node == node_id and v}

    def of_switches(self, node_id: int, switches: Iterable[TrimSwitch]) -> dict[int, float] | None:
        """The non-zero trims of these switches' slots on the node (None: none)."""
        found = {s.slot: v for s in switches if (v := self.values.get((node_id, s.slot)))}
        return found or None

    def step(self, node_id: int, switch: TrimSwitch, steps: int) -> float:
        key = (node_id, switch.slot)
        value = stepped(self.values.get(key, 0.0), steps, switch)
        self.values[key] = value
        return value

    def keep(self, node_id: int, switches: Iterable[TrimSwitch]) -> list[str]:
        """After a reload: the node's trims whose slot still has a switch, within its (new)
        limit; the others are dropped (0). Returns what changed, for the log."""
        limits = {s.slot: s.limit for s in switches}
        changes = []
        for (node, slot), value in list(self.values.items()):
            if node != node_id:
                continue
            if slot not in limits:
                del self.values[(node, slot)]
                if value:
                    changes.append(f"{AXIS_NAMES[slot]} trim {value:+.3f} dropped (no trim switch)")
            elif abs(value) > limits[slot]:
                clamped = max(-limits[slot], min(limits[slot], value))
                self.values[(node, slot)] = clamped
                name = AXIS_NAMES[slot]
                changes.append(f"{name} trim {value:+.3f} -> {clamped:+.3f} (new limit)")
        return changes
