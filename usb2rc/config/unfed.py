"""Channels that read an axis slot no device of its node feeds, once the devices are known.

A config may name any of a node's ten axis slots (`node0.z`); which slots a node gets is
up to the devices that become it. A T.16000M on the default layout feeds x, y, slider and
rz: a CRSF `channels: [node0.x, node0.y, node0.z, node0.rz]` then sends a constant centre
on channel 3, with nothing wrong in the file. So once the devices are known (`check
--replay DIR` binds recordings; the daemon binds a device when it is plugged), each channel
that reads a slot none of its node's devices feeds is a warning naming the devices and the
axes they have. A switch with `slot:` feeds that slot of its node, and an entry pinned to the
node whose device is not there yet is taken to feed what it lists (its own warning says
nothing matched it). A node no known device became is left out.

Pure: the callers hand in what the devices feed (`DeviceFeed`) and which protocols carry
channels (the output registry sits above the config package).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.config.controls_model import MixRef
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.config.model import SUMD_DEFAULT_SLOTS, Config, OutputConfig
from usb2rc.config.yamlnodes import Problem, Where


@dataclass(frozen=True)
class DeviceFeed:
    """What one bound device feeds: its node and the axis slots it writes."""

    product: str
    vid: int
    pid: int
    node_id: int
    axes: frozenset[str]
    entry: Where | None = None  # the config entry it was bound by (its `where`); None: none

    @property
    def label(self) -> str:
        return f"{self.product or '?'} ({self.vid:04x}:{self.pid:04x})"

    def has(self) -> str:
        """`Thrustmaster T.16000M (044f:b10a) has axes x, y, slider, rz`."""
        slots = [slot for slot in AXIS_NAMES if slot in self.axes]
        return f"{self.label} has " + (f"axes {', '.join(slots)}" if slots else "no axes")


@dataclass(frozen=True)
class _SlotRead:
    """One axis slot an output's channel reads (directly or as a mix input)."""

    ref: ChannelRef
    channel: int  # 1-based, as a receiver numbers it
    where: Where | None  # the channel's line; None: a default channel list
    in_mix: bool


def unfed_slot_warnings(
    config: Config,
    devices: Sequence[DeviceFeed],
    carries_channels: Callable[[str], bool],
    nodes: Collection[int] | None = None,
) -> list[Problem]:
    """A warning for each channel (a mix's inputs included) of each output whose protocol
    carries channels (`carries_channels(protocol)`) that reads an axis slot of a node that
    `devices` became, when none of them (nor a switch's `slot:`) feeds it; one per node for
    a default channel list. `nodes`: only those nodes (the daemon: the node of the device
    just plugged)."""
    problems = []
    for index, output in enumerate(config.outputs):
        if not carries_channels(output.protocol):
            continue
        unfed: dict[int, list[_SlotRead]] = {}
        for read in _slot_reads(config, output):
            node_id = read.ref.node_id
            feeding = [d for d in devices if d.node_id == node_id]
            if (nodes is None or node_id in nodes) and feeding and not _fed(config, feeding, read):
                unfed.setdefault(node_id, []).append(read)
        for node_id, reads in unfed.items():
            feeding = [d for d in devices if d.node_id == node_id]
            if output.channels is None:
                problems.append(_default_list_warning(config, index, output, reads, feeding))
            else:
                problems += [_warning(read, feeding) for read in reads]
    return problems


def default_channels(config: Config) -> tuple[ChannelRef, ...]:
    """A channel output's list without `channels:`: the lowest pinned node's
    x, y, z, rz, slider, rx, ry, dial (node 0 when no node is pinned)."""
    node = min((d.node_id for d in config.devices if d.node_id is not None), default=0)
    return tuple(ChannelRef.axis(node, slot) for slot in SUMD_DEFAULT_SLOTS)


def _slot_reads(config: Config, output: OutputConfig) -> Iterator[_SlotRead]:
    if output.channels is None:
        for number, ref in enumerate(default_channels(config), 1):
            yield _SlotRead(ref, number, None, False)
        return
    wheres = output.channel_wheres
    for number, channel in enumerate(output.channels, 1):
        where = wheres[number - 1] if number <= len(wheres) else None
        if isinstance(channel, MixRef):
            for line in channel.inputs:
                if line.source.kind == "axis":
                    yield _SlotRead(line.source, number, where, True)
        elif channel.kind == "axis":
            yield _SlotRead(channel, number, where, False)


def _fed(config: Config, devices: Sequence[DeviceFeed], read: _SlotRead) -> bool:
    """A device feeds the slot, a switch does, or an entry pinned to the node that no
    device is bound by yet would (it is awaited: its own warning says nothing matched)."""
    ref = read.ref
    if any(ref.slot in d.axes for d in devices):
        return True
    if any(s.slot == ref.slot and s.node_id == ref.node_id for s in config.switches):
        return True
    bound = {d.entry for d in devices}
    return any(
        entry.node_id == ref.node_id
        and entry.where not in bound
        and (entry.default_layout or any(axis.slot == ref.slot for axis in entry.axes))
        for entry in config.devices
    )


def _unfed_text(node_id: int, devices: Sequence[DeviceFeed]) -> str:
    return f"no device of node {node_id} feeds: {'; '.join(d.has() for d in devices)}"


def _warning(read: _SlotRead, devices: Sequence[DeviceFeed]) -> Problem:
    """At the channel's line: what it reads, who could have fed it, what it sends."""
    assert read.where is not None  # a listed channel
    ref = read.ref
    if read.in_mix:
        what = f"{ref.name} (in the mix of channel {read.channel})"
        sends = "Its part of the mix never moves (the slot's 0, the centre)"
    else:
        what = ref.name
        sends = f"Channel {read.channel} never moves (it sends the slot's 0, the centre)"
    message = (
        f"warning: {what} reads axis {ref.slot} of node {ref.node_id}, which "
        f"{_unfed_text(ref.node_id, devices)}. {sends}"
    )
    return read.where.problem(message)


def _default_list_warning(
    config: Config,
    index: int,
    output: OutputConfig,
    reads: Sequence[_SlotRead],
    devices: Sequence[DeviceFeed],
) -> Problem:
    """At the output: the default list's channels of one node that nothing feeds."""
    node_id = reads[0].ref.node_id
    names = ", ".join(read.ref.name for read in reads)
    numbers = ", ".join(str(read.channel) for read in reads)
    message = (
        f"warning: the default channels {names} (channels {numbers}) read axes "
        f"{_unfed_text(node_id, devices)}. They never move (they send the slot's 0, the "
        "centre): list the channels you want with `channels:`"
    )
    if output.where is not None:
        return output.where.problem(message, key_suffix=".channels")
    return Problem(config.source, None, f"outputs[{index}].channels", message)
