"""How each output protocol's running pieces are built: link, session, driver, reader thread.

One `build_<protocol>(context)` per protocol of the registry (`usb2rc.outputs.PROTOCOLS`),
found by name in `BUILDERS` (tests/test_structure.py holds the two lists equal): each makes
the protocol's session (`usb2rc.protocols.<name>.session`) and its link and hands both to
the one generic driver (`usb2rc.lines.driver.LineDriver`). `usb2rc.daemon` calls `build` for
each configured output and only starts and stops what comes back. It lives here, above the
registry, which the config file reader reads and which therefore imports no session or
driver.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from usb2rc.config.mavlink import MavlinkOptions, read_signing_key
from usb2rc.configfile import OutputConfig
from usb2rc.lines.driver import LineDriver
from usb2rc.lines.link import Link
from usb2rc.lines.rx import LinkReader
from usb2rc.lines.serial_link import SerialLink
from usb2rc.lines.session import LineSession
from usb2rc.lines.udp_link import UdpLink, is_udp_url
from usb2rc.nodes.mapping import Mapping
from usb2rc.nodes.table import NodeTable
from usb2rc.outputs import protocol
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session
from usb2rc.protocols.channels import OutputChannels, WireScale
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.ibus import IBUS_SCALE
from usb2rc.protocols.ibus.session import IbusSession
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.sbus.session import SbusSession
from usb2rc.protocols.sumd.channels import SumdChannels
from usb2rc.protocols.sumd.session import SumdSession


@dataclass(frozen=True)
class OutputContext:
    """What a build function gets: the output's name and config, the compiled
    mapping, the node table, the daemon's hooks and version."""

    name: str
    config: OutputConfig
    mapping: Mapping
    table: NodeTable
    on_tick: Callable[[], None] | None = None
    on_first_write: Callable[[], None] | None = None
    version: str = ""
    alone: bool = False  # the daemon's only output: no lead (`lines.driver.LineDriver`)


@dataclass
class BuiltOutput:
    """A running output's pieces: its link, its driver and, when the link is read on its
    own thread (a serial link), the reader. The daemon uses of `link` its `Link` side
    (`open_now()`, `is_open`, `url`, `last_error`, `stats`, `close()`), of `driver` (run by
    the drivers' thread, `lines.driver.DriverThread`) its `stats`, `period_s`, `pace`,
    `last_tick_monotonic` and `protocol_stats()`."""

    link: Link
    driver: LineDriver
    rx: LinkReader | None = None


def _running(ctx: OutputContext, link: Link, session: LineSession, period_s: float) -> BuiltOutput:
    """The driver of `session` over `link`; a serial link gets its reader thread."""
    driver = LineDriver(
        ctx.name,
        link,
        session,
        ctx.table.step_if_due,
        period_s,
        ctx.on_tick,
        ctx.on_first_write,
        alone=ctx.alone,
    )
    rx = LinkReader(f"{ctx.name}-rx", link) if isinstance(link, SerialLink) else None
    return BuiltOutput(link, driver, rx)


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
    session = C2Session(out.port, settings)
    return _running(ctx, SerialLink(out.port, out.baudrate), session, 1.0 / out.rate_hz)


def build_sumd(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    channels = SumdChannels.of(ctx.mapping.sumd_channels(out), out.extended)
    session = SumdSession(out.port, channels, channels.frame_length, out.rate_hz)
    return _running(ctx, SerialLink(out.port, out.baudrate), session, 1.0 / out.rate_hz)


def _scaled_channels(ctx: OutputContext, scale: WireScale) -> OutputChannels:
    sources = ctx.mapping.sumd_channels(ctx.config)
    frame_length = protocol(ctx.config.protocol).frame_length(len(sources))
    return OutputChannels.scaled(sources, scale, frame_length)


def build_crsf(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    channels = _scaled_channels(ctx, RC11_SCALE)
    entry = protocol("crsf")
    module = CrsfModule(
        1.0 / out.rate_hz,
        follow_module=bool(out.option("follow_module")),
        min_interval_s=entry.bits_per_second(1.0, len(channels)) / out.baudrate,
    )
    session = CrsfSession(out.port, channels, module, int(out.option("address")))
    return _running(ctx, SerialLink(out.port, out.baudrate), session, 1.0 / out.rate_hz)


def build_sbus(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    session = SbusSession(out.port, _scaled_channels(ctx, RC11_SCALE), out.rate_hz)
    link = SerialLink(
        out.port, out.baudrate, parity=serial.PARITY_EVEN, stopbits=serial.STOPBITS_TWO
    )
    return _running(ctx, link, session, 1.0 / out.rate_hz)


def build_ibus(ctx: OutputContext) -> BuiltOutput:
    out = ctx.config
    assert out.port
    session = IbusSession(out.port, _scaled_channels(ctx, IBUS_SCALE), out.rate_hz)
    return _running(ctx, SerialLink(out.port, out.baudrate), session, 1.0 / out.rate_hz)


def build_mavlink(ctx: OutputContext) -> BuiltOutput:
    """The registry's build function: a MAVLink output on UDP (`udpout:` / `udpin:`, polled
    by the driver) or on a serial port / URL (read by a reader thread)."""
    from usb2rc.protocols.mavlink import (
        session as mavlink,  # pymavlink's dialect: only with a MAVLink output
    )

    out = ctx.config
    assert out.port
    options = MavlinkOptions.of(out)
    actions = out.option("actions")  # usb2rc.protocols.mavlink.actions
    triggers = ctx.mapping.action_triggers(actions)
    channels = mavlink.MavlinkChannels(ctx.mapping.sumd_channels(out), options.message, triggers)
    key = read_signing_key(options.signing_key_file) if options.signing_key_file else None
    link: Link
    if is_udp_url(out.port):
        call = mavlink.VehicleCall(options.target_system, key, time.time())
        link = UdpLink(out.port, call, options.allow)
    else:
        link = SerialLink(out.port, out.baudrate)
    tick_bytes = mavlink.heartbeat_bytes() + mavlink.max_message_bytes(options.message)
    engine = mavlink.MavlinkEngine(options, key, time.time(), actions)
    session = mavlink.MavlinkSession(out.port, channels, engine, tick_bytes, out.rate_hz)
    return _running(ctx, link, session, 1.0 / out.rate_hz)


BUILDERS: dict[str, Callable[[OutputContext], BuiltOutput]] = {
    "c2-16b": build_c2_16b,
    "sumd": build_sumd,
    "crsf": build_crsf,
    "sbus": build_sbus,
    "ibus": build_ibus,
    "mavlink": build_mavlink,
}


def build(context: OutputContext) -> BuiltOutput:
    """The running pieces of the output `context.config` configures."""
    return BUILDERS[context.config.protocol](context)
