"""Read a usage (and which field of it) from a config value: shared by the device entries
(config/devices.py) and their status options (config/status.py)."""

from __future__ import annotations

from yaml.nodes import Node

from usb2rc.config.yamlnodes import Items, NodeReader, show
from usb2rc.hid.usages import usage_from_name

USAGES_ALLOWED = (
    "a usage name such as X, Y, Z, Rx, Ry, Rz, Slider, Dial, Wheel, HatSwitch, Throttle, "
    "Rudder, Aileron, Elevator, Accelerator, Brake, Steering, or 0xPPPPUUUU"
)


def read_usage(reader: NodeReader, node: Node, path: str) -> int | None:
    """A usage by name (`X`, `Throttle`, case-insensitive) or number (`0xPPPPUUUU`)."""
    value = reader.scalar(node)
    text = f"0x{value:08X}" if isinstance(value, int) and not isinstance(value, bool) else None
    text = text or (value if isinstance(value, str) else None)
    if text is not None:
        try:
            return usage_from_name(text)
        except (KeyError, ValueError):
            pass
    reader.error(node, path, f"unknown usage {show(node)}", USAGES_ALLOWED)
    return None


def read_usage_occurrence(
    reader: NodeReader, items: Items, path: str, default: int
) -> tuple[int | None, int]:
    """A mapping's `usage` (default `default`) and `occurrence` (default 0); a bad usage is
    None (the reader holds the problem)."""
    usage: int | None = default
    if "usage" in items:
        usage = read_usage(reader, items["usage"][1], f"{path}.usage")
    occurrence = 0
    if "occurrence" in items:
        occurrence = reader.integer(items["occurrence"][1], f"{path}.occurrence", 0, 255) or 0
    return usage, occurrence
