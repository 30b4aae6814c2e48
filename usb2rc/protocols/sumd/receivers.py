"""What the SUMD decoders of flight-controller firmware take of a SUMD output: the warnings
`usb2rc check` prints (docs/CONFIG.md, "SUMD receivers").

The SUMD decoders of PX4, ArduPilot and Betaflight accept usb2rc's SUMD frames as they are,
but each has limits the SUMD specification does not have (it allows 2..32 channels):

- PX4 and ArduPilot misread a frame with fewer than 4 channels;
- PX4 and Betaflight keep only the first 18 channels of a frame;
- ArduPilot wants the whole frame within 5 ms of its first byte, which at 115200 baud (what
  these firmwares read SUMD at) is at most 26 channels.

None of them makes a config wrong (another receiver may take it), so these are warnings: the
config still passes. A channel that reads a node no device entry pins is one too: it reads
whichever device happens to be numbered N automatically, which depends on plug order.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

from usb2rc.config.model import OutputConfig
from usb2rc.config.yamlnodes import Problem, Where
from usb2rc.lines.link import BITS_PER_BYTE_ON_WIRE
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.protocols.sumd import codec as sumd

FEWEST_CHANNELS_READ = 4  # PX4, ArduPilot: fewer are misread
MOST_CHANNELS_KEPT = 18  # PX4, Betaflight: the rest of the frame is dropped
ARDUPILOT_FRAME_S = 0.005  # ArduPilot: the whole frame within 5 ms of its first byte


def frame_seconds(channels: int, baudrate: int) -> float:
    """How long a SUMD frame of `channels` channels takes on the wire (8N1)."""
    return sumd.frame_length(channels) * BITS_PER_BYTE_ON_WIRE / baudrate


def most_channels_within(seconds: float, baudrate: int) -> int:
    """The most channels whose frame takes no longer than `seconds` at `baudrate`."""
    fits = [
        n
        for n in range(sumd.MIN_CHANNELS, sumd.MAX_CHANNELS + 1)
        if frame_seconds(n, baudrate) <= seconds
    ]
    return max(fits, default=0)


def receiver_warnings(
    output: OutputConfig, channels: Sequence[ChannelSource], pinned: Collection[int]
) -> list[Problem]:
    """Every warning for one SUMD output; `channels` as `Mapping.sumd_channels(output)` gives
    them (the default list when the output has none), `pinned`: the pinned Node-IDs."""
    if output.protocol != "sumd":
        return []
    where = _where(output)
    count = len(channels)
    warnings = []
    if count < FEWEST_CHANNELS_READ:
        warnings.append(
            f"{count} channels: PX4 and ArduPilot misread SUMD frames with fewer than "
            f"{FEWEST_CHANNELS_READ} channels; list at least {FEWEST_CHANNELS_READ}"
        )
    if count > MOST_CHANNELS_KEPT:
        lost = " ".join(c.name for c in channels[MOST_CHANNELS_KEPT:])
        warnings.append(
            f"{count} channels: PX4 and Betaflight keep only the first {MOST_CHANNELS_KEPT}; "
            f"they drop {lost}"
        )
    took = frame_seconds(count, output.baudrate)
    if took > ARDUPILOT_FRAME_S:
        most = most_channels_within(ARDUPILOT_FRAME_S, output.baudrate)
        warnings.append(
            f"{count} channels take {took * 1000:.2f} ms at {output.baudrate} baud: ArduPilot "
            f"drops a SUMD frame that does not arrive whole within "
            f"{ARDUPILOT_FRAME_S * 1000:g} ms (at most {most} channels at this baud rate)"
        )
    problems = [where.problem(f"warning: {text}") for text in warnings]
    return problems + _unpinned(output, channels, pinned, where)


def _unpinned(
    output: OutputConfig, channels: Sequence[ChannelSource], pinned: Collection[int], where: Where
) -> list[Problem]:
    """Channels reading a node no entry pins: one warning per channel (per node for the
    default list, which the output's own line stands for)."""
    if output.channels is None:
        nodes = sorted({c.node_id for c in channels} - set(pinned))
        return [where.problem(_unpinned_text(node, "the default channels")) for node in nodes]
    return [
        w.problem(_unpinned_text(c.node_id, c.name))
        for c, w in zip(channels, output.channel_wheres, strict=False)
        if c.node_id not in pinned and c.kind != "mix"  # a mix: no node of its own
    ]


def _unpinned_text(node_id: int, what: str) -> str:
    return (
        f"warning: {what}: no device entry pins node {node_id}; the channel reads whichever "
        f"device is numbered {node_id} automatically (plug order). Pin one with "
        f"`node_id: {node_id}`"
    )


def _where(output: OutputConfig) -> Where:
    if output.where is None:  # a Config built in code
        return Where("<config>", 0, "outputs")
    suffix = ".channels" if output.channels is not None else ""
    return Where(output.where.source, output.where.line, output.where.key + suffix)
