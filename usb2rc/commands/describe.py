"""`usb2rc describe FILE | --hex HEX | --known [--json] [--reports N]`: what usb2rc reads in
a device.

Prints the parsed layout of a HID report descriptor (from a hid-recorder file or raw hex):
each input field (report ID, usage, bit offset / size, logical range, null state), the
buttons, the top-level application, and the default C2-16B mapping the device would get
(with its neutral guard: from the device database when the file's vid:pid is in it). For a
hid-recorder file also the decoded values of its first N recorded reports.

`--known` lists the device database instead (usb2rc/data/devices.yaml): each known device,
its axes' roles and where they rest, and the public source of each entry.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from usb2rc.hid.descriptor import DescriptorError, DeviceLayout, parse_descriptor
from usb2rc.hid.recording import Recording, RecordingError, read_recording
from usb2rc.hid.usages import device_type_name, usage_name
from usb2rc.nodes.binding import default_binding
from usb2rc.nodes.known_devices import KnownDevice, all_devices, lookup


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "describe",
        help="show a HID descriptor's fields and the default mapping it gets",
        description="Parse a HID report descriptor (hid-recorder file or hex) and describe it.",
    )
    parser.add_argument("file", nargs="?", help="a hid-recorder file")
    parser.add_argument("--hex", metavar="HEX", help="the descriptor as hex bytes instead")
    parser.add_argument(
        "--known",
        action="store_true",
        help="list the device database: known devices, their axes' rest and sources",
    )
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument(
        "--reports", type=int, default=10, metavar="N", help="decode the first N reports (10)"
    )
    parser.set_defaults(func=run)


class DescribeError(ValueError):
    pass


def load(args: argparse.Namespace) -> tuple[bytes, Recording | None]:
    if (args.file is None) == (args.hex is None):
        raise DescribeError("give either FILE or --hex HEX (or --known)")
    if args.hex is not None:
        try:
            return bytes.fromhex(args.hex.replace(":", " ")), None
        except ValueError as exc:
            raise DescribeError(f"--hex: not hex bytes: {exc}") from None
    try:
        recording = read_recording(args.file)
    except (OSError, RecordingError) as exc:
        raise DescribeError(str(exc)) from None
    return recording.descriptor, recording


def layout_dict(layout: DeviceLayout) -> dict[str, Any]:
    return {
        "application": usage_name(layout.application),
        "device_type": device_type_name(layout.application),
        "uses_report_ids": layout.uses_report_ids,
        "input_report_lengths": {str(k): v for k, v in layout.input_report_lengths.items()},
        "button_count": layout.button_count,
        "inputs": [
            {
                "index": f.index,
                "report_id": f.report_id,
                "usage": usage_name(f.usage),
                "usage_code": f"0x{f.usage:08X}",
                "occurrence": f.occurrence,
                "bit_offset": f.bit_offset,
                "bit_size": f.bit_size,
                "logical_min": f.logical_min,
                "logical_max": f.logical_max,
                "null": f.has_null,
            }
            for f in layout.inputs
        ],
    }


def decoded_reports(layout: DeviceLayout, recording: Recording, limit: int) -> list[dict[str, Any]]:
    decoder = layout.make_decoder()
    out = []
    for event in recording.events[: max(limit, 0)]:
        ok = decoder.feed(event.report)
        state = decoder.state()
        pressed = [n + 1 for n in range(state.buttons.bit_length()) if state.buttons >> n & 1]
        values = {
            (usage_name(f.usage) + (f" #{f.occurrence + 1}" if f.occurrence else "")): v
            for f, v in zip(layout.inputs, state.values, strict=True)
        }
        out.append({"time_s": event.time_s, "ok": ok, "values": values, "buttons": pressed})
    return out


def text_lines(
    info: dict[str, Any], mapping: list[str], reports: list[dict[str, Any]]
) -> list[str]:
    lines = [
        f"application: {info['application']} (device type {info['device_type']})",
        f"report IDs: {'yes' if info['uses_report_ids'] else 'no'}; input reports "
        + ", ".join(f"ID {k}: {v} bytes" for k, v in info["input_report_lengths"].items()),
        f"buttons: {info['button_count']}",
        "inputs:",
        "  #   id  usage              bits (offset+size)  logical range        null",
    ]
    for f in info["inputs"]:
        label = f["usage"] + (f" #{f['occurrence'] + 1}" if f["occurrence"] else "")
        bits = f"{f['bit_offset']}+{f['bit_size']}"
        span = f"{f['logical_min']}..{f['logical_max']}"
        null = "yes" if f["null"] else "no"
        lines.append(
            f"  {f['index']:<3} {f['report_id']:<3} {label:<18} {bits:<19} {span:<20} {null}"
        )
    lines += ["default C2-16B mapping:", *(f"  {line}" for line in mapping)]
    if reports:
        lines.append(f"first {len(reports)} reports:")
        for r in reports:
            values = " ".join(f"{k}={v}" for k, v in r["values"].items())
            bad = "" if r["ok"] else " (not decoded)"
            lines.append(f"  {r['time_s']:.6f} {values} buttons={r['buttons']}{bad}")
    return lines


def known_dict(device: KnownDevice) -> dict[str, Any]:
    return {
        "vid": f"{device.vid:04x}",
        "pid": f"{device.pid:04x}",
        "name": device.name,
        "kind": device.kind,
        "source": device.source,
        "axes": [
            {"usage": usage_name(a.usage), "role": a.role, "arm": a.arm, "why": a.why}
            for a in device.axes
        ],
    }


def run_known(as_json: bool) -> int:
    devices = all_devices()
    if as_json:
        print(json.dumps([known_dict(d) for d in devices], indent=2))
        return 0
    print(f"{len(devices)} known devices (usb2rc/data/devices.yaml; a config `arm:` overrides):")
    for device in devices:
        print("\n".join(device.describe()))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.known:
        if args.file is not None or args.hex is not None:
            print("usb2rc describe: --known takes no FILE or --hex", file=sys.stderr)
            return 2
        return run_known(args.json)
    try:
        descriptor, recording = load(args)
        layout = parse_descriptor(descriptor)
    except (DescribeError, DescriptorError) as exc:
        print(f"usb2rc describe: {exc}", file=sys.stderr)
        return 2
    info = layout_dict(layout)
    name = recording.name if recording and recording.name else "device"
    known = lookup(recording.vid, recording.pid) if recording else None
    mapping = default_binding(layout, name, known=known).describe()[1:]
    reports = decoded_reports(layout, recording, args.reports) if recording else []
    if args.json:
        info.update(default_mapping=[line.strip() for line in mapping], reports=reports)
        print(json.dumps(info, indent=2))
    else:
        print("\n".join(text_lines(info, [m.strip() for m in mapping], reports)))
    return 0
