"""The SUMD output's channels: node frames → SUMD wire values (µs × 8) and the failsafe flag.

The evaluation is every channel output's (`usb2rc.protocols.channels`); SUMD brings its scale:
an axis through `protocols.sumd.codec.axis_to_sumd` (1100..1900 µs, or 900..2100 µs `extended`), a
button through `protocols.sumd.codec.button_to_sumd` (1900 µs pressed, 1100 µs released). A frame is
failsafe (status 0x81) when any node it reads is failsafe or absent.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import partial

from usb2rc.nodes.mapping import ChannelSource
from usb2rc.protocols.channels import (
    Channel,
    ChannelValue,
    OutputChannels,
    WireScale,
    channel_value,
    wire_value,
)
from usb2rc.protocols.sumd import codec as sumd

__all__ = ["SumdChannels", "sumd_channel", "sumd_scale", "sumd_value"]


def sumd_scale(extended: bool = False) -> WireScale:
    return WireScale(partial(sumd.axis_to_sumd, extended=extended), sumd.button_to_sumd)


def sumd_value(
    source: ChannelSource,
    axes: Sequence[int | None],
    group1: int,
    group2: int,
    extended: bool = False,
) -> int:
    """The SUMD wire value (µs×8) of one channel from a node's frame values."""
    return wire_value(source, axes, group1, group2, sumd_scale(extended))


def sumd_channel(source: Channel, extended: bool) -> ChannelValue:
    """A function from the nodes' frames to (wire value, in failsafe) for one SUMD channel."""
    return channel_value(source, sumd_scale(extended))


class SumdChannels(OutputChannels):
    """One SUMD output's channels, in frame order."""

    @classmethod
    def of(cls, sources: Iterable[Channel], extended: bool = False) -> SumdChannels:
        """The channels of a config's output: `SumdChannels.of(mapping.sumd_channels(out),
        out.extended)`."""
        return cls.scaled(sources, sumd_scale(extended))

    @property
    def frame_length(self) -> int:
        return sumd.frame_length(max(sumd.MIN_CHANNELS, len(self.channels)))
