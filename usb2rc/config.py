"""The YAML config: load → validate → (mapping.py) compile.

`load_config(path)` / `load_config_text(text, source)` return a `Config` of plain frozen
dataclasses, or raise `ConfigError` listing *every* problem found, each a `Problem` record
(file, line, key path, message, allowed values) that prints as
`file:line: key.path: message (allowed: ...)`. Lines come from the YAML node tree
(`yamlnodes.compose`), so each problem points at the key the user has to change.

`Config.default()` is zero config: one C2-16B output, every device on the default layout.
docs/CONFIG.md describes every key.

The schema is in four modules; this one is the entry point and re-exports the others'
public names (import them from here):

- `yamlnodes.py`: the node reader (lines, type checks, unknown keys), `Problem`,
  `ConfigError`, `Where` — nothing about usb2rc's schema;
- `config_model.py`: the dataclasses and `ChannelRef` (SUMD channel names, parsed once);
- this module: the top level and `outputs:`;
- `config_devices.py`: `devices:`; `config_checks.py`: clashes and SUMD channel sources.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from yaml.nodes import Node

from usb2rc.config_checks import channel_problem, check_channels, check_clashes, device_claims
from usb2rc.config_devices import read_devices
from usb2rc.config_mavlink import MAVLINK_KEYS, check_mavlink_output, read_mavlink_options
from usb2rc.config_model import (
    CHANNEL_ALLOWED,
    DEFAULT_BAUDRATE,
    DEFAULT_RATE_HZ,
    HAT_DIRECTIONS,
    MAX_HID_BUTTON,
    PROTOCOLS,
    SUMD_DEFAULT_SLOTS,
    SUMD_MAX_CHANNELS,
    SUMD_MIN_CHANNELS,
    AxisConfig,
    ButtonRoute,
    Calibration,
    ChannelRef,
    Config,
    DeviceConfig,
    HatConfig,
    MatchConfig,
    OutputConfig,
)
from usb2rc.yamlnodes import ConfigError, NodeReader, Problem, Where, compose, decode

__all__ = [
    "DEFAULT_BAUDRATE",
    "DEFAULT_RATE_HZ",
    "HAT_DIRECTIONS",
    "MAX_HID_BUTTON",
    "PROTOCOLS",
    "SUMD_DEFAULT_SLOTS",
    "SUMD_MAX_CHANNELS",
    "SUMD_MIN_CHANNELS",
    "AxisConfig",
    "ButtonRoute",
    "Calibration",
    "ChannelRef",
    "Config",
    "ConfigError",
    "DeviceConfig",
    "HatConfig",
    "MatchConfig",
    "OutputConfig",
    "Problem",
    "Where",
    "channel_problem",
    "device_claims",
    "load_config",
    "load_config_text",
]

TOP_KEYS = ("outputs", "devices", "defaults")
OUTPUT_KEYS = (
    "protocol", "port", "baudrate", "rate_hz", "line_feed", "service_status", "channels",
    "extended", *MAVLINK_KEYS,
)  # fmt: skip
C2_ONLY_KEYS = ("line_feed", "service_status")
SUMD_ONLY_KEYS = ("channels", "extended")
NOT_OPTIONS = {  # keys other protocols have
    "c2-16b": (*SUMD_ONLY_KEYS, *MAVLINK_KEYS),
    "sumd": (*C2_ONLY_KEYS, *MAVLINK_KEYS),
    "mavlink": (*C2_ONLY_KEYS, "extended"),
}


def load_config(path: str) -> Config:
    """Read and validate a config file; raises ConfigError (or OSError if unreadable)."""
    with open(path, "rb") as fh:
        data = fh.read()
    return load_config_text(decode(data, str(path)), str(path))


def load_config_text(text: str, source: str = "<config>") -> Config:
    root = compose(text, source)
    if root is None:
        return Config(outputs=(OutputConfig(),), source=source)
    reader = NodeReader(source)
    try:
        config = _read_config(reader, root)
    except RecursionError:
        raise ConfigError([Problem(source, 1, None, "nested too deeply")]) from None
    if config is not None:
        check_clashes(reader, config)
        check_channels(reader, config)
    if reader.problems:
        raise ConfigError(sorted(reader.problems, key=lambda p: p.line or 0))
    assert config is not None
    return config


def _read_config(reader: NodeReader, root: Node) -> Config | None:
    items = reader.mapping(root, "", TOP_KEYS)
    if items is None:
        return None
    outputs: tuple[OutputConfig, ...] = (OutputConfig(),)
    if "outputs" in items:
        outputs = reader.list_of(items["outputs"][1], "outputs", _read_output, allow_empty=False)
    devices: tuple[DeviceConfig, ...] = ()
    if "devices" in items:
        devices = read_devices(reader, items["devices"][1])
    defaults = True
    if "defaults" in items:
        defaults = reader.boolean(items["defaults"][1], "defaults") is not False
    return Config(outputs=outputs, devices=devices, defaults=defaults, source=reader.source)


# --------------------------------------------------------------------------- outputs


def _read_output(reader: NodeReader, node: Node, path: str) -> OutputConfig | None:
    items = reader.mapping(node, path, OUTPUT_KEYS)
    if items is None:
        return None
    if "protocol" not in items:
        reader.error(node, f"{path}.protocol", "missing", ", ".join(PROTOCOLS))
        return None
    protocol = reader.choice(items["protocol"][1], f"{path}.protocol", PROTOCOLS)
    if protocol is None:
        return None
    wrong = NOT_OPTIONS[protocol]
    for key in wrong:
        if key in items:
            reader.error(items[key][0], f"{path}.{key}", f"not an option of {protocol} outputs")
    values: dict[str, Any] = {"protocol": protocol, "where": reader.where(node, path)}
    values["rate_hz"] = DEFAULT_RATE_HZ[protocol]
    readers: dict[str, Callable[[Node, str], Any]] = {
        "port": reader.string,
        "baudrate": lambda n, p: reader.integer(n, p, 1200, 4_000_000),
        "rate_hz": lambda n, p: reader.number(n, p, 1, 1000),
        "line_feed": reader.boolean,
        "service_status": lambda n, p: reader.choice(n, p, ("ascii", "binary")),
        "extended": reader.boolean,
    }
    for key, read in readers.items():
        if key in items and key not in wrong:
            value = read(items[key][1], f"{path}.{key}")
            if value is not None:
                values[key] = value
    if "channels" in items and "channels" not in wrong:
        counted = protocol != "mavlink"  # MAVLink's count depends on its message
        channels = _read_channels(reader, items["channels"][1], f"{path}.channels", counted)
        if channels is not None:
            values["channels"], values["channel_wheres"] = channels
    if protocol == "mavlink":
        values["mavlink"] = read_mavlink_options(reader, items, path)
        output = OutputConfig(**values)
        check_mavlink_output(reader, node, items, path, output)
        return output
    return OutputConfig(**values)


def _read_channels(
    reader: NodeReader, node: Node, path: str, counted: bool = True
) -> tuple[tuple[ChannelRef, ...], tuple[Where, ...]] | None:
    """The channel references (parsed here, once) and where each is; bad names reported."""
    entries = reader.sequence(node, path)
    if entries is None:
        return None
    if counted and not SUMD_MIN_CHANNELS <= len(entries) <= SUMD_MAX_CHANNELS:
        reader.error(
            node, path, f"{len(entries)} channels", f"{SUMD_MIN_CHANNELS}..{SUMD_MAX_CHANNELS}"
        )
    refs: list[ChannelRef] = []
    wheres: list[Where] = []
    for i, entry in enumerate(entries):
        name = reader.string(entry, f"{path}[{i}]")
        if name is None:
            continue
        ref = ChannelRef.parse(name)
        if ref is None:
            reader.error(entry, f"{path}[{i}]", f"bad channel {name!r}", CHANNEL_ALLOWED)
            continue
        refs.append(ref)
        wheres.append(reader.where(entry, f"{path}[{i}]"))
    return tuple(refs), tuple(wheres)
