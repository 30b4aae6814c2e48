"""Read the status options of a `devices:` entry: `handover` (`&` frames) and `low_battery`
(`%` frames). Part of the config file's schema (docs/CONFIG.md, "Handover and low battery");
config/devices.py calls these. Every problem goes to the NodeReader, which keeps reading.
"""

from __future__ import annotations

from yaml.nodes import Node, ScalarNode

from usb2rc.config.model import (
    AUTO_LOW_BATTERY,
    LOW_BATTERY_PERCENT,
    MAX_HID_BUTTON,
    Config,
    HandoverConfig,
    LowBatteryConfig,
)
from usb2rc.config.usages import read_usage_occurrence
from usb2rc.config.yamlnodes import NodeReader, show
from usb2rc.hid.usages import GDC_BATTERY_STRENGTH

HANDOVER_KEYS = ("button", "destination", "frames")
LOW_BATTERY_KEYS = ("usage", "occurrence", "below")
MAX_HANDOVER_FRAMES = 1000  # 20 s at 50 Hz: a burst longer than that is a held button
ALLOWED = (
    "true (the default), false, or a mapping of usage (default BatteryStrength), occurrence, below"
)


def read_handover(reader: NodeReader, node: Node, path: str) -> HandoverConfig | None:
    """`handover: {button: 5, destination: 7, frames: 10}` (`frames` optional)."""
    items = reader.mapping(node, path, HANDOVER_KEYS)
    if items is None:
        return None
    values: dict[str, int | None] = {}
    for key, lo, hi in (
        ("button", 1, MAX_HID_BUTTON),
        ("destination", 0, 255),
        ("frames", 1, MAX_HANDOVER_FRAMES),
    ):
        if key in items:
            values[key] = reader.integer(items[key][1], f"{path}.{key}", lo, hi)
        elif key in _HANDOVER_HELP:
            reader.error(node, f"{path}.{key}", "missing", _HANDOVER_HELP[key])
    button, destination = values.get("button"), values.get("destination")
    if button is None or destination is None or ("frames" in items and not values["frames"]):
        return None
    return HandoverConfig(button, destination, values.get("frames"), reader.where(node, path))


_HANDOVER_HELP = {
    "button": f"the device's HID button that asks for the handover, 1..{MAX_HID_BUTTON}",
    "destination": "the Node-ID to hand over to (byte 4 of the `&` frames), 0..255",
}


def read_low_battery(reader: NodeReader, node: Node, path: str) -> LowBatteryConfig | None:
    """`low_battery: false`, or `{usage: BatteryStrength, occurrence: 0, below: 20}`.

    Returns None for `false` (and after a problem, which the reader holds: the config is
    then rejected anyway)."""
    if isinstance(node, ScalarNode):
        value = reader.scalar(node)
        if isinstance(value, bool):
            return AUTO_LOW_BATTERY if value else None
        reader.error(node, path, f"expected false or a mapping, got {show(node)}", ALLOWED)
        return None
    items = reader.mapping(node, path, LOW_BATTERY_KEYS)
    if items is None:
        return None
    usage, occurrence = read_usage_occurrence(reader, items, path, GDC_BATTERY_STRENGTH)
    below: float | None = LOW_BATTERY_PERCENT
    if "below" in items:
        below = reader.number(items["below"][1], f"{path}.below", 0.0, 100.0)
    if usage is None or below is None:
        return None
    return LowBatteryConfig(usage, occurrence, below, False, reader.where(node, path))


def check_handovers(reader: NodeReader, config: Config) -> None:
    """One handover button per pinned node: two would ask `&` for two destinations at once,
    and a receiver must never have to guess where the control goes."""
    first: dict[int, HandoverConfig] = {}
    for device in config.devices:
        handover = device.handover
        if handover is None or handover.where is None or device.node_id is None:
            continue
        owner = first.setdefault(device.node_id, handover)
        if owner is not handover and owner.where is not None:
            line = owner.where.line
            message = f"node {device.node_id} already has a handover button (line {line})"
            reader.report(handover.where.problem(message, "one handover button per node"))
