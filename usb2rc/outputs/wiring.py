"""How each output protocol's running pieces are built: link, output thread, RX thread.

The registry (`usb2rc.outputs.PROTOCOLS`) names one `build_<protocol>(context)` here per
protocol; `usb2rc.daemon` calls it for each configured output and only starts and stops
what comes back.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from usb2rc.config.load import OutputConfig
from usb2rc.config.mavlink import MavlinkOptions, read_signing_key
from usb2rc.nodes.mapping import Mapping
from usb2rc.nodes.table import NodeTable
from usb2rc.outputs import protocol
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.channels import IBUS_SCALE, RC11_SCALE, OutputChannels, WireScale
from usb2rc.protocols.sumd.channels import SumdChannels
from usb2rc.rc_sessions import CrsfSession, IbusSession, SbusSession
from usb2rc.runtime.worker import Worker
from usb2rc.scheduler import (
    C2Output,
    ChannelOutput,
    CrsfOutput,
    MavlinkOutput,
    ReplyRx,
    RxThread,
    SumdOutput,
    TickThread,
    queue_cap,
)
from usb2rc.session import C2Settings, frames_per_tick
from usb2rc.transport import SerialLink
from usb2rc.transport_udp import UdpLink, is_udp_url


@dataclass(frozen=True)
class OutputContext:
    """What a build function gets: the output's thread name and config, the compiled
    mapping, the node table, the daemon's hooks and version."""

    name: str
    config: OutputConfig
    mapping: Mapping
    table: NodeTable
    on_tick: Callable[[], None] | None = None
    on_first_write: Callable[[], None] | None = None
    version: str = ""


@dataclass
class BuiltOutput:
    """A running output's pieces: its link, its thread and, when it reads, its RX thread.

    The daemon uses of `link` what `SerialLink` (and MAVLink's `UdpLink`) offers:
    `open_now()`, `is_open`, `url`, `last_error`, `stats` (`LinkStats`) and `close()`; of
    `thread` a `TickThread`'s `start`, `stop`, `join`, `stats`, `period_s`, `pace`,
    `last_tick_monotonic` and `protocol_stats()`."""

    link: SerialLink | UdpLink
    thread: TickThread
    rx: Worker | None = None


def build_c2_16b(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    settings = C2Settings(
        rate_hz=out.rate_hz,
        baudrate=out.baudrate,
        line_feed=out.line_feed,
        binary_status=out.service_status == "binary",
        version=ctx.version,
    )
    frame_len = c2_16b.FRAME_LEN + (1 if out.line_feed else 0)
    tick_bytes = frames_per_tick(out.baudrate, out.rate_hz, frame_len) * frame_len
    link = SerialLink(out.port, out.baudrate, max_queued_bytes=queue_cap(tick_bytes))
    c2 = C2Output(ctx.name, link, ctx.table, settings, ctx.on_tick, ctx.on_first_write)
    return BuiltOutput(link, c2, RxThread(f"{ctx.name}-rx", link, c2.received))


def build_sumd(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    channels = SumdChannels.of(ctx.mapping.sumd_channels(out), out.extended)
    link = SerialLink(out.port, out.baudrate, max_queued_bytes=queue_cap(channels.frame_length))
    thread = SumdOutput(
        ctx.name, link, ctx.table, channels, out.rate_hz, ctx.on_tick, ctx.on_first_write
    )
    return BuiltOutput(link, thread)


def _scaled_channels(ctx: OutputContext, scale: WireScale) -> OutputChannels:
    sources = ctx.mapping.sumd_channels(ctx.config)
    frame_length = protocol(ctx.config.protocol).frame_length(len(sources))
    return OutputChannels.scaled(sources, scale, frame_length)


def build_crsf(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    channels = _scaled_channels(ctx, RC11_SCALE)
    entry = protocol("crsf")
    session = CrsfSession(
        1.0 / out.rate_hz,
        follow_module=bool(out.option("follow_module")),
        address=int(out.option("address")),
        min_interval_s=entry.bits_per_second(1.0, len(channels)) / out.baudrate,
    )
    link = SerialLink(out.port, out.baudrate, max_queued_bytes=queue_cap(channels.frame_length))
    thread = CrsfOutput(
        ctx.name, link, ctx.table, channels, session, ctx.on_tick, ctx.on_first_write
    )
    return BuiltOutput(link, thread, ReplyRx(f"{ctx.name}-rx", link, thread.received.put))


def build_sbus(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    channels = _scaled_channels(ctx, RC11_SCALE)
    link = SerialLink(
        out.port,
        out.baudrate,
        max_queued_bytes=queue_cap(channels.frame_length),
        parity=serial.PARITY_EVEN,
        stopbits=serial.STOPBITS_TWO,
    )
    thread = ChannelOutput(
        ctx.name,
        link,
        ctx.table,
        channels,
        SbusSession(),
        out.rate_hz,
        ctx.on_tick,
        ctx.on_first_write,
    )
    return BuiltOutput(link, thread)


def build_ibus(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    channels = _scaled_channels(ctx, IBUS_SCALE)
    link = SerialLink(out.port, out.baudrate, max_queued_bytes=queue_cap(channels.frame_length))
    thread = ChannelOutput(
        ctx.name,
        link,
        ctx.table,
        channels,
        IbusSession(),
        out.rate_hz,
        ctx.on_tick,
        ctx.on_first_write,
    )
    return BuiltOutput(link, thread)


def build_mavlink(ctx: OutputContext) -> BuiltOutput:
    """The registry's build function: a MAVLink output on UDP (`udpout:` / `udpin:`, read
    by the output thread) or on a serial port / URL (read by an RX thread)."""
    from usb2rc.outputs import mavlink  # pymavlink's dialect: only with a MAVLink output

    out = ctx.config
    assert out.port
    options = MavlinkOptions.of(out)
    actions = out.option("actions")  # usb2rc.protocols.mavlink.actions
    triggers = ctx.mapping.action_triggers(actions)
    channels = mavlink.MavlinkChannels(ctx.mapping.sumd_channels(out), options.message, triggers)
    key = read_signing_key(options.signing_key_file) if options.signing_key_file else None
    link: SerialLink | UdpLink
    if is_udp_url(out.port):
        call = mavlink.VehicleCall(options.target_system, key, time.time())
        link = UdpLink(out.port, call, options.allow)
    else:
        tick_bytes = mavlink.heartbeat_bytes() + mavlink.max_message_bytes(options.message)
        link = SerialLink(out.port, out.baudrate, max_queued_bytes=queue_cap(tick_bytes))
    thread = MavlinkOutput(
        ctx.name,
        link,
        ctx.table,
        channels,
        mavlink.MavlinkSession(options, key, time.time(), actions),
        out.rate_hz,
        ctx.on_tick,
        ctx.on_first_write,
    )
    if isinstance(link, UdpLink):
        return BuiltOutput(link, thread)
    return BuiltOutput(link, thread, ReplyRx(f"{ctx.name}-rx", link, thread.received.put))
