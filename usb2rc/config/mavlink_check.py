"""The checks only a MAVLink output has (the output registry's `own_checks`, run by the
config file reader after the keys are read): its channel count by message, MANUAL_CONTROL's
layout (x, y, z, r, then buttons), a UDP port's address (`allow` only on udpin), the signing key
file (readable, owner only), and on a serial line the bandwidth of the control message each
tick plus a heartbeat a second. Each problem is at the line of its key
(the output's own line when the key is missing); docs/CONFIG.md, "MAVLink outputs".
"""

from __future__ import annotations

from yaml.nodes import Node

from usb2rc.config.mavlink import (
    BITS_PER_BYTE,
    HEARTBEAT_BYTES,
    MANUAL_AXES,
    MANUAL_MAX_BUTTONS,
    MESSAGE_BYTES,
    OVERRIDE_MAX_CHANNELS,
    RC_CHANNELS_OVERRIDE,
    SIGNATURE_BYTES,
    MavlinkOptions,
    SigningKeyError,
    baud_needed,
    read_signing_key,
)
from usb2rc.config.model import OutputConfig
from usb2rc.config.udp_url import is_udp_url, parse_udp_url
from usb2rc.config.yamlnodes import NodeReader

Items = dict[str, tuple[Node, Node]]


def check_mavlink_output(
    reader: NodeReader, node: Node, items: Items, path: str, output: OutputConfig
) -> None:
    """The channel count and layout for the message, and a UDP port's address; each problem
    at the line of its key (the output's own line when the key is missing)."""
    if output.port and is_udp_url(output.port):
        try:
            parse_udp_url(output.port)
        except ValueError as exc:
            at = items["port"][1] if "port" in items else node
            reader.error(at, f"{path}.port", str(exc), "udpout:HOST:PORT, udpin:HOST:PORT")
    options = MavlinkOptions.of(output)
    _check_link_keys(reader, items, path, output, options)
    if "channels" in items:
        node = items["channels"][1]
    if output.port and not is_udp_url(output.port):
        _check_bandwidth(reader, node, items, path, output, options)
    channels = output.channels
    if options.message == RC_CHANNELS_OVERRIDE:
        if channels is not None and not 1 <= len(channels) <= OVERRIDE_MAX_CHANNELS:
            reader.error(
                node, f"{path}.channels", f"{len(channels)} channels", f"1..{OVERRIDE_MAX_CHANNELS}"
            )
        return
    axes = len(MANUAL_AXES)
    most = axes + MANUAL_MAX_BUTTONS
    if channels is None:
        reader.error(
            node,
            f"{path}.channels",
            "missing: manual_control needs its channels: x, y, z, r, then up to 32 buttons",
            "nodeN.<slot> or nodeN.buttonK",
        )
        return
    if not axes <= len(channels) <= most:
        reader.error(node, f"{path}.channels", f"{len(channels)} channels", f"{axes}..{most}")
    wheres = output.channel_wheres
    for i, (ref, where) in enumerate(zip(channels, wheres, strict=False)):
        if i >= axes and ref.kind != "button":
            message = f"{ref.name}: manual_control channels after x, y, z, r are buttons"
            reader.report(where.problem(message, "nodeN.buttonK"))


def _check_link_keys(
    reader: NodeReader, items: Items, path: str, output: OutputConfig, options: MavlinkOptions
) -> None:
    """`allow` only where something calls (udpin); a signing key file usb2rc can use."""
    udpin = (output.port or "").startswith("udpin:")
    if options.allow and not udpin:
        reader.error(
            items["allow"][1],
            f"{path}.allow",
            "only a udpin: port takes calls from other addresses (udpout and serial talk "
            "to one far end)",
            "remove allow, or listen with udpin:HOST:PORT",
        )
    if options.signing_key_file:
        try:
            read_signing_key(options.signing_key_file)
        except SigningKeyError as exc:
            reader.error(items["signing_key_file"][1], f"{path}.signing_key_file", str(exc))


def _check_bandwidth(
    reader: NodeReader,
    node: Node,
    items: Items,
    path: str,
    output: OutputConfig,
    options: MavlinkOptions,
) -> None:
    message, signed = options.message, bool(options.signing_key_file)
    needed = baud_needed(message, output.rate_hz, signed)
    if needed <= output.baudrate:
        return
    extra = SIGNATURE_BYTES if signed else 0
    line_bytes = output.baudrate / BITS_PER_BYTE - HEARTBEAT_BYTES - extra
    most_hz = line_bytes / (MESSAGE_BYTES[message] + extra)
    key = "rate_hz" if "rate_hz" in items else "baudrate" if "baudrate" in items else None
    at = items[key][1] if key else node
    reader.error(
        at,
        f"{path}.{key or 'baudrate'}",
        f"{message} at {output.rate_hz:g} Hz needs {needed} baud, more than the line's "
        f"{output.baudrate}; it carries at most {max(0.0, most_hz):.0f} Hz",
        "a lower rate_hz or a higher baudrate",
    )
