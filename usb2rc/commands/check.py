"""`usb2rc check [--config FILE] [--replay DIR]`: validate a config before anything is sent.

Exit 0 with a one-screen summary of outputs, nodes and channels; exit 2 with every error
found, one `file:line: key: message` per line. With `--replay DIR`, each hid-recorder file in
DIR is bound as the daemon would bind that device: its node and any usage it lacks.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

from usb2rc.binding import DeviceBinding, MappingError
from usb2rc.config import (
    Config,
    ConfigError,
    DeviceConfig,
    OutputConfig,
    Problem,
    load_config,
)
from usb2rc.config_mavlink import MavlinkOptions, baud_needed
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import DescriptorError, parse_descriptor
from usb2rc.hid.node_ids import NodeIdAllocator, NodeIdError
from usb2rc.hid.replay import ReplayBackend
from usb2rc.mapping import Mapping, compile_mapping
from usb2rc.outputs import protocol
from usb2rc.udp_url import is_udp_url


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "check",
        help="validate a config file (exit 0 ok, 2 with every error)",
        description="Validate a config: exit 0 with a summary, or 2 with every error found.",
    )
    parser.add_argument("--config", metavar="FILE", help="YAML config (default: zero config)")
    parser.add_argument(
        "--replay", metavar="DIR", help="also bind each hid-recorder file in DIR as a device"
    )
    parser.set_defaults(func=run)


def load_or_default(path: str | None) -> Config:
    """The config at path, or zero config. Raises ConfigError (file errors included)."""
    if path is None:
        return Config.default()
    try:
        return load_config(path)
    except OSError as exc:
        problem = Problem(path, None, None, f"cannot read: {exc.strerror or exc}")
        raise ConfigError([problem]) from None


@dataclass(frozen=True)
class BoundDevice:
    """One replayed device as the daemon would see it."""

    info: DeviceInfo
    binding: DeviceBinding | None  # None: ignored (defaults: false) or unusable
    node_id: int | None
    error: str = ""  # descriptor / mapping problem


def bind_replay(mapping: Mapping, directory: str) -> tuple[list[BoundDevice], list[str]]:
    """Bind every usable recording in directory, in port-path order; (devices, problems)."""
    backend = ReplayBackend(directory)
    infos = sorted(backend.enumerate(), key=lambda i: i.port_path)
    allocator = NodeIdAllocator(mapping.pinned_node_ids())
    devices = [_bind_one(backend, mapping, allocator, info) for info in infos]
    return devices, list(backend.problems)


def _bind_one(
    backend: ReplayBackend, mapping: Mapping, allocator: NodeIdAllocator, info: DeviceInfo
) -> BoundDevice:
    try:
        device = backend.open(info)
        try:
            layout = parse_descriptor(device.report_descriptor())
        finally:
            device.close()
        binding = mapping.bind(info, layout)
    except (OSError, DescriptorError, MappingError) as exc:
        return BoundDevice(info, None, None, str(exc))
    if binding is None:
        return BoundDevice(info, None, None)
    try:
        node_id = allocator.assign(info, binding.node_id)
    except NodeIdError as exc:
        return BoundDevice(info, binding, None, str(exc))
    return BoundDevice(info, binding, node_id)


# --------------------------------------------------------------------------- summary


def describe_output(output: OutputConfig) -> str:
    port = output.port or "(port from --port)"
    baud = "" if is_udp_url(port) else f"  {output.baudrate} baud"
    text = f"{output.protocol:<7} {port}{baud}  {output.rate_hz:g} Hz"
    if output.protocol == "c2-16b":
        lf = "line feed" if output.line_feed else "no line feed"
        return f"{text}  {lf}, service status {output.service_status}"
    if output.protocol == "sumd":
        ranges = "900-2100 us" if output.extended else "1100-1900 us"
        return f"{text}  axes {ranges}"
    if output.protocol == "crsf":
        follow = "follows the module's rate" if output.option("follow_module") else "own rate"
        return f"{text}  axes 172..1811 (988-2012 us), {follow}, no frames while failsafe"
    if output.protocol == "sbus":
        return f"{text}  8E2, axes 172..1811, frame-lost + failsafe flags while failsafe"
    if output.protocol == "mavlink":
        return f"{text}  {mavlink_text(output)}"
    return text


def mavlink_text(output: OutputConfig) -> str:
    """The MAVLink output's message, IDs and, on a serial line, the bandwidth it uses."""
    opts = MavlinkOptions.of(output)
    text = (
        f"{opts.message} to system {opts.target_system} component {opts.target_component}, "
        f"as system {opts.system_id} component {opts.component_id}, heartbeat 1 Hz"
    )
    if output.port and is_udp_url(output.port):
        return text + " (UDP: no baud rate)"
    needed = baud_needed(opts.message, output.rate_hz)
    return text + f", needs {needed} of {output.baudrate} baud"


def describe_device(device: DeviceConfig) -> str:
    parts = []
    if device.default_layout:
        parts.append("default layout")
    if device.axes:
        parts.append("axes " + " ".join(a.slot for a in device.axes))
    if device.buttons:
        parts.append(f"{len(device.buttons)} buttons")
    for hat in device.hats:
        parts.append("hat1" if hat.to == "hat1" else "hat -> buttons")
    return f"{device.name}: " + ", ".join(parts or ["nothing mapped"])


def summary(config: Config, mapping: Mapping) -> list[str]:
    lines = [f"{config.source}: OK", "outputs:"]
    for output in config.outputs:
        lines.append(f"  {describe_output(output)}")
        if protocol(output.protocol).channels:
            names = [c.name for c in mapping.sumd_channels(output)]
            lines.append(f"    {len(names)} channels: {' '.join(names)}")
    lines.append("nodes:")
    for node_id in sorted(mapping.pinned_node_ids()):
        devices = [d for d in config.devices if d.node_id == node_id]
        lines.append(f"  node {node_id}: " + "; ".join(describe_device(d) for d in devices))
    automatic = [d for d in config.devices if d.node_id is None]
    for device in automatic:
        lines.append(f"  automatic node: {describe_device(device)}")
    other = "default layout, automatic node" if config.defaults else "ignored (defaults: false)"
    lines.append(f"  devices without an entry: {other}")
    return lines


def replay_lines(devices: list[BoundDevice], problems: list[str]) -> list[str]:
    lines = ["replayed devices:"]
    for dev in devices:
        label = f"{dev.info.product or '?'} ({dev.info.vid:04x}:{dev.info.pid:04x})"
        if dev.error:
            lines.append(f"  {label}: ERROR {dev.error}")
        elif dev.binding is None:
            lines.append(f"  {label}: ignored (no entry, defaults: false)")
        else:
            lines.append(f"  {label}: node {dev.node_id} as {dev.binding.name!r}")
            lines.extend(f"    {line}" for line in dev.binding.describe()[1:])
    lines.extend(f"  problem: {p}" for p in problems)
    return lines


def run(args: argparse.Namespace) -> int:
    try:
        config = load_or_default(args.config)
    except ConfigError as exc:
        for error in exc.errors:
            print(error, file=sys.stderr)
        print(f"{len(exc.errors)} error(s)", file=sys.stderr)
        return 2
    mapping = compile_mapping(config)
    print("\n".join(summary(config, mapping)))
    if not args.replay:
        return 0
    devices, problems = bind_replay(mapping, args.replay)
    print("\n".join(replay_lines(devices, problems)))
    return 2 if any(d.error for d in devices) else 0
