"""The MAVLink output's keys in the config (part of config.py's schema; docs/CONFIG.md,
"MAVLink outputs"): `message`, `system_id`, `component_id`, `target_system`,
`target_component`, and the checks only a MAVLink output has: its channel count by message,
MANUAL_CONTROL's layout (x, y, z, r, then buttons), a UDP port's address.
"""

from __future__ import annotations

import difflib

from yaml.nodes import Node

from usb2rc.config_model import MavlinkOptions, OutputConfig
from usb2rc.udp_url import is_udp_url, parse_udp_url
from usb2rc.yamlnodes import NodeReader

Items = dict[str, tuple[Node, Node]]

MAVLINK_KEYS = ("message", "system_id", "component_id", "target_system", "target_component")
# The MAVLink output's facts, here so that the config loads without pymavlink's 2 MB
# dialect (check, icd); usb2rc.outputs.mavlink imports them.
RC_CHANNELS_OVERRIDE, MANUAL_CONTROL = "rc_channels_override", "manual_control"
MESSAGES = (RC_CHANNELS_OVERRIDE, MANUAL_CONTROL)
OVERRIDE_MAX_CHANNELS = 18
MANUAL_AXES = ("x", "y", "z", "r")  # the first four channels of a manual_control output
MANUAL_MAX_BUTTONS = 32  # buttons (bits 0-15) and buttons2 (16-31)
# Bytes on the wire at most (MAVLink 2, unsigned), for the bandwidth of a serial line;
# tests hold them to what pymavlink packs (outputs.mavlink.max_message_bytes).
MESSAGE_BYTES = {RC_CHANNELS_OVERRIDE: 50, MANUAL_CONTROL: 25}
HEARTBEAT_BYTES = 21
BITS_PER_BYTE = 10  # 8N1
ID_RANGES = {
    "system_id": (1, 255),  # 0 is not a valid sender
    "component_id": (1, 255),
    "target_system": (0, 255),  # 0: every system
    "target_component": (0, 255),  # 0: every component
}


def read_mavlink_options(reader: NodeReader, items: Items, path: str) -> MavlinkOptions:
    options: dict[str, str | int] = {}
    if "message" in items:
        message = _message(reader, items["message"][1], f"{path}.message")
        if message is not None:
            options["message"] = message
    for key, (lo, hi) in ID_RANGES.items():
        if key in items:
            value = reader.integer(items[key][1], f"{path}.{key}", lo, hi)
            if value is not None:
                options[key] = value
    return MavlinkOptions(**options)  # type: ignore[arg-type]


def _message(reader: NodeReader, node: Node, path: str) -> str | None:
    value = reader.string(node, path)
    if value is None:
        return None
    if value not in MESSAGES:
        close = difflib.get_close_matches(value.lower(), MESSAGES, n=1)
        reader.error(node, path, f"{value!r} is not valid", ", ".join(MESSAGES), *close[:1])
        return None
    return value


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
    if "channels" in items:
        node = items["channels"][1]
    options = output.mavlink or MavlinkOptions()
    if output.port and not is_udp_url(output.port):
        _check_bandwidth(reader, node, items, path, output, options.message)
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


def baud_needed(message: str, rate_hz: float) -> int:
    """Bits per second a MAVLink output needs on a serial line: its control message each
    tick and a heartbeat a second."""
    return int((MESSAGE_BYTES[message] * rate_hz + HEARTBEAT_BYTES) * BITS_PER_BYTE + 0.999)


def _check_bandwidth(
    reader: NodeReader, node: Node, items: Items, path: str, output: OutputConfig, message: str
) -> None:
    needed = baud_needed(message, output.rate_hz)
    if needed <= output.baudrate:
        return
    most_hz = (output.baudrate / BITS_PER_BYTE - HEARTBEAT_BYTES) / MESSAGE_BYTES[message]
    key = "rate_hz" if "rate_hz" in items else "baudrate" if "baudrate" in items else None
    at = items[key][1] if key else node
    reader.error(
        at,
        f"{path}.{key or 'baudrate'}",
        f"{message} at {output.rate_hz:g} Hz needs {needed} baud, more than the line's "
        f"{output.baudrate}; it carries at most {max(0.0, most_hz):.0f} Hz",
        "a lower rate_hz or a higher baudrate",
    )
