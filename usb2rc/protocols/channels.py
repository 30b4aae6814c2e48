"""Channel outputs' channels: node frames → wire values and the failsafe flag, for any protocol.

Every channel output (and MAVLink's RC override) carries a list of channels named the same
way in the config: `nodeN.<slot>` (an axis slot of node N) or `nodeN.buttonK` (node button K,
1..56); `config.channel_ref.ChannelRef` holds one, parsed once, and
`Mapping.sumd_channels(output)` resolves an output's list (or the default one) into
`ChannelSource`s. Here they are evaluated, once a tick, from the NodeTable's frames, through
the protocol's `WireScale`:

- an axis: the node's slot value; whether it is a uint16 comes from the frame
  (`NodeFrame.unsigned_slots`: the bindings and pinned entries feeding the node, see
  `binding.unsigned_slots`), not from a guess about the config; a uint16 is shifted to int16,
  then `scale.axis` (an int16 onto the protocol's wire values);
- a button: `scale.button(pressed)`;
- a switch (`switch.<name>`): its int16 value on its node's frame (`NodeFrame.switches`,
  usb2rc.nodes.switches), then `scale.axis`: its positions spread over the range;
- a mix: each line's source as -1..1, `weight × rate × curve(x) + offset` summed and
  clamped (usb2rc.nodes.curves), then `scale.axis`: never out of range;
- a node that does not exist: the centre / released, and the channel is in failsafe; a frame
  is failsafe when any channel it reads is.

Nothing here raises on a tick.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Self

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.nodes.curves import clamp, mix_line, normalised, position_value, to_int16
from usb2rc.nodes.mapping import ChannelSource, MixLine
from usb2rc.nodes.scaling import node_button_bit
from usb2rc.nodes.table import NodeFrame

Nodes = Mapping[int, NodeFrame]
ChannelValue = Callable[[Nodes], tuple[int, bool]]  # the nodes' frames -> (wire, failsafe)
Channel = ChannelRef | ChannelSource


@dataclass(frozen=True)
class WireScale:
    """A protocol's channel scaling: an int16 axis and a button onto its wire values."""

    axis: Callable[[int], int]
    button: Callable[[bool], int]


def _axis_wire(value: int | None, unsigned: bool, scale: WireScale) -> int:
    if value is None:
        value = 32768 if unsigned else 0
    if unsigned:
        value -= 32768
    return scale.axis(min(32767, max(-32768, value)))  # never raise on a tick


def _button_wire(button: int, group1: int, group2: int, scale: WireScale) -> int:
    group, bit = node_button_bit(button)
    return scale.button(bool(((group1, group2)[group] >> bit) & 1))


def wire_value(
    source: ChannelSource,
    axes: Sequence[int | None],
    group1: int,
    group2: int,
    scale: WireScale,
) -> int:
    """The wire value of one channel from a node's frame values; `source.unsigned` says
    whether the axis value is a uint16 (None: this slot is not fed, the centre)."""
    if source.kind == "button":
        return _button_wire(source.index, group1, group2, scale)
    return _axis_wire(axes[source.index], source.unsigned, scale)


def channel_value(source: Channel, scale: WireScale) -> ChannelValue:
    """A function from the nodes' frames to (wire value, in failsafe) for one channel.

    Whether an axis is unsigned comes from the frame (the bindings feeding it); a node that
    does not exist sends the centre / released, in failsafe."""
    node_id, index = source.node_id, source.index
    if isinstance(source, ChannelSource) and source.kind in ("switch", "mix"):
        int16 = int16_value(source)
        return lambda nodes: _scaled(int16(nodes), scale)
    if source.kind == "button":
        released = scale.button(False)

        def button(nodes: Nodes) -> tuple[int, bool]:
            frame = nodes.get(node_id)
            if frame is None:
                return released, True
            return _button_wire(index, frame.group1, frame.group2, scale), frame.failsafe

        return button
    centre = _axis_wire(0, False, scale)

    def axis(nodes: Nodes) -> tuple[int, bool]:
        frame = nodes.get(node_id)
        if frame is None:
            return centre, True
        unsigned = bool(frame.unsigned_slots >> index & 1)
        return _axis_wire(frame.axes[index], unsigned, scale), frame.failsafe

    return axis


Int16Value = Callable[[Nodes], tuple[int, bool]]  # the nodes' frames -> (int16, failsafe)


def nodes_read(sources: Iterable[Channel]) -> frozenset[int] | None:
    """The Node-IDs whose frames these channels read: each source's node, a mix's lines'
    sources and rate switches. None when one is not resolved to a node (a switch by name
    before `Mapping.sumd_channels`): then any node may be read."""
    nodes: set[int] = set()
    for source in sources:
        if isinstance(source, ChannelSource) and source.kind == "mix":
            lines = nodes_read(
                [line.source for line in source.mix]
                + [line.rates[0] for line in source.mix if line.rates is not None]
            )
            if lines is None:
                return None
            nodes |= lines
        elif source.node_id < 0:
            return None
        else:
            nodes.add(source.node_id)
    return frozenset(nodes)


def _scaled(value: tuple[int, bool], scale: WireScale) -> tuple[int, bool]:
    return scale.axis(value[0]), value[1]


def int16_value(source: ChannelSource) -> Int16Value:
    """A channel as an int16 (an axis's value, a button low / high, a switch's position, a
    mix), and whether its node is in failsafe (or absent): what a mix adds up."""
    node_id, index = source.node_id, source.index
    if source.kind == "mix":
        return _mix_value(source.mix)
    if source.kind == "switch":
        fallback, name = source.fallback, source.name.removeprefix("switch.")

        def switch(nodes: Nodes) -> tuple[int, bool]:
            frame = nodes.get(node_id)
            if frame is not None:
                for key, value in frame.switches:
                    if key == name:
                        return value, frame.failsafe
            return fallback, True  # no such node, or a reload removed the switch

        return switch
    if source.kind == "button":
        group, bit = node_button_bit(index)

        def button(nodes: Nodes) -> tuple[int, bool]:
            frame = nodes.get(node_id)
            if frame is None:
                return -32768, True
            pressed = ((frame.group1, frame.group2)[group] >> bit) & 1
            return (32767 if pressed else -32768), frame.failsafe

        return button

    def axis(nodes: Nodes) -> tuple[int, bool]:
        frame = nodes.get(node_id)
        if frame is None:
            return 0, True
        value = frame.axes[index]
        if frame.unsigned_slots >> index & 1:
            value -= 32768
        return min(32767, max(-32768, value)), frame.failsafe

    return axis


def _mix_value(lines: Sequence[MixLine]) -> Int16Value:
    """docs/CONFIG.md "Mixes and curves": y = clamp(Σ weight·rate·curve(x) + offset)."""
    compiled = [
        (int16_value(line.source), line, None if line.rates is None else int16_value(line.rates[0]))
        for line in lines
    ]

    def mix(nodes: Nodes) -> tuple[int, bool]:
        total, failsafe = 0.0, False
        for value, line, rate_switch in compiled:
            raw, line_failsafe = value(nodes)
            weight = line.weight * _rate(line, rate_switch, nodes)
            total += mix_line(normalised(raw), weight, line.offset, line.curve)
            failsafe = failsafe or line_failsafe
        return to_int16(clamp(total)), failsafe

    return mix


def _rate(line: MixLine, switch: Int16Value | None, nodes: Nodes) -> float:
    """The rates' weight at the switch's position (1 without rates)."""
    if line.rates is None or switch is None:
        return 1.0
    weights = line.rates[1]
    value, _ = switch(nodes)
    position = min(range(len(weights)), key=lambda k: abs(position_value(k, len(weights)) - value))
    return weights[position]


class OutputChannels:
    """One output's channels, in frame order: `evaluate` once a tick (the output thread)."""

    def __init__(
        self,
        channels: Sequence[ChannelValue],
        frame_length: int = 0,
        node_ids: frozenset[int] | None = None,
        of_frames_alone: bool = False,
    ) -> None:
        """`of_frames_alone`: every channel's value is a function of the node frames alone
        (as `scaled` makes them from a config), so a result may be reused for equal frames;
        a callable that reads anything else (a test's own value) is evaluated every tick."""
        self.channels = tuple(channels)
        self._frame_length = frame_length
        # the nodes the channels read (None: any node): the step before a tick of this
        # output alone need not step the others
        self.node_ids = node_ids
        # the last frames evaluated and what they gave: frames equal to the last ones
        # (nodes in failsafe, sticks at rest) give the same values without evaluating
        # every channel again
        self._of_frames_alone = of_frames_alone
        self._last: tuple[list[NodeFrame], list[int], bool] | None = None

    @classmethod
    def scaled(cls, sources: Iterable[Channel], scale: WireScale, frame_length: int = 0) -> Self:
        """The channels of a config's output through a protocol's scale, and the nodes
        they read."""
        sources = tuple(sources)
        values = [channel_value(source, scale) for source in sources]
        return cls(values, frame_length, nodes_read(sources), of_frames_alone=True)

    def __len__(self) -> int:
        return len(self.channels)

    @property
    def frame_length(self) -> int:
        """Bytes of one frame on the wire (for the transmit queue cap)."""
        return self._frame_length

    def evaluate(self, frames: Iterable[NodeFrame]) -> tuple[list[int], bool]:
        """The wire values of every channel, and whether the frame is a failsafe frame."""
        if not self._of_frames_alone:
            return self._evaluated(frames)
        frames = list(frames)
        last = self._last
        if last is not None and last[0] == frames:
            return list(last[1]), last[2]
        values, failsafe = self._evaluated(frames)
        self._last = (frames, values, failsafe)
        return list(values), failsafe

    def _evaluated(self, frames: Iterable[NodeFrame]) -> tuple[list[int], bool]:
        nodes = {frame.node_id: frame for frame in frames}
        values: list[int] = []
        failsafe = False
        for channel in self.channels:
            value, channel_failsafe = channel(nodes)
            values.append(value)
            failsafe = failsafe or channel_failsafe
        return values, failsafe
