"""`usb2rc check [--config FILE] [--port PORT] [--replay DIR]`: validate a config.

Exit 0 with a one-screen summary of outputs, nodes and channels; exit 2 with every error
found, one `file:line: key: message` per line. The verdict is the last line (`FILE: OK` on
stdout, `N error(s)` on stderr), printed once everything was checked, and the exit status
stays the verdict when whoever reads stdout has gone (`usb2rc check | head -1`).

The config is judged by `config.load_runnable`, the function `usb2rc run` starts with and a
reload (SIGHUP) takes: what `check --port PORT` passes, a daemon started with `--port PORT`
takes on a reload. So an output without a port, with one that exists but cannot be a
serial line (`/dev/null`, a file, a directory), or on the line of another output (`--port`
included) is an error here too. The summary and `--json` give each output the port it
will open (`config.ports.used_ports`: `--port` applied), not the file's.

Warnings (on stderr, `file:line: key: warning: ...`) do not change the exit code: what the
SUMD decoders of PX4, ArduPilot and Betaflight would not take of a SUMD output, SUMD channels
on a node no entry pins, a `feedback:` rule that names an output its device does not have
(when the device's outputs are known by its vid:pid: docs/CONFIG.md, "Feedback") and, with
`--replay DIR`, entries no device in DIR matches and channels that read an axis slot no
device of its node in DIR feeds (`config.unfed`). With
`--replay DIR`, each hid-recorder file in DIR is bound as the daemon would bind that device:
its node and any usage it lacks.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from usb2rc.commands.arguments import replay_dir
from usb2rc.config.mavlink import MavlinkOptions, baud_needed
from usb2rc.config.model import DeviceRef, FeedbackRule
from usb2rc.config.port_url import port_argument
from usb2rc.config.ports import UsedPort, used_ports
from usb2rc.config.udp_url import is_udp_url
from usb2rc.config.unfed import DeviceFeed, unfed_slot_warnings
from usb2rc.configfile import (
    Config,
    ConfigError,
    DeviceConfig,
    OutputConfig,
    Problem,
    load_config,
    load_runnable,
)
from usb2rc.feedback.drivers import known_capabilities
from usb2rc.feedback.rules import missing_outputs
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import DescriptorError, parse_descriptor
from usb2rc.hid.replay import ReplayBackend
from usb2rc.nodes.binding import DeviceBinding, MappingError
from usb2rc.nodes.mapping import Mapping, compile_mapping, match_text
from usb2rc.nodes.node_ids import NodeIdAllocator, NodeIdError
from usb2rc.outputs import protocol
from usb2rc.protocols.crsf.checks import address_warnings
from usb2rc.protocols.sumd.receivers import receiver_warnings
from usb2rc.service.sandbox import sandbox_warnings


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "check",
        help="validate a config file (exit 0 ok, 2 with every error)",
        description="Validate a config: exit 0 with a summary, or 2 with every error found.",
    )
    parser.add_argument("--config", metavar="FILE", help="YAML config (default: zero config)")
    parser.add_argument(
        "--port",
        type=port_argument,
        help="the first output's port, as `usb2rc run --port` would give it",
    )
    parser.add_argument(
        "--replay",
        metavar="DIR",
        type=replay_dir,
        help="also bind each hid-recorder file in DIR as a device",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="one JSON document: the problems as records (file, line, key, message, severity)",
    )
    parser.set_defaults(func=run)


def load_or_default(path: str | None) -> Config:
    """The config at path, or zero config, without its outputs' ports checked (`icd`
    describes the wire, opens nothing). Raises ConfigError (file errors included)."""
    return _file_errors_as_problems(
        path, lambda: Config.default() if not path else load_config(path)
    )


def load_checked(path: str | None, port_override: str | None) -> Config:
    """The config at path, or zero config, as `run --port port_override` would run it
    (`load_runnable`). Raises ConfigError (file errors included)."""
    return _file_errors_as_problems(path, lambda: load_runnable(path, port_override))


def _file_errors_as_problems(path: str | None, load: Callable[[], Config]) -> Config:
    try:
        return load()
    except OSError as exc:
        assert path is not None  # zero config reads no file
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


def describe_output(output: OutputConfig, used: UsedPort | None = None) -> str:
    """One line: protocol, the port it will open (`used`, --port applied), baud, rate and
    what the protocol sends."""
    opened = used.port if used is not None else output.port
    baud = "" if opened and is_udp_url(opened) else f"  {output.baudrate} baud"
    text = f"{output.protocol:<7} {port_text(output, used)}{baud}  {output.rate_hz:g} Hz"
    if output.protocol == "c2-16b":
        lf = "line feed" if output.line_feed else "no line feed"
        return f"{text}  {lf}, service status {output.service_status}"
    if output.protocol == "sumd":
        ranges = "900-2100 us" if output.extended else "1100-1900 us"
        return f"{text}  axes {ranges}"
    if output.protocol == "crsf":
        follow = "follows the module's rate" if output.option("follow_module") else "own rate"
        to = f"to 0x{output.option('address'):02X}"
        return f"{text}  {to}, axes 172..1811 (988-2012 us), {follow}, no frames while failsafe"
    if output.protocol == "mavlink":
        return f"{text}  {mavlink_text(output)}"
    note = protocol(output.protocol).note
    return f"{text}  {note}" if note else text


def port_text(output: OutputConfig, used: UsedPort | None) -> str:
    """The port the output will open, and where it comes from when --port gave it."""
    if used is None or not used.from_option:
        return output.port or "(port from --port)"
    config_port = f"the config's {used.replaced}" if used.replaced else "the config gives none"
    return f"{used.port} (from --port; {config_port})"


def mavlink_text(output: OutputConfig) -> str:
    """The MAVLink output's message, IDs and, on a serial line, the bandwidth it uses."""
    opts = MavlinkOptions.of(output)
    text = (
        f"{opts.message} to system {opts.target_system} component {opts.target_component}, "
        f"as system {opts.system_id} component {opts.component_id}, heartbeat 1 Hz"
    )
    if output.port and is_udp_url(output.port):
        return text + " (UDP: no baud rate)"
    needed = baud_needed(opts.message, output.rate_hz, bool(opts.signing_key_file))
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
    if device.handover is not None:
        parts.append(f"handover button {device.handover.button} -> {device.handover.destination}")
    return f"{device.name}: " + ", ".join(parts or ["nothing mapped"])


def summary(config: Config, mapping: Mapping, port_override: str | None = None) -> list[str]:
    """What the config does, with `--port` applied; the verdict line comes after everything."""
    lines = ["outputs:"]
    for used in used_ports(config, port_override):
        output = used.output
        lines.append(f"  {describe_output(output, used)}")
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


def warnings(config: Config, mapping: Mapping) -> list[Problem]:
    """What a receiver would not take (the config is still good: exit 0)."""
    pinned = mapping.pinned_node_ids()
    return [
        problem
        for output in config.outputs
        for problem in [
            *receiver_warnings(output, mapping.sumd_channels(output), pinned),
            *address_warnings(output),
        ]
    ]


def feedback_warnings(config: Config) -> list[Problem]:
    """A warning at each rule that names an output its device does not have, for a device
    whose outputs usb2rc knows by its vid:pid (a rule for every device drives only those
    that have the output: nothing to warn about)."""
    found = []
    for rule in config.feedback or ():
        usb_id = rule_usb_id(rule, config.devices)
        if usb_id is None or rule.device is None:
            continue
        capabilities = known_capabilities(*usb_id)
        if capabilities is None:
            continue
        device = f"{usb_id[0]:04x}:{usb_id[1]:04x}"
        if rule.device.entry is not None:
            device = f"{rule.device.entry} ({device})"
        for key, what in missing_outputs(rule, capabilities):
            where = rule.where_of(key)
            assert where is not None
            found.append(where.problem(f"warning: {device} has no {what}"))
    return found


def rule_usb_id(rule: FeedbackRule, entries: tuple[DeviceConfig, ...]) -> tuple[int, int] | None:
    """The vid:pid a rule names, itself or through the entry it names (one that matches
    both a vid and a pid); None: not one device."""
    device: DeviceRef | None = rule.device
    if device is None:
        return None
    if device.vid is not None and device.pid is not None:
        return device.vid, device.pid
    entry = next((d for d in entries if d.name == device.entry), None)
    if entry is None or entry.match.vid is None or entry.match.pid is None:
        return None
    return entry.match.vid, entry.match.pid


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


def unmatched_entries(
    mapping: Mapping, devices: list[BoundDevice], directory: str
) -> list[Problem]:
    """A warning at each entry that no replayed device matches (a device that matches but
    cannot be bound is an error of its own)."""
    matched = {id(mapping.entry_for(d.info)) for d in devices}
    return [
        device.where.problem(
            f"warning: no device in {directory} matches entry {device.name!r} "
            f"(match: {match_text(device.match)}); its node waits for it"
        )
        for device in mapping.devices
        if id(device) not in matched
    ]


def unfed_warnings(config: Config, devices: list[BoundDevice]) -> list[Problem]:
    """A warning at each channel that reads an axis slot no replayed device of its node
    feeds (`config.unfed`), naming the devices and the axes they have."""
    feeds = [device_feed(d) for d in devices if d.binding is not None and d.node_id is not None]
    return unfed_slot_warnings(config, feeds, carries_channels)


def device_feed(device: BoundDevice) -> DeviceFeed:
    assert device.binding is not None and device.node_id is not None
    info = device.info
    binding = device.binding
    return DeviceFeed(
        info.product, info.vid, info.pid, device.node_id, binding.axis_slots, binding.where
    )


def carries_channels(name: str) -> bool:
    """Whether outputs of this protocol send channels (C2-16B sends whole nodes)."""
    return protocol(name).channels is not None


@dataclass
class Verdict:
    """Everything `check` found, worked out before a line is printed."""

    config: Config
    out: list[str]  # stdout, without the verdict line
    warnings: list[Problem]
    errors: int  # replayed devices that cannot be bound


def run(args: argparse.Namespace) -> int:
    if args.json:
        document = json_document(args)
        return _printed(lambda: print(json.dumps(document, indent=2)), 0 if document["ok"] else 2)
    try:
        config = load_checked(args.config, args.port)
    except ConfigError as exc:
        errors, count = exc.errors, len(exc.problems)  # errors: the same problem once
        return _printed(lambda: print_errors(errors, count), 2)
    verdict = judge(config, args.replay, args.port)
    return _printed(lambda: print_verdict(verdict), 2 if verdict.errors else 0)


def config_warnings(config: Config, mapping: Mapping) -> list[Problem]:
    """What the config itself may get wrong without being refused: the outputs' far ends,
    the service's sandbox, the feedback rules (text and `--json` alike)."""
    return warnings(config, mapping) + sandbox_warnings(config) + feedback_warnings(config)


def judge(config: Config, directory: str | None, port_override: str | None = None) -> Verdict:
    mapping = compile_mapping(config)
    found = config_warnings(config, mapping)
    verdict = Verdict(config, summary(config, mapping, port_override), found, 0)
    if directory:
        devices, problems = bind_replay(mapping, directory)
        verdict.out += replay_lines(devices, problems)
        verdict.warnings += unmatched_entries(mapping, devices, directory)
        verdict.warnings += unfed_warnings(config, devices)
        verdict.errors = sum(1 for d in devices if d.error)
    return verdict


def print_errors(errors: list[str], count: int) -> None:
    for error in errors:
        print(error, file=sys.stderr)
    print(f"{count} error(s)", file=sys.stderr)


def print_verdict(verdict: Verdict) -> None:
    """The summary, the warnings, then the verdict: the last line says how it ended."""
    print("\n".join(verdict.out), flush=True)
    for warning in verdict.warnings:
        print(warning, file=sys.stderr)
    if verdict.errors:
        print(f"{verdict.config.source}: {verdict.errors} error(s)", file=sys.stderr)
    else:
        print(f"{verdict.config.source}: OK")


def _printed(write: Callable[[], None], code: int) -> int:
    """`code`, once write() printed it out, or when stdout's reader has gone before
    (`check | head -1`): the verdict was reached first, a closed pipe does not change it."""
    try:
        write()
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
    return code


# --------------------------------------------------------------------------- --json
# `usb2rc check --json`: the same verdict as `check`, as one JSON document on stdout.
#
#     {"config": FILE | null, "ok": bool,
#      "problems": [{"file", "line", "key", "message", "severity", "allowed", "suggestion"}],
#      "outputs": [{"protocol", "port", "config_port", "port_from", "baudrate", "rate_hz"}],
#      "replay": [...]}   # replay: with --replay DIR only
#
# An output's `port` is the one it will open (--port applied); `config_port` is the file's.
#
# Every config problem is an `error` (exit 2, as without --json), and every warning the text
# prints is a `warning` (the exit stays 0); with `--replay DIR`, a device
# that cannot be bound is an `error` too (at the config line it names, `recording`: which
# device) and a file in DIR that is no usable recording a `warning` (the exit stays 0, as
# the text summary only lists it).


def problem_record(problem: Problem, severity: str = "error") -> dict[str, Any]:
    return {
        "file": problem.source,
        "line": problem.line,
        "key": problem.key,
        "message": problem.message,
        "severity": severity,
        "allowed": problem.allowed or None,
        "suggestion": problem.suggestion,
    }


def output_records(config: Config, port_override: str | None = None) -> list[dict[str, Any]]:
    """Each output with the port it will open (`port`, --port applied), the config's own
    (`config_port`) and which of the two gave it (`port_from`: "config" or "--port")."""
    return [
        {
            "protocol": used.output.protocol,
            "port": used.port,
            "config_port": used.output.port,
            "port_from": "--port" if used.from_option else "config",
            # a UDP port has no baud rate: null, as `icd` prints "- (UDP)"
            "baudrate": None if used.port and is_udp_url(used.port) else used.output.baudrate,
            "rate_hz": used.output.rate_hz,
        }
        for used in used_ports(config, port_override)
    ]


def device_record(device: BoundDevice) -> dict[str, Any]:
    info = device.info
    return {
        "file": info.path,
        "vid": info.vid,
        "pid": info.pid,
        "product": info.product,
        "used": device.binding is not None and not device.error,
        "node_id": device.node_id,
        "entry": device.binding.name if device.binding is not None else None,
        "error": device.error or None,
    }


# A mapping error names the config line it comes from: `file:line: key: message`.
CONFIG_LINE = re.compile(r"^(?P<file>.+?):(?P<line>\d+): (?P<key>[^\s:]+): (?P<message>.+)$")


def bind_problem(device: BoundDevice) -> dict[str, Any]:
    """A device the config does not fit: at the config line when the error names one (for
    an editor to jump to), else at the recording; `recording` says which device it was."""
    match = CONFIG_LINE.match(device.error)
    if match is None:
        problem = Problem(device.info.path, None, None, device.error)
    else:
        problem = Problem(match["file"], int(match["line"]), match["key"], match["message"])
    return {**problem_record(problem), "recording": device.info.path}


def json_document(args: argparse.Namespace) -> dict[str, Any]:
    """The verdict as one document; `ok` decides the exit status."""
    document: dict[str, Any] = {"config": args.config, "ok": True, "problems": []}
    try:
        config = load_checked(args.config, args.port)
    except ConfigError as exc:
        document["ok"] = False
        document["problems"] = [problem_record(p) for p in exc.problems]
        return document
    document["outputs"] = output_records(config, args.port)
    mapping = compile_mapping(config)
    found = [problem_record(p, "warning") for p in config_warnings(config, mapping)]
    document["problems"] = found
    if args.replay:
        devices, problems = bind_replay(mapping, args.replay)
        unmatched = unmatched_entries(mapping, devices, args.replay)
        document["replay"] = [device_record(d) for d in devices]
        document["problems"] = (
            found
            + [bind_problem(d) for d in devices if d.error]
            + [problem_record(Problem(args.replay, None, None, p), "warning") for p in problems]
            + [problem_record(p, "warning") for p in unmatched]
            + [problem_record(p, "warning") for p in unfed_warnings(config, devices)]
        )
        document["ok"] = not any(d.error for d in devices)
    return document


def check_record(config: Config, port_override: str | None = None) -> dict[str, Any]:
    """`usb2rc check --port port_override`'s verdict on the running config: its summary
    (the ports the daemon opens) and warnings (it has no errors: a config with errors is
    refused at start and on a reload)."""
    verdict = judge(config, None, port_override)
    return {
        "source": config.source,
        "ok": not verdict.errors,
        "summary": verdict.out,
        "warnings": [problem_record(p, "warning") for p in verdict.warnings],
    }
