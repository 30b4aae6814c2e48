"""The starter config `usb2rc init` writes: the plugged devices as the default layout maps them.

Sans-IO: devices (their `DeviceInfo` and parsed `DeviceLayout`) in, YAML text out. The layout
is not decided here: the axes, buttons and hat come from `binding.default_binding` (the
default layout, docs/ICD.md "Default axis layout"), written out as explicit entries so that
a user (or `usb2rc calibrate`) can edit each axis. Every line says which HID usage and
logical range it comes from. Node-IDs are pinned to what the automatic numbering gives the
same devices now (`NodeIdAllocator`, USB port-path order), so the config keeps them.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.config.layout import GROUP1_BUTTONS
from usb2rc.config.model import DEFAULT_BAUDRATE
from usb2rc.configfile import DEFAULT_RATE_HZ
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import DeviceLayout, InputField
from usb2rc.hid.usages import usage_name
from usb2rc.nodes.binding import (
    AxisInfo,
    ButtonRun,
    default_axis_fields,
    default_binding,
    first_hat,
    usage_label,
)
from usb2rc.nodes.node_ids import NodeIdAllocator

COMMENT_COLUMN = 40  # where the end-of-line comments start, so they line up


@dataclass(frozen=True)
class PluggedDevice:
    info: DeviceInfo
    layout: DeviceLayout


@dataclass(frozen=True)
class SkippedDevice:
    info: DeviceInfo
    reason: str  # why init could not read it (permission, descriptor)


def _line(text: str, comment: str = "") -> str:
    if not comment:
        return text
    return f"{text.ljust(COMMENT_COLUMN - 1)} # {comment}"


def yaml_string(text: str) -> str:
    """A double-quoted YAML scalar: JSON's string syntax is valid YAML."""
    return json.dumps(text, ensure_ascii=False)


def device_label(info: DeviceInfo) -> str:
    return f"{info.product or '(no name)'} {info.vid:04x}:{info.pid:04x}"


def entry_names(devices: Sequence[PluggedDevice]) -> list[str]:
    """One unique, shell-friendly name per device, from its product string."""
    names: list[str] = []
    for dev in devices:
        info = dev.info
        base = re.sub(r"[^a-z0-9]+", "-", info.product.lower()).strip("-")
        base = base or f"device-{info.vid:04x}-{info.pid:04x}"
        name, k = base, 2
        while name in names:
            name, k = f"{base}-{k}", k + 1
        names.append(name)
    return names


def match_line(info: DeviceInfo, devices: Sequence[PluggedDevice]) -> str:
    """vid/pid, plus the serial (or the USB port) when another plugged device is alike."""
    alike = [d.info for d in devices if (d.info.vid, d.info.pid) == (info.vid, info.pid)]
    parts = [f"vid: 0x{info.vid:04x}", f"pid: 0x{info.pid:04x}"]
    if len(alike) > 1:
        serials = [other.serial for other in alike]
        ports = [other.port_path for other in alike]
        if info.serial and serials.count(info.serial) == 1:
            parts.append(f"serial: {yaml_string(info.serial)}")
        elif info.port_path and ports.count(info.port_path) == 1:
            parts.append(f"port: {yaml_string(info.port_path)}")
        else:  # two interfaces of one device: only the device path tells them apart
            parts.append(f"port: {yaml_string(info.path)}")
    return "match: {" + ", ".join(parts) + "}"


def _range(field: InputField) -> str:
    return f"logical {field.logical_min}..{field.logical_max}, {field.bit_size} bits"


def axis_lines(layout: DeviceLayout, axis_info: Sequence[AxisInfo | None]) -> list[str]:
    fields = dict(default_axis_fields(layout))
    lines = []
    for info in axis_info:
        if info is None:
            continue
        field = fields[info.slot]
        key = f"{info.slot}:".ljust(8)
        usage = usage_name(field.usage)
        text = f"{key}{{usage: {usage}}}"
        if field.occurrence:
            text = f"{key}{{usage: {usage}, occurrence: {field.occurrence}}}"
        lines.append(_line(f"      {text}", f"{info.source}, {_range(field)}"))
    return lines


def button_lines(runs: Sequence[ButtonRun], button_count: int) -> list[str]:
    """The default layout's button runs, cut at the device's highest button."""
    lines = []
    for run in runs:
        first = run.shift + 1
        last = min(run.shift + run.mask.bit_count(), button_count)
        if last < first:
            continue
        node_first = run.dest + 1 + (GROUP1_BUTTONS if run.group else 0)
        node_last = node_first + last - first
        bits = f"group {run.group + 1} bits {run.dest}-{run.dest + last - first}"
        hid = f'"{first}-{last}": "{node_first}-{node_last}"'
        lines.append(_line(f"      {hid}", f"HID buttons {first}-{last} -> {bits}"))
    return lines


def hat_lines(layout: DeviceLayout) -> list[str]:
    hat = first_hat(layout)
    if hat is None:
        return []
    text = f"      - {{usage: {usage_name(hat.usage)}, to: hat1}}"
    positions = hat.logical_max - hat.logical_min + 1
    comment = f"{usage_label(hat.usage)}, logical {hat.logical_min}..{hat.logical_max}"
    comment += f" ({positions} positions) -> group 1 bits 24-31"
    return ["    hats:", _line(text, comment)]


def unmapped_lines(layout: DeviceLayout) -> list[str]:
    """What the default layout leaves out, so the user knows it is there."""
    used = {f.index for _, f in default_axis_fields(layout)}
    hat = first_hat(layout)
    if hat is not None:
        used.add(hat.index)
    rest = [f for f in layout.inputs if f.index not in used]
    counts = Counter((f.usage, f.logical_min, f.logical_max) for f in rest)
    parts = []
    for (usage, lo, hi), n in counts.items():
        times = f" x{n}" if n > 1 else ""
        parts.append(f"{usage_name(usage)}{times} ({lo}..{hi})")
    if layout.button_count > 56:
        parts.append(f"buttons 57-{layout.button_count}")
    if not parts:
        return []
    return [f"    # not mapped by the default layout: {', '.join(parts)}"]


def device_lines(
    dev: PluggedDevice, name: str, node_id: int, devices: Sequence[PluggedDevice]
) -> list[str]:
    binding = default_binding(dev.layout, name, node_id)
    info = dev.info
    where = info.port_path or info.path
    lines = [
        _line(f"  - name: {name}", f"{device_label(info)}, port {where}"),
        f"    {match_line(info, devices)}",
        _line(f"    node_id: {node_id}", "the Node-ID it gets now, pinned"),
    ]
    axes = axis_lines(dev.layout, binding.axis_info)
    if axes:
        lines += ["    axes:", *axes]
    buttons = button_lines(binding.button_runs, dev.layout.button_count)
    if buttons:
        lines += ["    buttons:", *buttons]
    lines += hat_lines(dev.layout)
    lines += unmapped_lines(dev.layout)
    return lines


def output_lines(port: str | None) -> list[str]:
    port_line = (
        _line(f"    port: {yaml_string(port)}", "`usb2rc run --port` overrides it")
        if port
        else "    # port: /dev/serial0                 # none given: `usb2rc run --port PORT`"
    )
    return [
        "outputs:",
        _line("  - protocol: c2-16b", "SERaero C2-16B (docs/ICD.md)"),
        port_line,
        f"    baudrate: {DEFAULT_BAUDRATE}",
        f"    rate_hz: {DEFAULT_RATE_HZ['c2-16b']}",
    ]


# A switch and a MAVLink action, commented out (docs/CONFIG.md, "Switches", "MAVLink
# actions"): each line's first "# " removed gives keys `check` takes (tests hold it).
SWITCHES_EXAMPLE = (
    "switches:",
    _line("  gear: {toggle: node0.button3}", "each press flips: low / high"),
    "  mode: {steps: [node0.button4, node0.button5], positions: 3, failsafe: 0}",
)
ACTIONS_EXAMPLE = (
    "- protocol: mavlink",
    "  port: udpout:127.0.0.1:14550",
    "  actions:",
    _line("    - {button: node0.button2, do: arm}", "held 1 s"),
    "    - {switch: mode, position: 2, do: {mode: RTL}}",
)


def switches_example() -> list[str]:
    return ['# Switches (docs/CONFIG.md, "Switches"): uncomment to use'] + [
        f"# {line}" for line in SWITCHES_EXAMPLE
    ]


def actions_example() -> list[str]:
    return ['  # MAVLink button actions (docs/CONFIG.md, "MAVLink actions"): uncomment to use'] + [
        f"  # {line}" for line in ACTIONS_EXAMPLE
    ]


def starter_config(
    devices: Sequence[PluggedDevice], port: str | None, skipped: Sequence[SkippedDevice] = ()
) -> str:
    """The YAML text of a config for these devices (given in USB port-path order)."""
    lines = [
        "# usb2rc config written by `usb2rc init` from the devices plugged in: each device as",
        "# the default layout maps it. Next: `usb2rc calibrate --config FILE`, then",
        "# `usb2rc check --config FILE`. Every key is in docs/CONFIG.md.",
        "",
        *output_lines(port),
        *actions_example(),
        "",
        _line("defaults: true", "devices not listed: default layout, automatic Node-ID"),
        "",
        *switches_example(),
        "",
        "devices:" if devices else "devices: []",
    ]
    allocator = NodeIdAllocator()
    for dev, name in zip(devices, entry_names(devices), strict=True):
        lines += device_lines(dev, name, allocator.assign(dev.info), devices)
        lines.append("")
    for skip in skipped:
        lines.append(f"# skipped {device_label(skip.info)}: {skip.reason}")
    return "\n".join(lines).rstrip("\n") + "\n"
