"""The output protocols, one registry entry each, and per protocol its channels.

An output is three pieces, and every protocol has the same shape:

- the sans-IO wire codec, `usb2rc.protocols.<name>` (values → bytes → values);
- the sans-IO line session, `usb2rc.protocols.<name>.session`, on the one session interface
  (`usb2rc.lines.session`), driven by the one generic driver (`usb2rc.lines.driver`);
- the output's channels, from the typed channel references of the config to wire values and
  the frame's failsafe flag (`usb2rc.protocols.channels`, with each protocol's scale).

`PROTOCOLS` below is the one place that lists them: what the config file accepts for each
(`usb2rc.configfile` reads its keys, defaults and channel limits from here; the keys only
some protocols take are in `usb2rc.config.output_options`), how many bytes a frame takes
and how many bit times a byte (the bandwidth check), which decoder `usb2rc decode` uses.
Plain imports only: the registry sits above the codecs and the config model and below the
config file reader, and imports no session, link or driver; the running output is built by
`usb2rc.wiring` (one build function per protocol, found by name; tests/test_structure.py
holds the two lists equal). Adding a protocol is one `OutputProtocol` entry here, its build
function there, plus its codec and session.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from usb2rc.config import mavlink as config_mavlink
from usb2rc.config.mavlink_check import check_mavlink_output
from usb2rc.config.output_options import OPTIONS, Option
from usb2rc.protocols.c2_16b import codec as c2_16b_codec
from usb2rc.protocols.c2_16b.codec import Decoder as C2Decoder
from usb2rc.protocols.channels import WireScale
from usb2rc.protocols.crsf import codec as crsf_codec
from usb2rc.protocols.crsf.codec import CrsfDecoder
from usb2rc.protocols.ibus import IBUS_SCALE
from usb2rc.protocols.ibus import codec as ibus_codec
from usb2rc.protocols.ibus.codec import IbusDecoder
from usb2rc.protocols.sbus import codec as sbus_codec
from usb2rc.protocols.sbus.codec import SbusDecoder
from usb2rc.protocols.sumd import codec as sumd_codec
from usb2rc.protocols.sumd.codec import SumdDecoder


@dataclass(frozen=True)
class OutputProtocol:
    """One output protocol as the rest of usb2rc sees it.

    `channels` is (min, max) for a channel output, None for C2-16B (which sends nodes).
    `frame_length(n)` is the bytes of one frame of n listed channels (the bandwidth check).
    `decoder()` makes the stream decoder `usb2rc decode` uses. The running output is built
    by `usb2rc.wiring.build` (not from here: the sessions and the
    driver sit above this table)."""

    name: str
    summary: str
    default_baudrate: int
    default_rate_hz: float
    frame_length: Callable[[int], int]
    decoder: Callable[[], Any]  # makes the stream decoder `usb2rc decode` uses
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


def _mavlink_decoder() -> Any:
    # Imported when `decode` makes one: pymavlink's dialect costs 60 ms, and every command
    # that reads a config imports this registry.
    from usb2rc.protocols.mavlink.codec import MavlinkDecoder

    return MavlinkDecoder()


def _c2_frame_length(_channels: int) -> int:
    return c2_16b_codec.FRAME_LEN + 1


def _crsf_frame_length(_channels: int) -> int:
    return crsf_codec.RC_FRAME_LEN


def _sbus_frame_length(_channels: int) -> int:
    return sbus_codec.FRAME_LEN


def _ibus_frame_length(_channels: int) -> int:
    return ibus_codec.FRAME_LEN


def _mavlink_frame_length(_channels: int) -> int:
    return max(config_mavlink.MESSAGE_BYTES.values())  # the check hook counts per message


def _sumd_frame_length(channels: int) -> int:
    return sumd_codec.frame_length(max(sumd_codec.MIN_CHANNELS, channels))


PROTOCOLS: dict[str, OutputProtocol] = {
    p.name: p
    for p in (
        OutputProtocol(
            "c2-16b",
            "SERaero C2-16B: a data frame per node, service frames",
            default_baudrate=115200,
            default_rate_hz=50,
            frame_length=_c2_frame_length,
            decoder=C2Decoder,
            options=OPTIONS["c2-16b"],
        ),
        OutputProtocol(
            "sumd",
            "Graupner HoTT SUMD: 2..32 channels",
            default_baudrate=115200,
            default_rate_hz=100,
            frame_length=_sumd_frame_length,
            decoder=SumdDecoder,
            channels=(sumd_codec.MIN_CHANNELS, sumd_codec.MAX_CHANNELS),
            options=OPTIONS["sumd"],
        ),
        OutputProtocol(
            "crsf",
            "CRSF RC_CHANNELS_PACKED to an ExpressLRS / Crossfire module or a flight controller",
            default_baudrate=400000,
            default_rate_hz=250,
            frame_length=_crsf_frame_length,
            decoder=CrsfDecoder,
            channels=(1, 16),
            channels_required=True,
            options=OPTIONS["crsf"],
        ),
        OutputProtocol(
            "sbus",
            "Futaba SBUS: 16 channels, ch17/ch18, frame-lost and failsafe flags (8E2)",
            default_baudrate=sbus_codec.BAUDRATE,
            default_rate_hz=100,
            frame_length=_sbus_frame_length,
            decoder=SbusDecoder,
            bits_per_byte=sbus_codec.BITS_PER_BYTE,
            channels=(1, 18),
            channels_required=True,
            note="8E2, axes 172..1811, frame-lost + failsafe flags while failsafe",
        ),
        OutputProtocol(
            "ibus",
            "FlySky iBus: 14 channels 1000..2000 µs, silent while failsafe",
            default_baudrate=ibus_codec.BAUDRATE,
            # 100 Hz as SUMD and SBUS: FlySky receivers send every 7 ms but flight controllers
            # take any rate, and 32 bytes at 115200 baud fit up to 360 Hz.
            default_rate_hz=100,
            frame_length=_ibus_frame_length,
            decoder=IbusDecoder,
            channels=(1, ibus_codec.CHANNELS),
            channels_required=True,
            note="32-byte frames, 14 channels, 115200 baud 8N1; channels past the list "
            "1000 µs. While a listed channel's node is in failsafe no frame is sent: the "
            'receiver\'s own failsafe takes over (docs/ICD.md, "iBus output").',
            scale=IBUS_SCALE,
            display_name="iBus",
        ),
        OutputProtocol(
            "mavlink",
            "MAVLink 2 RC_CHANNELS_OVERRIDE or MANUAL_CONTROL and a GCS heartbeat, serial or UDP",
            default_baudrate=115200,
            default_rate_hz=50,
            frame_length=_mavlink_frame_length,
            decoder=_mavlink_decoder,
            channels=(1, config_mavlink.MOST_CHANNELS),
            options=OPTIONS["mavlink"],
            own_checks=check_mavlink_output,
        ),
    )
}


def protocol(name: str) -> OutputProtocol:
    """The registry entry of a protocol name (KeyError for an unknown one)."""
    return PROTOCOLS[name]


def option_keys() -> tuple[str, ...]:
    """Every protocol-only key, in registry order."""
    keys: dict[str, None] = {}
    for entry in PROTOCOLS.values():
        keys.update(dict.fromkeys(entry.options))
    return tuple(keys)
