"""`usb2rc list [--json] [--replay DIR] [--all] [--config FILE]`: the HID devices present.

For each: vid:pid, product, serial, USB port path, hidraw node, top-level usage, whether
usb2rc would use it, the Node-ID it would get (port-path order, pins from --config), and
why not when it cannot be opened or its descriptor cannot be used.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from usb2rc.commands.arguments import replay_dir
from usb2rc.hid.backend import Backend, DeviceInfo, DevicePermissionError
from usb2rc.hid.choose import choose_backend
from usb2rc.hid.hotplug import sort_by_port_path
from usb2rc.hid.permissions import INSTALL_RULE
from usb2rc.nodes.node_ids import NodeIdAllocator, NodeIdError

if TYPE_CHECKING:
    from usb2rc.hid.descriptor import DeviceLayout


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "list",
        help="list the HID joysticks present and the Node-IDs they would get",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument(
        "--replay", metavar="DIR", type=replay_dir, help="list the recordings in DIR instead"
    )
    parser.add_argument("--all", action="store_true", help="include non-joystick HID devices")
    parser.add_argument("--config", metavar="FILE", help="take Node-ID pins from this config")
    parser.set_defaults(func=run)


@dataclass
class Row:
    info: DeviceInfo
    used: bool = False
    node_id: int | None = None
    problem: str | None = None
    name: str = ""
    notes: list[str] = field(default_factory=list)


def make_backend(replay: str | None) -> Backend:
    return choose_backend(replay)


def load_mapping(path: str | None) -> Any:
    """The compiled mapping of --config, or None (raises ValueError on a bad config)."""
    if not path:
        return None
    from usb2rc.configfile import load_config
    from usb2rc.nodes.mapping import compile_mapping

    return compile_mapping(load_config(path))


class UnreadableDevice(Exception):
    """A device whose layout cannot be read; the message says why (permission, descriptor)."""


def read_layout(backend: Backend, info: DeviceInfo) -> DeviceLayout:
    """Open the device and parse its report descriptor; raises UnreadableDevice."""
    from usb2rc.hid.descriptor import DescriptorError, parse_descriptor

    try:
        device = backend.open(info)
    except DevicePermissionError as exc:
        raise UnreadableDevice(exc.strerror or str(exc)) from None
    except OSError as exc:
        raise UnreadableDevice(f"cannot open: {exc.strerror or exc}") from None
    try:
        return parse_descriptor(device.report_descriptor())
    except (DescriptorError, OSError) as exc:
        raise UnreadableDevice(f"report descriptor unusable: {exc}") from None
    finally:
        device.close()


def inspect(backend: Backend, info: DeviceInfo, mapping: Any) -> Row:
    """Open the device, parse its descriptor, bind it: would usb2rc use it, and if not why."""
    row = Row(info)
    if not info.usable:
        row.problem = f"not a joystick-like device ({info.usage_name})"
        return row
    try:
        layout = read_layout(backend, info)
    except UnreadableDevice as exc:
        row.problem = str(exc)
        return row
    binding = mapping.bind(info, layout) if mapping is not None else None
    if mapping is not None and binding is None:
        row.problem = "ignored by the config"
        return row
    row.used = True
    if binding is not None:
        row.name, row.node_id = binding.name, binding.node_id
    return row


def assign_node_ids(rows: list[Row], mapping: Any) -> None:
    pins = mapping.pinned_node_ids() if mapping is not None else set()
    allocator = NodeIdAllocator(pins)
    for row in rows:
        if row.used:
            try:
                row.node_id = allocator.assign(row.info, row.node_id)
            except NodeIdError as exc:
                row.used, row.problem = False, str(exc)


def row_json(row: Row) -> dict[str, Any]:
    info = row.info
    return {
        "key": info.key,
        "path": info.path,
        "vid": f"{info.vid:04x}",
        "pid": f"{info.pid:04x}",
        "product": info.product,
        "manufacturer": info.manufacturer,
        "serial": info.serial,
        "port_path": info.port_path,
        "hidraw": info.hidraw,
        "usage_page": info.usage_page,
        "usage": info.usage,
        "usage_name": info.usage_name,
        "used": row.used,
        "node_id": row.node_id,
        "name": row.name,
        "problem": row.problem,
    }


def row_lines(row: Row) -> list[str]:
    info = row.info
    node = f"node {row.node_id}" if row.used else "not used"
    lines = [
        f"{info.vid:04x}:{info.pid:04x}  {info.product or '(no name)'}  [{node}]",
        f"    port {info.port_path or '?'}  {info.hidraw or info.path}  {info.usage_name}"
        + (f"  serial {info.serial}" if info.serial else ""),
    ]
    if row.name:
        lines.append(f"    config: {row.name}")
    if row.problem:
        lines.append(f"    why not: {row.problem}")
    return lines


def no_devices_hint(replay: str | None, shown_all: bool = False) -> str:
    """What to try when nothing is listed; `shown_all`: `--all` was given (not suggested)."""
    if replay:
        return f"No devices: no usable hid-recorder files in {replay}."
    found = "No HID devices found." if shown_all else "No HID joysticks found."
    every = (
        "" if shown_all else " `usb2rc list --all` shows every HID device and why it is not used."
    )
    return (
        f"{found} Plug one in, or try `usb2rc list --replay demo` (the built-in recordings; "
        "--replay DIR takes a folder of hid-recorder files). If a device is plugged in but "
        f"missing, check its permissions: install the udev rule with {INSTALL_RULE}.{every}"
    )


def run(args: argparse.Namespace) -> int:
    try:
        mapping = load_mapping(args.config)
    except ImportError as exc:
        print(f"usb2rc list: config support unavailable ({exc}); no pins", file=sys.stderr)
        mapping = None
    except ValueError as exc:
        print(f"usb2rc list: {exc}", file=sys.stderr)
        return 2
    backend = make_backend(args.replay)
    try:
        infos = sort_by_port_path(backend.enumerate(all=True))
    except OSError as exc:
        print(f"usb2rc list: cannot enumerate HID devices: {exc}", file=sys.stderr)
        return 1
    rows = [inspect(backend, info, mapping) for info in infos if args.all or info.usable]
    assign_node_ids(rows, mapping)
    problems = list(getattr(backend, "problems", []))
    if args.json:
        out = {"backend": backend.name, "devices": [row_json(r) for r in rows]}
        print(json.dumps({**out, "problems": problems}, indent=2))
        return 0
    for row in rows:
        print("\n".join(row_lines(row)))
    for problem in problems:
        print(f"problem: {problem}")
    if not rows:
        print(no_devices_hint(args.replay, args.all))
    return 0
