"""`usb2rc icd [--config FILE] [--format markdown|text] [--replay DIR]`: the application ICD.

The C2-16B ICD leaves the axis and button layout "HID descriptor dependent, must be described
in the application ICD". This writes that document for a config: per Node-ID which device
and usage feeds each axis (signed / unsigned, range, failsafe), each button bit and the hat
bits, and each SUMD output's channel list with its µs ranges. For a receiver-side engineer.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from typing import Any

from usb2rc.commands import controls_describe as describe
from usb2rc.commands.arguments import replay_dir
from usb2rc.commands.check import bind_replay, device_record, load_or_default, output_records
from usb2rc.config.layout import GROUP1_BUTTONS, HAT1_SHIFT
from usb2rc.config.mavlink import MANUAL_AXES, RC_CHANNELS_OVERRIDE, MavlinkOptions
from usb2rc.config.udp_url import is_udp_url
from usb2rc.configfile import (
    HAT_DIRECTIONS,
    AxisConfig,
    Config,
    ConfigError,
    DeviceConfig,
    OutputConfig,
)
from usb2rc.hid.usages import GD_JOYSTICK
from usb2rc.nodes.binding import shaping_text, usage_label
from usb2rc.nodes.guard import DEFAULT_TOLERANCE, default_arm, normalize_arm
from usb2rc.nodes.mapping import ChannelSource, Mapping, compile_mapping
from usb2rc.nodes.scaling import node_button_bit
from usb2rc.outputs import protocol

FORMATS = ("markdown", "text")


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "icd",
        help="write the application ICD (axes, buttons, hats, each output's channels) for a config",
        description="Write the application ICD the C2-16B ICD asks for, from a config: nodes, "
        "axes, buttons, hats, and the channels of each SUMD, CRSF, SBUS and MAVLink output.",
    )
    parser.add_argument("--config", metavar="FILE", help="YAML config (default: zero config)")
    parser.add_argument("--format", choices=FORMATS, default="markdown")
    parser.add_argument(
        "--replay", metavar="DIR", type=replay_dir, help="also describe the devices in DIR"
    )
    parser.add_argument(
        "--json", action="store_true", help="the same tables as one JSON document, for scripts"
    )
    parser.set_defaults(func=run)


def table(headers: Sequence[str], rows: Sequence[Sequence[object]], fmt: str) -> list[str]:
    cells = [[str(c) for c in row] for row in rows]
    if fmt == "markdown":
        lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        return lines + ["| " + " | ".join(row) + " |" for row in cells] + [""]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(headers)]

    def fmt_row(row: Sequence[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()

    return [fmt_row(headers), *(fmt_row(r) for r in cells), ""]


def heading(text: str, level: int, fmt: str) -> list[str]:
    if fmt == "markdown":
        return ["#" * level + " " + text, ""]
    return [text, "=" * len(text) if level == 1 else "-" * len(text), ""]


# --------------------------------------------------------------------------- rows


def axis_source(axis: AxisConfig) -> str:
    if axis.usage is not None:
        return usage_label(axis.usage, axis.occurrence)
    if axis.hat is not None:
        return f"{usage_label(axis.hat, axis.occurrence)} {axis.hat_axis} (-1/0/+1)"
    assert axis.buttons is not None
    return f"HID buttons {axis.buttons[0]} (-) / {axis.buttons[1]} (+)"


def axis_rows(devices: Sequence[DeviceConfig]) -> list[list[object]]:
    rows: list[list[object]] = []
    for device in devices:
        for axis in device.axes:
            kind, span = ("unsigned", "0..65535") if axis.unsigned else ("signed", "-32768..32767")
            failsafe = "hold last" if axis.failsafe is None else axis.failsafe
            rows.append(
                [
                    axis.slot,
                    device.name,
                    axis_source(axis),
                    kind,
                    span,
                    failsafe,
                    shaping_text(axis),
                ]
            )
    return rows


def button_rows(devices: Sequence[DeviceConfig]) -> list[list[object]]:
    rows: list[list[object]] = []
    for device in devices:
        for route in device.buttons:
            group, bit = node_button_bit(route.node)
            rows.append([route.node, group + 1, bit, device.name, f"HID button {route.hid}"])
        for hat in device.hats:
            if isinstance(hat.to, str):  # "hat1": no node buttons
                continue
            label = usage_label(hat.usage, hat.occurrence)
            for direction, node in zip(HAT_DIRECTIONS, hat.to, strict=True):
                if node is not None:
                    group, bit = node_button_bit(node)
                    rows.append([node, group + 1, bit, device.name, f"{label} {direction}"])
    return sorted(rows, key=lambda r: int(str(r[0])))


def hat_rows(devices: Sequence[DeviceConfig]) -> list[list[object]]:
    rows: list[list[object]] = []
    for device in devices:
        for hat in device.hats:
            if hat.to == "hat1":
                label = usage_label(hat.usage, hat.occurrence)
                for d, direction in enumerate(HAT_DIRECTIONS):
                    rows.append([f"SG1_SY{d + 1}", HAT1_SHIFT + d, direction, device.name, label])
    return rows


def default_layout_lines() -> list[str]:
    return [
        "Devices on the default layout (no config entry, or an entry without axes / buttons /",
        "hats) map as the C2-16B ICD's default tables:",
        "",
        "- axes: X, Y, Z, Slider, Rx, Ry, Rz, Dial to the slot of the same name; Wheel and a",
        "  second Slider / Dial to aux1, aux2 in descriptor order, then Simulation Controls",
        "  values (Throttle, Rudder, ...) to a still free aux1 / aux2; each linear over its",
        "  logical range onto -32768..32767 (signed); failsafe: hold last value;",
        "- HID buttons 1-24 -> group 1 bits 0-23; HID buttons 25-56 -> group 2 bits 0-31;",
        "- the first hat switch -> group 1 bits 24-31, one bit per direction: UP, UP-RIGHT,",
        "  RIGHT, DOWN-RIGHT, DOWN, DOWN-LEFT, LEFT, UP-LEFT; centred sets none.",
        "",
    ]


def rc11_rows(mapping: Mapping, output: OutputConfig) -> list[list[object]]:
    """CRSF / SBUS channels: 11-bit values and what a receiver makes of them."""
    rows: list[list[object]] = []
    sources = mapping.sumd_channels(output)
    for i, source in enumerate(sources, start=1):
        digital = output.protocol == "sbus" and i > 16
        if source.kind == "button":
            wire = "flag off / on" if digital else "172 / 1811 (988 / 2012 µs)"
            rows.append([i, source.name, "button", wire])
        else:
            kind = axis_kind(source)
            wire = "flag on above 992" if digital else "172..1811, centre 992 (988..2012 µs)"
            rows.append([i, source.name, kind, wire])
    if len(sources) < 16:
        rows.append([f"{len(sources) + 1}..16", "(not listed)", "", "172 (988 µs)"])
    return rows


def sumd_rows(mapping: Mapping, output: OutputConfig) -> list[list[object]]:
    lo, hi = (900, 2100) if output.extended else (1100, 1900)
    rows: list[list[object]] = []
    for i, source in enumerate(mapping.sumd_channels(output), start=1):
        if source.kind == "button":
            rows.append([i, source.name, "button", "1100 / 1900"])
        else:
            kind = axis_kind(source)
            rows.append([i, source.name, kind, f"{lo}..{hi}"])
    return rows


def axis_kind(source: ChannelSource) -> str:
    """An axis-like channel's kind: a switch, a mix (usb2rc.controls), a signed or unsigned axis."""
    if source.kind in ("switch", "mix"):
        return source.kind
    return "axis, unsigned" if source.unsigned else "axis, signed"


def controls_section(config: Config, fmt: str) -> list[str]:
    """Switches, throttle cuts, mixes and MAVLink actions (docs/CONFIG.md, "Switches")."""
    if not (
        config.switches
        or config.throttle_cuts
        or describe.mix_rows(config)
        or describe.action_rows(config)
    ):
        return []
    lines = heading("Switches, mixes and actions", 2, fmt)
    if config.switches:
        rows = [describe.switch_row(s) for s in config.switches]
        lines += table(list(describe.SWITCH_KEYS), rows, fmt)
    lines += [*describe.cut_lines(config), ""] if config.throttle_cuts else []
    if mixes := describe.mix_rows(config):
        lines += table(list(describe.MIX_KEYS), mixes, fmt)
    if actions := describe.action_rows(config):
        lines += table(list(describe.ACTION_KEYS), actions, fmt)
    return lines


def mavlink_rows(mapping: Mapping, output: OutputConfig) -> list[list[object]]:
    """RC_CHANNELS_OVERRIDE: channel n in µs; MANUAL_CONTROL: x, y, z, r, then button bits."""
    message = MavlinkOptions.of(output).message
    rows: list[list[object]] = []
    for i, source in enumerate(mapping.sumd_channels(output)):
        kind = "button" if source.kind == "button" else "axis"
        if message == RC_CHANNELS_OVERRIDE:
            span = "1000 / 2000" if kind == "button" else "1000..2000 (centre 1500)"
            rows.append([f"chan{i + 1}_raw", source.name, kind, span])
        elif i < len(MANUAL_AXES):
            name = MANUAL_AXES[i]
            lo = 0 if name == "z" else -1000
            span = f"{lo} / 1000" if kind == "button" else f"{lo}..1000"
            rows.append([name, source.name, kind, span])
        else:
            bit = i - len(MANUAL_AXES)
            field = f"buttons bit {bit}" if bit < 16 else f"buttons2 bit {bit - 16}"
            rows.append([field, source.name, kind, "1 pressed"])
    return rows


def mavlink_section(mapping: Mapping, output: OutputConfig, index: int, fmt: str) -> list[str]:
    opts = MavlinkOptions.of(output)
    lines = heading(f"MAVLink output {index} ({output.port or '--port'})", 2, fmt)
    lines += [
        f"{opts.message} at {output.rate_hz:g} Hz to system {opts.target_system} component "
        f"{opts.target_component}, and a HEARTBEAT (MAV_TYPE_GCS) at 1 Hz, from system "
        f"{opts.system_id} component {opts.component_id}. Failsafe (a channel's node is): "
        + (
            "every channel released (0 on 1-8, 65534 on 9-18) for 1 s, then heartbeats only."
            if opts.message == RC_CHANNELS_OVERRIDE
            else "no MANUAL_CONTROL, heartbeats only (the autopilot's manual-control loss)."
        )
        + (
            " Every message signed (MAVLink 2 signing, link id 0)." if opts.signing_key_file else ""
        ),
        "",
    ]
    return lines + table(["field", "source", "kind", "range"], mavlink_rows(mapping, output), fmt)


# --------------------------------------------------------------------------- document


def _baud(output: OutputConfig) -> str:
    """A UDP port has no baud rate (its default 115200 means nothing there)."""
    return "- (UDP)" if output.port and is_udp_url(output.port) else str(output.baudrate)


def node_section(config: Config, node_id: int, fmt: str) -> list[str]:
    devices = [d for d in config.devices if d.node_id == node_id]
    lines = heading(f"Node {node_id}", 2, fmt)
    lines.append("Devices: " + ", ".join(_device_label(d) for d in devices))
    lines.append("")
    configured = [d for d in devices if not d.default_layout]
    if len(configured) < len(devices):
        lines += default_layout_lines()
    rows = axis_rows(configured)
    headers = ["axis", "device", "source", "kind", "range", "failsafe", "shaping"]
    lines += table(headers, rows, fmt) if rows else []
    rows = button_rows(configured)
    lines += table(["button", "group", "bit", "device", "source"], rows, fmt) if rows else []
    rows = hat_rows(configured)
    lines += (
        table(["switch", "group 1 bit", "direction", "device", "hat"], rows, fmt) if rows else []
    )
    return lines + status_lines(devices) + guard_lines(devices)


def guard_lines(devices: Sequence[DeviceConfig]) -> list[str]:
    """What each device must rest at after a plug before its node goes `>`, and its trim
    switches (docs/ICD.md, "Neutral guard"; docs/CONFIG.md, "Trims")."""
    lines = []
    for device in devices:
        if device.default_layout:
            lines.append(
                f"Neutral guard of {device.name}: X, Y and Rz at the centre on a Joystick or "
                "Game Pad, a Simulation Controls Throttle low (the default layout), or as "
                "the device database says (usb2rc describe --known)."
            )
            continue
        rests = [r for r in (_axis_rest(axis) for axis in device.axes) if r]
        lines.append(f"Neutral guard of {device.name}: {', '.join(rests) or 'none'}.")
        for axis in device.axes:
            switch = axis.trim_switch
            if switch is None:
                continue
            by = (
                f"HID buttons {switch.buttons[0]} (-) / {switch.buttons[1]} (+)"
                if switch.buttons
                else f"{usage_label(switch.hat or 0, switch.occurrence)} {switch.hat_axis}"
            )
            lines.append(
                f"Trim switch of {axis.slot} ({device.name}): {by}, step {switch.step:g}, "
                f"limit ±{switch.limit:g}."
            )
    return [*lines, ""] if lines else []


def _axis_rest(axis: AxisConfig) -> str:
    """`x centre`, `z low (±0.05)`, `x centre on a Joystick or Game Pad`; "" when `any`."""
    if axis.arm is not None:
        arm, where = normalize_arm(axis.arm), ""
    else:
        arm = default_arm(axis.usage, GD_JOYSTICK)
        where = " on a Joystick or Game Pad" if arm != default_arm(axis.usage, 0) else ""
    if arm == "any":
        return ""
    tolerance = DEFAULT_TOLERANCE if axis.arm_tolerance is None else axis.arm_tolerance
    return f"{axis.slot} {arm}{where} (±{tolerance:g})"


def status_lines(devices: Sequence[DeviceConfig]) -> list[str]:
    """When the node sends `&` and `%` (docs/ICD.md, "Status priority")."""
    lines = []
    for device in devices:
        handover, battery = device.handover, device.low_battery
        if handover is not None:
            how = "while held" if handover.frames is None else f"{handover.frames} frames a press"
            lines.append(
                f"Status `&` (byte 4 = destination {handover.destination}): HID button "
                f"{handover.button} of {device.name}, {how}; no message code is used."
            )
        if battery is not None:
            source = f"{usage_label(battery.usage, battery.occurrence)} of {device.name}"
            if battery.auto:
                source += " (if the device reports it)"
            lines.append(f"Status `%`: {source} below {battery.below:g} %.")
    return [*lines, ""] if lines else []


def _device_label(device: DeviceConfig) -> str:
    m = device.match
    parts = [f"vid 0x{m.vid:04x}" if m.vid is not None else "", ""]
    parts[1] = f"pid 0x{m.pid:04x}" if m.pid is not None else ""
    parts += [f"{k} {getattr(m, k)!r}" for k in ("serial", "port", "product") if getattr(m, k)]
    return f"{device.name} ({', '.join(p for p in parts if p)})"


def document(config: Config, fmt: str) -> list[str]:
    mapping = compile_mapping(config)
    lines = heading("usb2rc application ICD", 1, fmt)
    lines += [
        f"Config: {config.source}",
        "",
        "Axes are int16 little-endian, X Y Z Slider Rx Ry Rz Dial Aux1 Aux2; a linear axis maps",
        "its HID logical range [min, max] as round((v - min) * 65535 / (max - min)) - 32768",
        "(unsigned: without - 32768). Node buttons 1-24 are group 1 bits 0-23, node buttons",
        f"25-56 group 2 bits 0-31 (button n > {GROUP1_BUTTONS}: bit n - 25); group 1 bits 24-31",
        "are hat1. Unfed axes send 0, unfed bits 0.",
        "Status: `!` in failsafe, else `&` (handover) while asked, else `%` while a battery is",
        "low, else `>`.",
        "",
    ]
    lines += heading("Outputs", 2, fmt)
    rows = [[o.protocol, o.port or "(--port)", _baud(o), f"{o.rate_hz:g}"] for o in config.outputs]
    lines += table(["protocol", "port", "baud", "Hz"], rows, fmt)
    for node_id in sorted(mapping.pinned_node_ids()):
        lines += node_section(config, node_id, fmt)
    lines += heading("Devices without a Node-ID in the config", 2, fmt)
    if config.defaults:
        lines += ["Automatic Node-ID: lowest free from 0, in USB port-path order.", ""]
        lines += default_layout_lines()
    else:
        lines += ["Ignored (defaults: false).", ""]
    for i, output in enumerate(config.outputs):
        if output.protocol == "sumd":
            lines += heading(f"SUMD output {i + 1} ({output.port or '--port'})", 2, fmt)
            lines += table(["channel", "source", "kind", "µs"], sumd_rows(mapping, output), fmt)
        elif output.protocol == "mavlink":
            lines += mavlink_section(mapping, output, i + 1, fmt)
        elif output.protocol in RC11_NOTES:
            name = output.protocol.upper()
            lines += heading(f"{name} output {i + 1} ({output.port or '--port'})", 2, fmt)
            lines += [RC11_NOTES[output.protocol], ""]
            lines += table(["channel", "source", "kind", "wire"], rc11_rows(mapping, output), fmt)
        elif (entry := protocol(output.protocol)).note and entry.scale is not None:
            lines += heading(f"{entry.title} output {i + 1} ({output.port or '--port'})", 2, fmt)
            lines += [entry.note, ""]
            lines += table(["channel", "source", "kind", "wire"], scaled_rows(mapping, output), fmt)
    return lines + controls_section(config, fmt)


def scaled_rows(mapping: Mapping, output: OutputConfig) -> list[list[object]]:
    """The channels of an output whose registry row has a `WireScale`, from that scale;
    channels past the list at the released-button value (what such a session pads with)."""
    entry = protocol(output.protocol)
    scale = entry.scale
    assert scale is not None  # only called for a registry row with one
    axis = f"{scale.axis(-32768)}..{scale.axis(32767)}, centre {scale.axis(0)}"
    button = f"{scale.button(False)} / {scale.button(True)}"
    rows: list[list[object]] = []
    sources = mapping.sumd_channels(output)
    for i, source in enumerate(sources, start=1):
        if source.kind == "button":
            rows.append([i, source.name, "button", button])
        else:
            kind = axis_kind(source)
            rows.append([i, source.name, kind, axis])
    assert entry.channels is not None  # a channel output: its row says how many
    most = entry.channels[1]
    if len(sources) < most:
        rows.append([f"{len(sources) + 1}..{most}", "(not listed)", "", scale.button(False)])
    return rows


RC11_NOTES = {
    "crsf": "RC_CHANNELS_PACKED (0x16) to address 0xEE, 16 × 11 bits. While a listed channel's "
    "node is in failsafe no RC frame is sent: the ExpressLRS module stops and the receiver's "
    'own failsafe takes over (docs/ICD.md, "CRSF failsafe").',
    "sbus": "25-byte frames, 100000 baud 8E2, inverted. While a listed channel's node is in "
    'failsafe the frames carry the frame-lost and failsafe flags (docs/ICD.md, "SBUS output"); '
    "channels 17 and 18 are the digital flags.",
}


def replay_section(config: Config, directory: str, fmt: str) -> list[str]:
    devices, problems = bind_replay(compile_mapping(config), directory)
    lines = heading(f"Devices in {directory}", 2, fmt)
    for dev in devices:
        label = f"{dev.info.product or '?'} ({dev.info.vid:04x}:{dev.info.pid:04x})"
        if dev.binding is None:
            lines.append(f"- {label}: {dev.error or 'ignored'}")
            continue
        lines.append(f"- {label}: node {dev.node_id}")
        lines += [f"    - {line.strip()}" for line in dev.binding.describe()[1:]]
    lines += [f"- problem: {p}" for p in problems]
    return [*lines, ""]


def run(args: argparse.Namespace) -> int:
    if args.json:
        return run_json(args)
    try:
        config = load_or_default(args.config)
    except ConfigError as exc:
        print("\n".join(exc.errors), file=sys.stderr)
        return 2
    lines = document(config, args.format)
    if args.replay:
        lines += replay_section(config, args.replay, args.format)
    print("\n".join(lines).rstrip())
    return 0


# --------------------------------------------------------------------------- --json
# `usb2rc icd --json`: the application ICD's tables as one JSON document, for scripts.
#
# The rows are the ones the markdown / text document above prints, each a
# record; values are the same (an axis range "-32768..32767", a failsafe "hold last" or a
# number):
#
#     {"config": FILE | null,
#      "outputs": [{"protocol", "port", "baudrate" (null for UDP), "rate_hz"}],
#      "nodes": [{"node_id", "devices": [{"name", "match", "default_layout"}],
#                 "axes": [{"slot", "device", "source", "kind", "range", "failsafe", "shaping"}],
#                 "buttons": [{"button", "group", "bit", "device", "source"}],
#                 "hats": [{"switch", "bit", "direction", "device", "hat"}]}],
#      "devices_without_entry": "default layout, automatic node" | "ignored",
#      "sumd": [{"output", "port", "channels": [{"channel", "source", "kind", "us"}]}],
#      "switches": [{"switch", "kind", "buttons", "positions", "int16", "initial",
#                    "failsafe", "slot"}], "throttle_cuts": [{"switch", "channel"}],
#      "mixes": [{"output", "channel", "lines"}],
#      "actions": [{"output", "trigger", "do", "hold_s"}],
#      "replay": [...]}                                   # with --replay DIR only

AXIS_KEYS = ("slot", "device", "source", "kind", "range", "failsafe", "shaping")
BUTTON_KEYS = ("button", "group", "bit", "device", "source")
HAT_KEYS = ("switch", "bit", "direction", "device", "hat")
SUMD_KEYS = ("channel", "source", "kind", "us")


def records(keys: Sequence[str], rows: Sequence[Sequence[object]]) -> list[dict[str, object]]:
    return [dict(zip(keys, row, strict=True)) for row in rows]


def device_entry(device: DeviceConfig) -> dict[str, Any]:
    match = {k: v for k, v in dataclasses.asdict(device.match).items() if v is not None}
    return {"name": device.name, "match": match, "default_layout": device.default_layout}


def node_record(config: Config, node_id: int) -> dict[str, Any]:
    devices = [d for d in config.devices if d.node_id == node_id]
    configured = [d for d in devices if not d.default_layout]
    return {
        "node_id": node_id,
        "devices": [device_entry(d) for d in devices],
        "axes": records(AXIS_KEYS, axis_rows(configured)),
        "buttons": records(BUTTON_KEYS, button_rows(configured)),
        "hats": records(HAT_KEYS, hat_rows(configured)),
    }


def json_document(config: Config) -> dict[str, Any]:
    mapping = compile_mapping(config)
    return {
        "config": config.source,
        "outputs": output_records(config),
        "nodes": [node_record(config, n) for n in sorted(mapping.pinned_node_ids())],
        "devices_without_entry": (
            "default layout, automatic node" if config.defaults else "ignored"
        ),
        "sumd": [
            {
                "output": i + 1,
                "port": out.port,
                "channels": records(SUMD_KEYS, sumd_rows(mapping, out)),
            }
            for i, out in enumerate(config.outputs)
            if out.protocol == "sumd"
        ],
        **describe.controls_record(config),
    }


def run_json(args: argparse.Namespace) -> int:
    try:
        config = load_or_default(args.config)
    except ConfigError as exc:
        print("\n".join(exc.errors), file=sys.stderr)
        return 2
    doc = json_document(config)
    if args.replay:
        devices, problems = bind_replay(compile_mapping(config), args.replay)
        doc["replay"] = [device_record(d) for d in devices]
        doc["replay_problems"] = problems
    print(json.dumps(doc, indent=2, ensure_ascii=False))
    return 0
