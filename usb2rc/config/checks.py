"""Cross-checks over a read config: clashes on a node, SUMD channels nobody feeds.

Part of the config file's schema (docs/CONFIG.md): two sources on one axis slot or node bit, a
default-layout entry sharing its node, and a SUMD channel whose node / slot / button no
device feeds are problems naming both places. (What would fail when the outputs open is
`config/ports.py`'s.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

from usb2rc.config.model import ChannelRef, Config, DeviceConfig
from usb2rc.config.yamlnodes import NodeReader, Where


@dataclass
class _NodeUse:
    """What the devices pinned to one Node-ID claim, for clash detection."""

    axes: dict[str, str] = field(default_factory=dict)  # slot -> "device (line)"
    bits: dict[str, str] = field(default_factory=dict)  # "button 5" / "hat1 up" -> owner
    everything: str | None = None  # a default-layout device claims all of it


def device_claims(device: DeviceConfig) -> tuple[list[tuple[str, Where]], list[tuple[str, Where]]]:
    """(axis slots, node bits) the entry feeds, each with where it is configured."""
    axes = [(axis.slot, axis.where) for axis in device.axes]
    bits = [(f"button {route.node}", route.where) for route in device.buttons]
    for hat in device.hats:
        if hat.to == "hat1":
            bits.append(("hat1 (group 1 bits 24-31)", hat.where))
        else:
            bits.extend((f"button {b}", hat.where) for b in hat.to if b is not None)
    return axes, bits


def check_clashes(reader: NodeReader, config: Config) -> None:
    nodes: dict[int, _NodeUse] = {}
    for device in config.devices:
        axes, bits = device_claims(device)
        _check_own_clashes(reader, device, bits)
        if device.node_id is None:
            continue
        use = nodes.setdefault(device.node_id, _NodeUse())
        _check_node_clash(reader, device, use, axes, bits)


def _check_own_clashes(
    reader: NodeReader, device: DeviceConfig, bits: list[tuple[str, Where]]
) -> None:
    seen: dict[str, Where] = {}
    for bit, where in bits:
        if bit in seen:
            reader.report(where.problem(f"{bit} is already fed from line {seen[bit].line}"))
        seen.setdefault(bit, where)


def _check_node_clash(
    reader: NodeReader,
    device: DeviceConfig,
    use: _NodeUse,
    axes: list[tuple[str, Where]],
    bits: list[tuple[str, Where]],
) -> None:
    owner = f"device {device.name!r} (line {device.where.line})"
    node = f"node {device.node_id}"
    if use.everything or (device.default_layout and (use.axes or use.bits)):
        first = use.everything or next(iter({**use.axes, **use.bits}.values()))
        message = (
            f"{node} is already fed by {first}; a device on the default layout needs a node "
            "of its own (or list its axes, buttons and hats)"
        )
        reader.report(device.where.problem(message, key_suffix=".node_id"))
        return
    if device.default_layout:
        use.everything = owner
        return
    for slot, where in axes:
        if slot in use.axes:
            reader.report(where.problem(f"{node} axis {slot} is already fed by {use.axes[slot]}"))
        use.axes.setdefault(slot, owner)
    for bit, where in bits:
        if use.bits.get(bit, owner) != owner:
            reader.report(where.problem(f"{node} {bit} is already fed by {use.bits[bit]}"))
        use.bits.setdefault(bit, owner)


def check_channels(reader: NodeReader, config: Config) -> None:
    for output in config.outputs:
        if output.channels is None:
            continue
        for channel, where in zip(output.channels, output.channel_wheres, strict=False):
            refs = [i.source for i in channel.inputs] if channel.kind == "mix" else [channel]
            for ref in refs:
                problem = channel_problem(config, ref)
                if problem:
                    reader.report(where.problem(problem))


def channel_problem(config: Config, ref: ChannelRef) -> str | None:
    """Why a SUMD channel cannot be fed, or None. Bad names never become a ChannelRef.
    Switches and mixes are config_controls' to check."""
    if ref.kind not in ("axis", "button"):
        return None
    node_id, name = ref.node_id, ref.name
    pinned = [d for d in config.devices if d.node_id == node_id]
    if not pinned:
        if config.defaults:
            return None  # an automatically numbered node may have it
        return f"{name}: no device is pinned to node {node_id} and defaults is false"
    if any(d.default_layout for d in pinned):
        return None
    claims = [device_claims(d) for d in pinned]
    if ref.kind == "axis":
        if any(slot == ref.slot for axes, _ in claims for slot, _ in axes):
            return None
        return f"{name}: no device feeds axis {ref.slot} of node {node_id}"
    if any(bit == f"button {ref.index}" for _, bits in claims for bit, _ in bits):
        return None
    return f"{name}: no device feeds button {ref.index} of node {node_id}"
