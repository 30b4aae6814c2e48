"""Cross-checks over a read config: clashes on a node, SUMD channels nobody feeds, ports.

Part of the config file's schema (docs/CONFIG.md): two sources on one axis slot or node bit, a
default-layout entry sharing its node, and a SUMD channel whose node / slot / button no
device feeds are problems naming both places. `port_problems` is what would fail when the
outputs open: an output without a port, a port that exists but is no serial line.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field

from usb2rc.config.model import ChannelRef, Config, DeviceConfig
from usb2rc.config.yamlnodes import NodeReader, Problem, Where


@dataclass
class _NodeUse:
    """What the devices pinned to one Node-ID claim, for clash detection."""

    axes: dict[str, str] = field(default_factory=dict)  # slot -> "device (line)"
    bits: dict[str, str] = field(default_factory=dict)  # "button 5" / "hat1 up" -> owner
    everything: str | None = None  # a default-layout device claims all of it


def device_claims(device: DeviceConfig) -> tuple[list[tuple[str, Where]], list[tuple[str, Where]]]:
    """(axis slots, node bits) the entry feeds, each with where it is configured."""
    axes = [(axis.slot, axis.where) for axis in device.axes]
    bits = [(f"button {route.node}", route.where) for route in device.buttons]
    for hat in device.hats:
        if hat.to == "hat1":
            bits.append(("hat1 (group 1 bits 24-31)", hat.where))
        else:
            bits.extend((f"button {b}", hat.where) for b in hat.to if b is not None)
    return axes, bits


def check_clashes(reader: NodeReader, config: Config) -> None:
    nodes: dict[int, _NodeUse] = {}
    for device in config.devices:
        axes, bits = device_claims(device)
        _check_own_clashes(reader, device, bits)
        if device.node_id is None:
            continue
        use = nodes.setdefault(device.node_id, _NodeUse())
        _check_node_clash(reader, device, use, axes, bits)


def _check_own_clashes(
    reader: NodeReader, device: DeviceConfig, bits: list[tuple[str, Where]]
) -> None:
    seen: dict[str, Where] = {}
    for bit, where in bits:
        if bit in seen:
            reader.report(where.problem(f"{bit} is already fed from line {seen[bit].line}"))
        seen.setdefault(bit, where)


def _check_node_clash(
    reader: NodeReader,
    device: DeviceConfig,
    use: _NodeUse,
    axes: list[tuple[str, Where]],
    bits: list[tuple[str, Where]],
) -> None:
    owner = f"device {device.name!r} (line {device.where.line})"
    node = f"node {device.node_id}"
    if use.everything or (device.default_layout and (use.axes or use.bits)):
        first = use.everything or next(iter({**use.axes, **use.bits}.values()))
        message = (
            f"{node} is already fed by {first}; a device on the default layout needs a node "
            "of its own (or list its axes, buttons and hats)"
        )
        reader.report(device.where.problem(message, key_suffix=".node_id"))
        return
    if device.default_layout:
        use.everything = owner
        return
    for slot, where in axes:
        if slot in use.axes:
            reader.report(where.problem(f"{node} axis {slot} is already fed by {use.axes[slot]}"))
        use.axes.setdefault(slot, owner)
    for bit, where in bits:
        if use.bits.get(bit, owner) != owner:
            reader.report(where.problem(f"{node} {bit} is already fed by {use.bits[bit]}"))
        use.bits.setdefault(bit, owner)


def check_channels(reader: NodeReader, config: Config) -> None:
    for output in config.outputs:
        if output.channels is None:
            continue
        for channel, where in zip(output.channels, output.channel_wheres, strict=False):
            refs = [i.source for i in channel.inputs] if channel.kind == "mix" else [channel]
            for ref in refs:
                problem = channel_problem(config, ref)
                if problem:
                    reader.report(where.problem(problem))


def channel_problem(config: Config, ref: ChannelRef) -> str | None:
    """Why a SUMD channel cannot be fed, or None. Bad names never become a ChannelRef.
    Switches and mixes are config_controls' to check."""
    if ref.kind not in ("axis", "button"):
        return None
    node_id, name = ref.node_id, ref.name
    pinned = [d for d in config.devices if d.node_id == node_id]
    if not pinned:
        if config.defaults:
            return None  # an automatically numbered node may have it
        return f"{name}: no device is pinned to node {node_id} and defaults is false"
    if any(d.default_layout for d in pinned):
        return None
    claims = [device_claims(d) for d in pinned]
    if ref.kind == "axis":
        if any(slot == ref.slot for axes, _ in claims for slot, _ in axes):
            return None
        return f"{name}: no device feeds axis {ref.slot} of node {node_id}"
    if any(bit == f"button {ref.index}" for _, bits in claims for bit, _ in bits):
        return None
    return f"{name}: no device feeds button {ref.index} of node {node_id}"


# --------------------------------------------------------------------------- ports
# What would fail when the outputs open, found before: `load_runnable` (usb2rc.configfile)
# adds these to the file's own problems, for `run`, a reload and `check` alike.


def port_problems(config: Config, port_override: str | None) -> list[Problem]:
    """Every output without a port once `--port` replaced the first one's, and every port
    that exists but cannot be a serial line. A path that does not exist is no problem: the
    adapter may be plugged later, and the output retries it every second."""
    problems = []
    for index, output in enumerate(config.outputs):
        overridden = index == 0 and bool(port_override)
        port = port_override if overridden else output.port
        reason = _NO_PORT if not port else serial_line_problem(port)
        if reason is None:
            continue
        if overridden:
            problems.append(Problem("--port", None, None, f"{port}: {reason}"))
        else:
            message = reason if not port else f"{port}: {reason}"
            problems.append(_port_problem(config, output.where, index, message))
    return problems


_NO_PORT = (
    "no port: set `port:` here, or give the first output's with --port PORT "
    "(to `usb2rc run` and to `usb2rc check` alike)"
)


def _port_problem(config: Config, where: Where | None, index: int, message: str) -> Problem:
    """At the output's `port:` in the file; zero config has no line."""
    if where is not None:
        return where.problem(message, key_suffix=".port")
    return Problem(config.source, None, f"outputs[{index}].port", message)


def serial_line_problem(port: str) -> str | None:
    """Why an existing `port` path cannot be a serial line, or None (URLs and absent paths
    are not judged here). Opens nothing: opening a serial port can reset what is on it."""
    if "://" in port:
        return None
    try:
        mode = os.stat(port)
    except OSError:
        return None  # absent (plugged later), a UDP address, or a name only pyserial knows
    if stat.S_ISDIR(mode.st_mode):
        return "is a directory, not a serial line"
    if stat.S_ISREG(mode.st_mode):
        return "is a regular file, not a serial line"
    if not stat.S_ISCHR(mode.st_mode):
        return "is not a character device, so not a serial line"
    device_class = _char_device_class(mode.st_rdev)
    if device_class not in (None, "tty"):
        return f"is a {device_class} device, not a serial line (tty)"
    return None


def _char_device_class(rdev: int) -> str | None:
    """The kernel's class of a character device ("tty", "mem", ...), from sysfs; None when
    sysfs does not list it (pseudo-terminals, other systems)."""
    link = f"/sys/dev/char/{os.major(rdev)}:{os.minor(rdev)}/subsystem"
    if not os.path.exists(link):
        return None
    return os.path.basename(os.path.realpath(link))
