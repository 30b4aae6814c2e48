"""The MAVLink output's keys in the config (docs/CONFIG.md, "MAVLink outputs"): `message`,
`system_id`, `component_id`, `target_system`, `target_component`, read as the output
registry's `Option`s (`OPTION_SPECS`) like every protocol's own keys, and the MAVLink facts
the config, `check` and `icd` need. The checks only a MAVLink output has are the registry's
`check` hook, `usb2rc.config_mavlink_check`.

Imported by the registry (`usb2rc.outputs`), so it imports neither config_model nor pymavlink.
"""

from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

from yaml.nodes import Node

from usb2rc.yamlnodes import NodeReader


class _Configured(Protocol):  # config_model.OutputConfig (which imports the registry)
    def option(self, name: str) -> Any: ...


@dataclass(frozen=True)
class MavlinkOptions:
    """A MAVLink output's own keys, with their defaults (the registry's Option defaults)."""

    message: str = "rc_channels_override"  # or "manual_control"
    system_id: int = 255  # usb2rc as a GCS: ArduPilot's SYSID_MYGCS default
    component_id: int = 190  # MAV_COMP_ID_MISSIONPLANNER
    target_system: int = 1
    target_component: int = 1  # MAV_COMP_ID_AUTOPILOT1

    @classmethod
    def of(cls, output: _Configured) -> MavlinkOptions:
        """A MAVLink output's options, as configured or defaulted."""
        return cls(**{f.name: output.option(f.name) for f in dataclasses.fields(cls)})


# The MAVLink output's facts, here so that the config loads without pymavlink's 2 MB
# dialect (check, icd); usb2rc.outputs.mavlink imports them.
RC_CHANNELS_OVERRIDE, MANUAL_CONTROL = "rc_channels_override", "manual_control"
MESSAGES = (RC_CHANNELS_OVERRIDE, MANUAL_CONTROL)
OVERRIDE_MAX_CHANNELS = 18
MANUAL_AXES = ("x", "y", "z", "r")  # the first four channels of a manual_control output
MANUAL_MAX_BUTTONS = 32  # buttons (bits 0-15) and buttons2 (16-31)
MOST_CHANNELS = max(OVERRIDE_MAX_CHANNELS, len(MANUAL_AXES) + MANUAL_MAX_BUTTONS)
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


def _message(reader: NodeReader, node: Node, path: str) -> str | None:
    value = reader.string(node, path)
    if value is None:
        return None
    if value not in MESSAGES:
        close = difflib.get_close_matches(value.lower(), MESSAGES, n=1)
        reader.error(node, path, f"{value!r} is not valid", ", ".join(MESSAGES), *close[:1])
        return None
    return value


def _mavlink_id(key: str, reader: NodeReader, node: Node, path: str) -> Any:
    low, high = ID_RANGES[key]
    return reader.integer(node, path, low, high)


def _options() -> dict[str, tuple[Any, Any, str]]:
    """(read, default, doc) of each key: the registry makes its `Option`s of them."""
    docs = {
        "system_id": "usb2rc's own MAVLink system ID (a GCS)",
        "component_id": "usb2rc's own MAVLink component ID",
        "target_system": "the vehicle's system ID (0: every system)",
        "target_component": "the autopilot's component ID (0: every component)",
    }
    message_doc = "rc_channels_override or manual_control"
    options: dict[str, tuple[Any, Any, str]] = {
        "message": (_message, MavlinkOptions.message, message_doc)
    }
    for key, doc in docs.items():
        options[key] = (partial(_mavlink_id, key), getattr(MavlinkOptions, key), doc)
    return options


def baud_needed(message: str, rate_hz: float) -> int:
    """Bits per second a MAVLink output needs on a serial line: its control message each
    tick and a heartbeat a second."""
    return int((MESSAGE_BYTES[message] * rate_hz + HEARTBEAT_BYTES) * BITS_PER_BYTE + 0.999)


OPTION_SPECS = _options()
