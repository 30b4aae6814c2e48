"""Switches and throttle cuts in the node step: one owner, stepped once per node step.

`SwitchBank` is owned by the node table (usb2rc.nodes.table) and used under its lock. Each step it
reads, per node, the presses its live devices' readers logged since the bank last looked
(`ReaderRecord.presses`, turned into node buttons through each device's binding), and the
node's buttons held now, and steps every switch once (docs/CONFIG.md, "Switches"):

- a tap that began and ended between two steps is in the press log: a toggle flips exactly
  once, whichever output reads first;
- positions are keyed by the switch's name, not by a device: a replug (a new attachment) and
  a reload (`configure`) keep them; a reload clamps them to the new `positions`, and only a
  switch's `reset` button (or a restart) puts it back to `initial`;
- a node in failsafe shows each of its switches at its configured `failsafe` position (held
  where it was without one), and presses of devices that are not live do not step them;
- a held button is not a press (usb2rc.nodes.presses): a switch steps only on presses made
  while its node is live, and a latch or hat switch reads only buttons pressed then
  (`NodeFrame.pressed`), so a button held at the plug moves no switch until it is
  released and pressed again. `NodeFrame.pressed_switches` names the switches a press
  moved since their node last went live (or a reload changed them): a MAVLink action
  fires on those only.

The step writes the switches' int16 values onto the node's frame (`NodeFrame.switches`, the
channels `switch.<name>` read), into an axis slot where a switch has `slot:`, and holds a
throttle-cut channel at its low end (`ThrottleCut`): on while its switch is off position 0,
released only when the slot's own value is low again (the neutral guard's rule for a
throttle, `guard.GuardedAxis` with arm "low").
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.config.controls_model import SwitchConfig, ThrottleCut
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.hid.descriptor import InputState
from usb2rc.nodes.curves import position_value
from usb2rc.nodes.guard import DEFAULT_TOLERANCE, GuardedAxis
from usb2rc.nodes.scaling import node_button_bit
from usb2rc.nodes.step import DeviceView, NodeFrame, NodeView

log = logging.getLogger(__name__)

Groups = tuple[int, int]  # node buttons: (group 1 bits, group 2 bits)


def button_groups(button: int) -> Groups:
    group, bit = node_button_bit(button)
    return (1 << bit, 0) if group == 0 else (0, 1 << bit)


def _has(groups: Groups, mask: Groups) -> bool:
    return bool(groups[0] & mask[0] or groups[1] & mask[1])


@dataclass(frozen=True)
class _Plan:
    """A switch compiled for the step: its buttons as node-button masks."""

    config: SwitchConfig
    masks: tuple[Groups, ...]
    reset: Groups | None
    slot: int | None
    values: tuple[int, ...]  # each position's int16 value

    @classmethod
    def of(cls, switch: SwitchConfig) -> _Plan:
        masks = tuple(button_groups(ref.index) for ref in switch.buttons)
        reset = button_groups(switch.reset.index) if switch.reset else None
        slot = AXIS_NAMES.index(switch.slot) if switch.slot else None
        values = tuple(position_value(p, switch.positions) for p in range(switch.positions))
        return cls(switch, masks, reset, slot, values)

    def step(self, position: int, presses: Sequence[Groups], held: Groups) -> int:
        """The position after this step's presses (in order) and what is held now."""
        config, masks = self.config, self.masks
        for press in presses:
            if self.reset is not None and _has(press, self.reset):
                position = config.initial
            elif config.kind == "toggle" and _has(press, masks[0]):
                position = 1 - position
            elif config.kind == "steps":
                position = self._stepped(position, press)
            elif config.kind == "hat_switch":
                position = next((k for k, m in enumerate(masks) if _has(press, m)), position)
        if config.kind == "latch":
            return int(_has(held, masks[0]) or any(_has(p, masks[0]) for p in presses))
        if config.kind == "hat_switch":  # a hat's buttons are sampled: not in the press log
            position = next((k for k, m in enumerate(masks) if _has(held, m)), position)
        return position

    def _stepped(self, position: int, press: Groups) -> int:
        last = self.config.positions - 1
        if len(self.masks) == 1:
            return (position + 1) % (last + 1) if _has(press, self.masks[0]) else position
        down, up = _has(press, self.masks[0]), _has(press, self.masks[1])
        return max(0, min(last, position - down + up))


class SwitchBank:
    """Every switch's position and every throttle cut's state (the node table's)."""

    def __init__(self) -> None:
        self._plans: tuple[_Plan, ...] = ()
        self._by_node: dict[int, list[_Plan]] = {}  # the plans of each node, in config order
        self._cuts: tuple[ThrottleCut, ...] = ()
        # per node, the nodes of the switches its throttle cuts follow
        self._cut_switch_nodes: dict[int, set[int]] = {}
        self.positions: dict[str, int] = {}
        self.cut_on: dict[str, bool] = {}  # by the cut channel's name
        self._seen: dict[int, int] = {}  # device_id -> the press serial stepped on
        self._pressed: set[str] = set()  # switches a press moved since their node went live

    def configure(self, switches: Sequence[SwitchConfig], cuts: Sequence[ThrottleCut]) -> None:
        """The config's switches (start and reload): positions kept by name, within the new
        `positions`; a new switch starts at `initial`."""
        before_plans = {plan.config.name: plan.config for plan in self._plans}
        self._plans = tuple(_Plan.of(s) for s in switches)
        # a switch the reload changed must be moved by a new press before an action fires
        self._pressed = {s.name for s in switches if before_plans.get(s.name) == s} & self._pressed
        self._by_node = {}
        for plan in self._plans:
            self._by_node.setdefault(plan.config.node_id, []).append(plan)
        self._cuts = tuple(cuts)
        node_of = {plan.config.name: plan.config.node_id for plan in self._plans}
        self._cut_switch_nodes = {}
        for cut in cuts:
            if cut.switch in node_of:
                needs = self._cut_switch_nodes.setdefault(cut.channel.node_id, set())
                needs.add(node_of[cut.switch])
        kept = {}
        for switch in switches:
            before = self.positions.get(switch.name)
            if before is None:
                kept[switch.name] = switch.initial
            else:
                kept[switch.name] = min(before, switch.positions - 1)
                if kept[switch.name] != before:
                    log.warning(
                        "config reload: switch %s clamped to position %d",
                        switch.name,
                        kept[switch.name],
                    )
        self.positions = kept
        self.cut_on = {c.channel.name: self.cut_on.get(c.channel.name, False) for c in cuts}

    def with_cut_switches(self, node_ids: frozenset[int]) -> frozenset[int]:
        """`node_ids` and the nodes of the switches their throttle cuts follow: a cut is
        decided at its node's step on its switch's position, stepped with that switch's
        node."""
        needs = self._cut_switch_nodes
        if not needs:
            return node_ids
        extra = [needs[node_id] for node_id in node_ids if node_id in needs]
        return node_ids.union(*extra) if extra else node_ids

    def step(self, views: Sequence[NodeView], every_node: bool = True) -> tuple[NodeView, ...]:
        """Step the switches of these nodes on their views (one node step: every node's,
        or `every_node` False, those an output reads); the views with the switches' values
        and the cuts applied to their frames. The switches of the nodes not stepped are
        where their last step left them."""
        if not self._plans:
            return tuple(views)
        seen: dict[int, int] = {} if every_node else dict(self._seen)
        for view in views:
            held, failsafe = view.frame.pressed, view.frame.failsafe
            presses = self._presses(view.devices, seen, failsafe)
            for plan in self._by_node.get(view.frame.node_id, ()):
                name = plan.config.name
                before = self.positions[name]
                self.positions[name] = plan.step(before, presses, held)
                if failsafe:
                    self._pressed.discard(name)
                elif self.positions[name] != before:
                    self._pressed.add(name)
        self._seen = seen
        return tuple(self._applied(view) for view in views)

    def _presses(
        self, devices: Sequence[DeviceView], seen: dict[int, int], failsafe: bool
    ) -> list[Groups]:
        """The node buttons pressed since the last step, per press, from the devices of a
        live node."""
        presses: list[Groups] = []
        for device in devices:
            before = self._seen.get(device.device_id, 0)
            record = device.record
            seen[device.device_id] = record.press_serial if device.known else before
            if failsafe or not device.live:
                continue  # presses while not live are consumed, never applied later
            after = max(before, device.counts_from)  # and those before its node went live
            new = record.presses_after(after)
            if not new:
                continue  # the common step: no binding applied
            values = record.state.values
            idle = device.binding.apply(InputState(values, 0))  # hats: not presses
            for mask in new:
                pressed = device.binding.apply(InputState(values, mask))
                presses.append((pressed.group1 & ~idle.group1, pressed.group2 & ~idle.group2))
        return presses

    def shown(self, plan: _Plan, failsafe: bool) -> int:
        """The position the switch shows: its failsafe position while its node is in
        failsafe (when configured), else where it is."""
        config = plan.config
        if failsafe and config.failsafe is not None:
            return config.failsafe
        return self.positions.get(config.name, config.initial)

    def _applied(self, view: NodeView) -> NodeView:
        frame = view.frame
        named, overrides, pressed = [], [], []
        for plan in self._by_node.get(frame.node_id, ()):
            name = plan.config.name
            value = plan.values[self.shown(plan, frame.failsafe)]
            named.append((name, value))
            if name in self._pressed:
                pressed.append(name)
            if plan.slot is not None:
                overrides.append((plan.slot, value))
        overrides += self._cut_overrides(frame, overrides)
        if not named and not overrides:
            return view
        axes = frame.axes
        if overrides:
            changed = list(axes)
            for slot, value in overrides:
                changed[slot] = value
            axes = tuple(changed)
        # `replace` (not a new NodeFrame): fields added to the frame later are kept
        frame = frame._replace(axes=axes, switches=tuple(named), pressed_switches=tuple(pressed))
        return view._replace(frame=frame, overrides=tuple(overrides))

    def _cut_overrides(
        self, frame: NodeFrame, overrides: Sequence[tuple[int, int]]
    ) -> list[tuple[int, int]]:
        result = []
        for cut in self._cuts:
            if cut.channel.node_id != frame.node_id:
                continue
            slot, name = cut.channel.index, cut.channel.name
            unsigned = bool(frame.unsigned_slots >> slot & 1)
            if self.positions.get(cut.switch, 0) != 0:
                self.cut_on[name] = True
            elif self.cut_on.get(name):
                low = GuardedAxis(slot, name, "low", DEFAULT_TOLERANCE, unsigned)
                value = dict(overrides).get(slot, frame.axes[slot])
                if not frame.failsafe and low.at_rest(value):
                    self.cut_on[name] = False
                    log.info("throttle cut on %s released: the throttle is low", name)
            if self.cut_on.get(name):
                result.append((slot, 0 if unsigned else -32768))
        return result
