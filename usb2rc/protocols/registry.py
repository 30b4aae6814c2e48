"""The output registry: one row per protocol, each declared and registered by its own package.

A protocol's package says in its `output` module (`usb2rc.protocols.<name>.output`) what the
rest of usb2rc needs of it, as an `OutputProtocol`: what the config file accepts for it (its
defaults, its channel limits, its own keys and their defaults), how many bytes a frame takes
and how many bit times a byte (the bandwidth check), which decoder `usb2rc decode` uses, the
checks only it has, and how its running output is built (`build`: session, link, driver,
`usb2rc.wiring`). It hands the row to `register` when it is imported.

Read the registry through `usb2rc.outputs`, which imports every protocol's `output`: here it
holds only the protocols imported so far. The config model finds a protocol's own keys'
defaults without it (`usb2rc.config.output_options`, filled by `register`), as the config sits
below the codecs and sessions that the rows name.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from usb2rc.config.output_options import Option, add_options
from usb2rc.protocols.channels import WireScale
from usb2rc.wiring import BuiltOutput, OutputContext


@dataclass(frozen=True)
class OutputProtocol:
    """One output protocol as the rest of usb2rc sees it.

    `channels` is (min, max) for a channel output, None for C2-16B (which sends nodes).
    `frame_length(n)` is the bytes of one frame of n listed channels (the bandwidth check).
    `decoder()` makes the stream decoder `usb2rc decode` uses. `build(context)` makes the
    running output."""

    name: str
    summary: str
    default_baudrate: int
    default_rate_hz: float
    frame_length: Callable[[int], int]
    decoder: Callable[[], Any]  # makes the stream decoder `usb2rc decode` uses
    build: Callable[[OutputContext], BuiltOutput]
    bits_per_byte: int = 10  # 8N1
    channels: tuple[int, int] | None = None
    channels_required: bool = False
    options: Mapping[str, Option] = field(default_factory=dict)
    # function(reader, node, items, path, output): the checks only this protocol has. A
    # protocol with one owns its channel count and bandwidth checks (MAVLink: both depend
    # on its `message`, and UDP has no baud rate); the config file skips the generic ones.
    own_checks: Callable[..., None] | None = None
    # One line on the wire and the failsafe, and the channels' `WireScale`: with both,
    # `check` and `icd` describe the output with no branch of their own.
    note: str = ""
    scale: WireScale | None = None
    display_name: str = ""  # as docs write it, when not the name in capitals
    # What users call it by (a radio system, a maker), lower case -> why it is this protocol:
    # the config's did-you-mean for an output's `protocol:`.
    aliases: Mapping[str, str] = field(default_factory=dict)

    @property
    def title(self) -> str:
        return self.display_name or self.name.upper()

    def check(self, *args: Any) -> None:
        """The protocol's own config checks (`own_checks`), if it has any."""
        if self.own_checks is not None:
            self.own_checks(*args)

    def bits_per_second(self, rate_hz: float, channel_count: int) -> float:
        """What one frame a tick needs on the wire."""
        return self.frame_length(channel_count) * self.bits_per_byte * rate_hz

    def bandwidth_problem(self, baudrate: int, rate_hz: float, channel_count: int) -> str | None:
        """Why one frame a tick does not fit the baud rate, or None."""
        needed = self.bits_per_second(rate_hz, channel_count)
        if needed <= baudrate:
            return None
        frame = self.frame_length(channel_count)
        return (
            f"{frame}-byte {self.name} frames at {rate_hz:g} Hz need {needed:.0f} bit/s "
            f"({self.bits_per_byte} bit times a byte) but {baudrate} baud carries "
            f"{baudrate / (frame * self.bits_per_byte):.0f} frames/s: raise baudrate or "
            "lower rate_hz"
        )


def fixed_length(length: int) -> Callable[[int], int]:
    """`frame_length` of a protocol whose frames have one length, whatever the channels."""

    def frame_length(_channels: int) -> int:
        return length

    return frame_length


PROTOCOLS: dict[str, OutputProtocol] = {}  # in the order they were registered


def register(row: OutputProtocol) -> OutputProtocol:
    """A protocol's `output` module registers its row (and its own keys, for the config model)."""
    if row.name in PROTOCOLS:
        raise ValueError(f"output protocol {row.name!r} is registered twice")
    PROTOCOLS[row.name] = row
    add_options(row.name, row.options)
    return row


def protocol(name: str) -> OutputProtocol:
    """The registry entry of a protocol name (KeyError for an unknown one)."""
    return PROTOCOLS[name]


def option_keys() -> tuple[str, ...]:
    """Every protocol-only key, in registry order."""
    keys: dict[str, None] = {}
    for entry in PROTOCOLS.values():
        keys.update(dict.fromkeys(entry.options))
    return tuple(keys)


def protocol_aliases() -> dict[str, tuple[str, str]]:
    """Every protocol's aliases: alias -> (the protocol's name, why)."""
    return {
        alias: (entry.name, why)
        for entry in PROTOCOLS.values()
        for alias, why in entry.aliases.items()
    }


def build(context: OutputContext) -> BuiltOutput:
    """The running pieces of the output `context.config` configures."""
    return PROTOCOLS[context.config.protocol].build(context)
