"""Compile a validated Config into plain tables; pick each device's binding.

`compile_mapping(config) -> Mapping` compiles every device entry once (`CompiledEntry`: its
matcher, button runs, unsigned slots, and the failsafe values its node sends before the device
comes: docs/ICD.md, "Failsafe"). `Mapping.bind(info, layout)` turns the first matching entry
(or the default layout, docs/ICD.md, "Default axis layout") plus the device's DeviceLayout into
a `DeviceBinding` (usb2rc.nodes.binding), whose `apply(state)` is the per-report hot path. The
arithmetic (docs/ICD.md, "Axis scaling") is usb2rc.nodes.scaling's; the SUMD wire values are the
SUMD output's (usb2rc.protocols.sumd.channels).
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from usb2rc.config.controls_model import ActionConfig, Curve, MixInput, MixRef
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.config.model import (
    SUMD_DEFAULT_SLOTS,
    ChannelRef,
    Config,
    DeviceConfig,
    MatchConfig,
    OutputConfig,
)
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import DeviceLayout
from usb2rc.nodes.binding import (
    NUM_AXES,
    ButtonRun,
    DeviceBinding,
    NodeInputs,
    compile_button_runs,
    configured_binding,
    default_binding,
    unsigned_slots,
)
from usb2rc.nodes.curves import position_value
from usb2rc.nodes.known_devices import KnownDevice, lookup


@dataclass(frozen=True)
class ChannelSource:
    """One SUMD channel: a node's axis slot (index 0..9) or node button (1..56), a switch
    (`switch.NAME`: read by name from its node's `NodeFrame.switches`) or a mix (node -1)."""

    node_id: int
    kind: str  # "axis", "button", "switch" or "mix"
    index: int
    unsigned: bool = False
    name: str = ""
    fallback: int = 0  # a switch: its int16 value while its node does not exist
    mix: tuple[MixLine, ...] = ()


@dataclass(frozen=True)
class MixLine:
    """One line of a mix: its source, its rates' switch resolved (CONFIG.md "Mixes and curves")."""

    source: ChannelSource
    weight: float
    offset: float
    curve: Curve | None
    rates: tuple[ChannelSource, tuple[float, ...]] | None = None


# --------------------------------------------------------------------------- Mapping


Matcher = Callable[[DeviceInfo], bool]


def compile_match(match: MatchConfig) -> Matcher:
    """Every given match key must agree; product is a case-insensitive glob (compiled once)."""
    product = re.compile(fnmatch.translate(match.product.lower())) if match.product else None

    def matches(info: DeviceInfo) -> bool:
        if match.vid is not None and match.vid != info.vid:
            return False
        if match.pid is not None and match.pid != info.pid:
            return False
        if match.serial is not None and match.serial != info.serial:
            return False
        if match.port is not None and match.port not in (info.port_path, info.path, info.hidraw):
            return False
        return product is None or product.match(info.product.lower()) is not None

    return matches


def match_text(match: MatchConfig) -> str:
    """The match as configured, for a user looking for the device: "vid 0x044f, pid 0xb679,
    serial ABC, port 1-1.2, product '*Pedals*'" (the keys given, in that order)."""
    parts = [f"{k} 0x{v:04x}" for k, v in (("vid", match.vid), ("pid", match.pid)) if v is not None]
    parts += [f"{k} {v}" for k, v in (("serial", match.serial), ("port", match.port)) if v]
    if match.product:
        parts.append(f"product {match.product!r}")
    return ", ".join(parts) or "any device"


@dataclass(frozen=True)
class CompiledEntry:
    """One device entry of the config, compiled once: all of its binding that does not
    depend on the device's descriptor, and what its node sends before the device comes."""

    config: DeviceConfig
    matches: Matcher
    button_runs: tuple[ButtonRun, ...]
    unsigned_slots: int  # bit k: slot k is a uint16 (`unsigned_slots`)
    failsafe: NodeInputs  # configured failsafe values, 0 without one (docs/ICD.md, "Failsafe")

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def node_id(self) -> int | None:
        return self.config.node_id

    def bind(self, layout: DeviceLayout, known: KnownDevice | None = None) -> DeviceBinding:
        """Raises MappingError naming the config line when a usage is not in the device.
        `known`: the device's entry in the device database (where axes without `arm:` rest)."""
        return configured_binding(layout, self.config, self.button_runs, known)


def compile_entry(device: DeviceConfig) -> CompiledEntry:
    axes: list[int | None] = [None] * NUM_AXES
    for axis in device.axes:
        axes[AXIS_NAMES.index(axis.slot)] = 0 if axis.failsafe is None else axis.failsafe
    return CompiledEntry(
        device,
        compile_match(device.match),
        compile_button_runs([(r.hid, r.node) for r in device.buttons]),
        unsigned_slots(device.axes),
        NodeInputs(tuple(axes), 0, 0),
    )


class Mapping:
    """The compiled config: device entries in order (compiled), outputs, SUMD channels."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.devices = config.devices
        self.entries = tuple(compile_entry(d) for d in config.devices)

    def compiled_entry_for(self, info: DeviceInfo) -> CompiledEntry | None:
        """The first compiled entry whose match fits the device, or None."""
        return next((e for e in self.entries if e.matches(info)), None)

    def entry_for(self, info: DeviceInfo) -> DeviceConfig | None:
        """The first config entry whose match fits the device, or None."""
        entry = self.compiled_entry_for(info)
        return entry.config if entry is not None else None

    def bind(self, info: DeviceInfo, layout: DeviceLayout) -> DeviceBinding | None:
        """The device's binding; None when it has no entry and `defaults: false`.

        Raises MappingError (naming the config line) when the entry names a usage the device
        does not have.
        """
        entry = self.compiled_entry_for(info)
        known = lookup(info.vid, info.pid)  # the device database (docs/ICD.md, "Neutral guard")
        if entry is not None:
            return entry.bind(layout, known)
        if not self.config.defaults:
            return None
        name = info.product or (known.name if known else f"{info.vid:04x}:{info.pid:04x}")
        return default_binding(layout, name, known=known)

    def pinned_node_ids(self) -> set[int]:
        return {e.node_id for e in self.entries if e.node_id is not None}

    def pinned_entries(self) -> list[CompiledEntry]:
        """The entries pinned to a Node-ID, in config order."""
        return [e for e in self.entries if e.node_id is not None]

    def sumd_channels(self, output: OutputConfig) -> list[ChannelSource]:
        """The output's channel sources; without `channels`, the lowest configured node's
        x, y, z, rz, slider, rx, ry, dial (node 0 when no node is pinned). `unsigned` is
        what the entries pinned to the node say (for `icd` and `check`); the output itself
        reads it from the node's frame (usb2rc.protocols.sumd.channels)."""
        refs = output.channels
        if refs is None:
            node = min(self.pinned_node_ids(), default=0)
            refs = tuple(ChannelRef.axis(node, slot) for slot in SUMD_DEFAULT_SLOTS)
        return [self._channel(ref) for ref in refs]

    def _channel(self, ref: ChannelRef | MixRef) -> ChannelSource:
        if isinstance(ref, MixRef):
            lines = tuple(self._mix_line(line) for line in ref.inputs)
            return ChannelSource(-1, "mix", -1, False, ref.name, mix=lines)
        if ref.kind == "switch":
            return self._switch(ref.name)
        if ref.kind == "button":
            return ChannelSource(ref.node_id, "button", ref.index, False, ref.name)
        unsigned = any(
            e.unsigned_slots >> ref.index & 1 for e in self.entries if e.node_id == ref.node_id
        )
        return ChannelSource(ref.node_id, "axis", ref.index, unsigned, ref.name)

    def _switch(self, name: str) -> ChannelSource:
        """A switch's channel: its node, its place among that node's switches."""
        key = name.strip().lower().removeprefix("switch.")
        switch = next(s for s in self.config.switches if s.name == key)  # config checked
        shown = switch.initial if switch.failsafe is None else switch.failsafe
        fallback = position_value(shown, switch.positions)
        return ChannelSource(switch.node_id, "switch", -1, False, f"switch.{key}", fallback)

    def action_triggers(
        self, actions: Sequence[ActionConfig]
    ) -> list[tuple[ChannelSource, int | None]]:
        """Each MAVLink action's trigger: its node button (None: active while down), or its
        switch and the int16 value of its position (usb2rc.protocols.mavlink.actions)."""
        triggers: list[tuple[ChannelSource, int | None]] = []
        for action in actions:
            if action.button is not None:
                triggers.append((self._channel(action.button), None))
                continue
            assert action.switch is not None
            switch = next(s for s in self.config.switches if s.name == action.switch)
            value = position_value(action.position, switch.positions)
            triggers.append((self._switch(action.switch), value))
        return triggers

    def _mix_line(self, line: MixInput) -> MixLine:
        rates = None
        if line.rates is not None:
            rates = (self._switch(line.rates.switch), line.rates.weights)
        return MixLine(self._channel(line.source), line.weight, line.offset, line.curve, rates)


def compile_mapping(config: Config) -> Mapping:
    """Compile every device entry of a validated config once (`Mapping.entries`)."""
    return Mapping(config)


__all__ = [
    "ChannelSource",
    "CompiledEntry",
    "Mapping",
    "MixLine",
    "compile_mapping",
]
