"""The SUMD output's channels: node frames → SUMD wire values (µs × 8) and the failsafe flag.

A SUMD channel is named as SUMD names it in the config: `nodeN.<slot>` (an axis slot of node
N) or `nodeN.buttonK` (node button K, 1..56); `config.ChannelRef` holds it, parsed once, and
`Mapping.sumd_channels(output)` resolves the output's list (or the default one) into
`ChannelSource`s. Here they are evaluated, once a tick, from the NodeTable's frames:

- an axis: the node's slot value; whether it is a uint16 comes from the frame
  (`NodeFrame.unsigned_slots`: the bindings and pinned entries feeding the node, see
  `binding.unsigned_slots`), not from a guess about the config; a uint16 is shifted to int16,
  then `protocol.sumd.axis_to_sumd` (1100..1900 µs, or 900..2100 µs `extended`);
- a button: `protocol.sumd.button_to_sumd` (1900 µs pressed, 1100 µs released);
- a node that does not exist: the centre / released, and the frame goes out as failsafe;
  the frame is failsafe (status 0x81) when any node it reads is.

The wire arithmetic is the codec's (usb2rc.protocol.sumd); nothing here raises on a tick.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence

from usb2rc.config import ChannelRef
from usb2rc.mapping import ChannelSource
from usb2rc.protocol import sumd
from usb2rc.scaling import node_button_bit
from usb2rc.state import NodeFrame

Nodes = Mapping[int, NodeFrame]
ChannelValue = Callable[[Nodes], tuple[int, bool]]  # the nodes' frames -> (wire, failsafe)
Channel = ChannelRef | ChannelSource


def _axis_wire(value: int | None, unsigned: bool, extended: bool) -> int:
    if value is None:
        value = 32768 if unsigned else 0
    if unsigned:
        value -= 32768
    return sumd.axis_to_sumd(min(32767, max(-32768, value)), extended)  # never raise on a tick


def _button_wire(button: int, group1: int, group2: int) -> int:
    group, bit = node_button_bit(button)
    return sumd.button_to_sumd(bool(((group1, group2)[group] >> bit) & 1))


def sumd_value(
    source: ChannelSource,
    axes: Sequence[int | None],
    group1: int,
    group2: int,
    extended: bool = False,
) -> int:
    """The SUMD wire value (µs×8) of one channel from a node's frame values; `source.unsigned`
    says whether the axis value is a uint16 (None: this slot is not fed, the centre)."""
    if source.kind == "button":
        return _button_wire(source.index, group1, group2)
    return _axis_wire(axes[source.index], source.unsigned, extended)


def sumd_channel(source: Channel, extended: bool) -> ChannelValue:
    """A function from the nodes' frames to (wire value, in failsafe) for one SUMD channel.

    Whether an axis is unsigned comes from the frame (the bindings feeding it); a node that
    does not exist sends the centre / released, in failsafe (0x81)."""
    node_id, index = source.node_id, source.index
    if source.kind == "button":
        released = sumd.button_to_sumd(False)

        def button(nodes: Nodes) -> tuple[int, bool]:
            frame = nodes.get(node_id)
            if frame is None:
                return released, True
            return _button_wire(index, frame.group1, frame.group2), frame.failsafe

        return button
    centre = _axis_wire(0, False, extended)

    def axis(nodes: Nodes) -> tuple[int, bool]:
        frame = nodes.get(node_id)
        if frame is None:
            return centre, True
        unsigned = bool(frame.unsigned_slots >> index & 1)
        return _axis_wire(frame.axes[index], unsigned, extended), frame.failsafe

    return axis


class SumdChannels:
    """One SUMD output's channels, in frame order: `evaluate` once a tick (the output
    thread's `SumdOutput.tick`)."""

    def __init__(self, channels: Sequence[ChannelValue]) -> None:
        self.channels = tuple(channels)

    @classmethod
    def of(cls, sources: Iterable[Channel], extended: bool = False) -> SumdChannels:
        """The channels of a config's output: `SumdChannels.of(mapping.sumd_channels(out),
        out.extended)`."""
        return cls([sumd_channel(source, extended) for source in sources])

    def __len__(self) -> int:
        return len(self.channels)

    @property
    def frame_length(self) -> int:
        """Bytes of one frame on the wire."""
        return sumd.frame_length(max(sumd.MIN_CHANNELS, len(self.channels)))

    def evaluate(self, frames: Iterable[NodeFrame]) -> tuple[list[int], bool]:
        """The wire values of every channel, and whether the frame is a failsafe frame."""
        nodes = {frame.node_id: frame for frame in frames}
        values: list[int] = []
        failsafe = False
        for channel in self.channels:
            value, channel_failsafe = channel(nodes)
            values.append(value)
            failsafe = failsafe or channel_failsafe
        return values, failsafe
