"""The MAVLink output: its row in the output registry, its own config keys and how it is
built (a `MavlinkSession` on UDP or a serial link); importing this module registers it.
Nothing here loads pymavlink: its 2 MB dialect is imported with a MAVLink output, or with
`decode --protocol mavlink`."""

from __future__ import annotations

import time
from typing import Any

from usb2rc.config import mavlink as config_mavlink
from usb2rc.config.mavlink import MavlinkOptions, read_signing_key
from usb2rc.config.mavlink_check import check_mavlink_output
from usb2rc.config.output_options import Option
from usb2rc.lines.udp_link import UdpLink, is_udp_url
from usb2rc.protocols.registry import OutputProtocol, register
from usb2rc.wiring import BuiltOutput, OutputContext, on_serial_port, running

OPTIONS = {key: Option(*spec) for key, spec in config_mavlink.OPTION_SPECS.items()}


def build(context: OutputContext) -> BuiltOutput:
    """A MAVLink output on UDP (`udpout:` / `udpin:`, polled by the driver) or on a serial
    port / URL (read by a reader thread)."""
    from usb2rc.protocols.mavlink import session as mavlink  # pymavlink's dialect

    out = context.config
    assert out.port
    options = MavlinkOptions.of(out)
    actions = out.option("actions")  # usb2rc.protocols.mavlink.actions
    triggers = context.mapping.action_triggers(actions)
    sources = context.mapping.sumd_channels(out)
    channels = mavlink.MavlinkChannels(sources, options.message, triggers)
    key = read_signing_key(options.signing_key_file) if options.signing_key_file else None
    udp = None
    if is_udp_url(out.port):
        call = mavlink.VehicleCall(options.target_system, key, time.time())
        udp = UdpLink(out.port, call, options.allow)
    tick_bytes = mavlink.heartbeat_bytes() + mavlink.max_message_bytes(options.message)
    engine = mavlink.MavlinkEngine(options, key, time.time(), actions)
    session = mavlink.MavlinkSession(out.port, channels, engine, tick_bytes, out.rate_hz)
    if udp is None:
        return on_serial_port(context, session)
    return running(context, udp, session)


def _decoder() -> Any:
    # Imported when `decode` makes one: pymavlink's dialect costs 60 ms, and every command
    # that reads a config imports the registry.
    from usb2rc.protocols.mavlink.codec import MavlinkDecoder

    return MavlinkDecoder()


def _frame_length(_channels: int) -> int:
    return max(config_mavlink.MESSAGE_BYTES.values())  # the check hook counts per message


MAVLINK = register(
    OutputProtocol(
        "mavlink",
        "MAVLink 2 RC_CHANNELS_OVERRIDE or MANUAL_CONTROL and a GCS heartbeat, serial or UDP",
        default_baudrate=115200,
        default_rate_hz=50,
        frame_length=_frame_length,
        decoder=_decoder,
        build=build,
        channels=(1, config_mavlink.MOST_CHANNELS),
        options=OPTIONS,
        own_checks=check_mavlink_output,
    )
)
