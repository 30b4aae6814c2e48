"""The MAVLink output's keys in the config (docs/CONFIG.md, "MAVLink outputs"): `message`,
`system_id`, `component_id`, `target_system`, `target_component`, `allow`,
`signing_key_file`, read as the output registry's `Option`s (`OPTION_SPECS`) like every
protocol's own keys, and the MAVLink facts the config, `check` and `icd` need: the signing
key is read here (`read_signing_key`: the file's mode checked, the passphrase hashed).
The checks only a MAVLink output has are the registry's `check` hook,
`usb2rc.config.mavlink_check`.

Imported by the registry (`usb2rc.outputs`), so it imports neither config.model nor pymavlink.
"""

from __future__ import annotations

import dataclasses
import difflib
import ipaddress
import os
import stat
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

from yaml.nodes import Node

from usb2rc.config.actions import read_actions
from usb2rc.config.yamlnodes import NodeReader


class _Configured(Protocol):  # config.model.OutputConfig (which imports this module's options)
    def option(self, name: str) -> Any: ...


@dataclass(frozen=True)
class MavlinkOptions:
    """A MAVLink output's own keys, with their defaults (the registry's Option defaults)."""

    message: str = "rc_channels_override"  # or "manual_control"
    system_id: int = 255  # usb2rc as a GCS: ArduPilot's MAV_GCS_SYSID (SYSID_MYGCS < 4.7)
    component_id: int = 190  # MAV_COMP_ID_MISSIONPLANNER
    target_system: int = 1
    target_component: int = 1  # MAV_COMP_ID_AUTOPILOT1
    allow: tuple[str, ...] = ()  # udpin: senders taken (addresses or CIDRs); empty: any
    signing_key_file: str = ""  # MAVLink 2 signing: the passphrase's file (absolute path)

    @classmethod
    def of(cls, output: _Configured) -> MavlinkOptions:
        """A MAVLink output's options, as configured or defaulted."""
        return cls(**{f.name: output.option(f.name) for f in dataclasses.fields(cls)})


# The MAVLink output's facts, here so that the config loads without pymavlink's 2 MB
# dialect (check, icd); usb2rc.protocols.mavlink.session imports them.
RC_CHANNELS_OVERRIDE, MANUAL_CONTROL = "rc_channels_override", "manual_control"
MESSAGES = (RC_CHANNELS_OVERRIDE, MANUAL_CONTROL)
OVERRIDE_MAX_CHANNELS = 18
MANUAL_AXES = ("x", "y", "z", "r")  # the first four channels of a manual_control output
MANUAL_MAX_BUTTONS = 32  # buttons (bits 0-15) and buttons2 (16-31)
MOST_CHANNELS = max(OVERRIDE_MAX_CHANNELS, len(MANUAL_AXES) + MANUAL_MAX_BUTTONS)
# Bytes on the wire at most (MAVLink 2, unsigned), for the bandwidth of a serial line;
# tests hold them to what pymavlink packs (protocols.mavlink.session.max_message_bytes).
MESSAGE_BYTES = {RC_CHANNELS_OVERRIDE: 50, MANUAL_CONTROL: 25}
HEARTBEAT_BYTES = 21
SIGNATURE_BYTES = 13  # a signed message's link id, timestamp and signature
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


def _allow_entry(reader: NodeReader, node: Node, path: str) -> str | None:
    value = reader.string(node, path)
    if value is None:
        return None
    try:
        return str(ipaddress.ip_network(value, strict=False))
    except ValueError:
        reader.error(
            node, path, f"{value!r} is not an address or network", "192.168.2.1, 10.0.0.0/24"
        )
        return None


def _allow(reader: NodeReader, node: Node, path: str) -> tuple[str, ...]:
    return reader.list_of(node, path, _allow_entry)


def _key_file(reader: NodeReader, node: Node, path: str) -> str | None:
    """The key file's path, relative to the config file's folder unless absolute."""
    value = reader.string(node, path)
    if value is None:
        return None
    if not value:
        reader.error(node, path, "empty", "a file holding the signing passphrase")
        return None
    base = os.path.dirname(os.path.abspath(reader.source))
    return os.path.normpath(os.path.join(base, os.path.expanduser(value)))


class SigningKeyError(ValueError):
    """The signing key file cannot be used; the message names the file and the fix."""


def read_signing_key(path: str) -> bytes:
    """The 32-byte MAVLink 2 signing key of a key file: its first line is a passphrase
    (surrounding whitespace stripped), hashed with SHA-256 as MAVProxy's `signing setup
    PASSPHRASE` and Mission Planner do, so the same passphrase gives the vehicle the same
    key. The file must be readable by its owner only: a key others can read lets them
    fly the vehicle."""
    try:
        mode = os.stat(path).st_mode
        if stat.S_IMODE(mode) & 0o077:
            raise SigningKeyError(
                f"{path}: mode {stat.S_IMODE(mode):04o} lets other users read or change the "
                f"MAVLink signing key; run `chmod 600 {path}`"
            )
        with open(path, "rb") as fh:
            text = fh.read(4096)
    except OSError as exc:
        raise SigningKeyError(f"{path}: {exc.strerror or exc}") from None
    passphrase = text.splitlines()[0].strip() if text.strip() else b""
    if not passphrase:
        raise SigningKeyError(f"{path}: empty; write the signing passphrase on its first line")
    # imported here: hashlib loads OpenSSL's libcrypto (~3.6 MB of RSS), which a daemon
    # without MAVLink signing never needs
    import hashlib

    return hashlib.sha256(passphrase).digest()


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
    allow_doc = "udpin: the addresses or networks (CIDR) a vehicle may call from"
    key_doc = "MAVLink 2 signing: a file (mode 600) whose first line is the passphrase"
    options["allow"] = (_allow, MavlinkOptions.allow, allow_doc)
    options["signing_key_file"] = (_key_file, MavlinkOptions.signing_key_file, key_doc)
    actions_doc = "buttons and switches that arm, disarm, change mode ... (docs/CONFIG.md)"
    options["actions"] = (_actions, (), actions_doc)
    return options


def _actions(reader: NodeReader, node: Node, path: str) -> Any:
    return read_actions(reader, node, path)


def baud_needed(message: str, rate_hz: float, signed: bool = False) -> int:
    """Bits per second a MAVLink output needs on a serial line: its control message each
    tick and a heartbeat a second, each 13 bytes longer when signed."""
    extra = SIGNATURE_BYTES if signed else 0
    per_second = (MESSAGE_BYTES[message] + extra) * rate_hz + HEARTBEAT_BYTES + extra
    return int(per_second * BITS_PER_BYTE + 0.999)


OPTION_SPECS = _options()
