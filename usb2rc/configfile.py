"""The YAML config file: load → validate → (nodes/mapping.py) compile.

`load_config(path)` / `load_config_text(text, source)` return a `Config` of plain frozen
dataclasses, or raise `ConfigError` listing *every* problem found, each a `Problem` record
(file, line, key path, message, allowed values) that prints as
`file:line: key.path: message (allowed: ...)`. Lines come from the YAML node tree
(`yamlnodes.compose`), so each problem points at the key the user has to change.

`Config.default()` is zero config: one C2-16B output, every device on the default layout.
docs/CONFIG.md describes every key. An empty file is an error, not zero config: an editor
saving it (truncate, then write) must not switch a running daemon's mapping on a reload.

`load_runnable(path, port_override)` is the one verdict `usb2rc run` starts with, a reload
(SIGHUP) takes and `usb2rc check` prints: the file's own problems, then what would fail when
the outputs open with `--port` applied (`config/ports.py`: a port per output, a port that
can be a serial line, one output per line). A file above
MAX_CONFIG_BYTES or with more than MAX_DEVICE_ENTRIES entries is refused before it is read
further: parsing holds the interpreter, and a reload parses while the outputs tick.

It sits at the top, above the output registry (`usb2rc.outputs`, whose rows say what each
protocol's output accepts), which sits above the codecs and the config package. The schema
is in the config package; this module is the entry point and re-exports its public names
for the commands (the stages below import them from where they are defined):

- `config/yamlnodes.py`: the node reader (lines, type checks, unknown keys), `Problem`,
  `ConfigError`, `Where` — nothing about usb2rc's schema;
- `config/model.py`: the dataclasses and `ChannelRef` (channel names, parsed once);
  `config/output_options.py`: the keys only some protocols take;
- this module: the top level and `outputs:`;
- `config/devices.py`: `devices:`; `config/checks.py`: clashes and channel sources;
  `config/ports.py`: the ports the outputs will use, `--port` applied;
  `config/controls.py`: switches, mixes, throttle cuts;
- `feedback/rules.py`: `feedback:`, the rules that drive the devices' outputs.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from yaml.nodes import MappingNode, Node, SequenceNode

from usb2rc.config.checks import channel_problem, check_channels, check_clashes, device_claims
from usb2rc.config.controls import check_controls, read_mix, read_switches, read_throttle_cuts
from usb2rc.config.controls_model import MixRef
from usb2rc.config.devices import read_devices
from usb2rc.config.model import (
    CHANNEL_ALLOWED,
    DEFAULT_BAUDRATE,
    HAT_DIRECTIONS,
    MAX_HID_BUTTON,
    SUMD_DEFAULT_SLOTS,
    SUMD_MAX_CHANNELS,
    SUMD_MIN_CHANNELS,
    AxisConfig,
    ButtonRoute,
    Calibration,
    ChannelRef,
    Config,
    DeviceConfig,
    HandoverConfig,
    HatConfig,
    LowBatteryConfig,
    MatchConfig,
    OutputConfig,
)
from usb2rc.config.port_url import port_name_problem
from usb2rc.config.ports import port_problems
from usb2rc.config.status import check_handovers
from usb2rc.config.yamlnodes import (
    ConfigError,
    NodeReader,
    Problem,
    Where,
    compose,
    decode,
    reject_recording,
)
from usb2rc.feedback.rules import read_feedback
from usb2rc.outputs import PROTOCOLS as OUTPUT_PROTOCOLS
from usb2rc.outputs import OutputProtocol, option_keys, protocol_aliases
from usb2rc.outputs import protocol as output_protocol

PROTOCOLS = tuple(OUTPUT_PROTOCOLS)
PROTOCOL_ALIASES = protocol_aliases()  # what users call a protocol by -> (it, why)
DEFAULT_RATE_HZ = {name: entry.default_rate_hz for name, entry in OUTPUT_PROTOCOLS.items()}

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
    "HandoverConfig",
    "HatConfig",
    "LowBatteryConfig",
    "MatchConfig",
    "OutputConfig",
    "Problem",
    "Where",
    "channel_problem",
    "device_claims",
    "load_config",
    "load_config_text",
    "load_runnable",
]

TOP_KEYS = ("outputs", "devices", "defaults", "switches", "throttle_cut", "feedback")
COMMON_OUTPUT_KEYS = ("protocol", "port", "baudrate", "rate_hz")
OUTPUT_KEYS = (*COMMON_OUTPUT_KEYS, "channels", *option_keys())
_CONFIG_FIELDS = {f.name for f in dataclasses.fields(OutputConfig)}

# Bounds on what a reload parses while the outputs tick (docs/CONFIG.md, "Reload"). Parsing
# runs Python on the main thread; the output threads get the interpreter back every 0.5 ms,
# but parts of the parse (PyYAML's scan of the whole text, collections of a large node tree)
# hold it longer: a 10 MB file held the ticks up 60-240 ms, 2000 entries 100 ms. The shipped
# configs are 1-3 KiB with three entries; these leave room for 40 times that.
MAX_CONFIG_BYTES = 128 * 1024
MAX_DEVICE_ENTRIES = 128


def load_runnable(path: str | None, port_override: str | None) -> Config:
    """The config at `path` (zero config for None) as the daemon would run it with
    `--port port_override`: raises ConfigError with every problem of the file, or else with
    every output that could not open (no port, a port that is no serial line, a line an
    earlier output has). The one check shared by `run`, a reload and `check`. OSError when
    the file cannot be read."""
    config = Config.default() if path is None else load_config(path)
    problems = port_problems(config, port_override)
    if problems:
        raise ConfigError(problems)
    return config


def load_config(path: str) -> Config:
    """Read and validate a config file; raises ConfigError (or OSError if unreadable)."""
    with open(path, "rb") as fh:
        data = fh.read(MAX_CONFIG_BYTES + 1)
    if len(data) > MAX_CONFIG_BYTES:
        # a recording is the likely large file given here by mistake: name it as such
        reject_recording(data[:4096].decode("utf-8", "replace"), str(path))
        message = (
            f"larger than {MAX_CONFIG_BYTES // 1024} KiB: a config is a few KiB, and a larger "
            "one would hold up the outputs while a reload parses it"
        )
        raise ConfigError([Problem(str(path), None, None, message)])
    return load_config_text(decode(data, str(path)), str(path))


def load_config_text(text: str, source: str = "<config>") -> Config:
    root = compose(text, source)
    if root is None:
        message = (
            "empty (no YAML document): a config needs `outputs:` or `devices:`; "
            "run without --config for zero config"
        )
        raise ConfigError([Problem(source, None, None, message)])
    reader = NodeReader(source)
    try:
        config = _read_config(reader, root)
    except RecursionError:
        raise ConfigError([Problem(source, 1, None, "nested too deeply")]) from None
    if config is not None:
        check_clashes(reader, config)
        check_channels(reader, config)
        check_handovers(reader, config)
        check_controls(reader, config)
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
    if "devices" in items and _entries_within_limit(reader, items["devices"][1]):
        devices = read_devices(reader, items["devices"][1])
    defaults = True
    if "defaults" in items:
        defaults = reader.boolean(items["defaults"][1], "defaults") is not False
    switches = read_switches(reader, items["switches"][1]) if "switches" in items else ()
    cuts = read_throttle_cuts(reader, items["throttle_cut"][1]) if "throttle_cut" in items else ()
    feedback = None  # no key: the zero-config rule (docs/CONFIG.md, "Feedback")
    if "feedback" in items:
        names = [device.name for device in devices]
        feedback = read_feedback(reader, items["feedback"][1], names)
    return Config(outputs, devices, defaults, reader.source, switches, cuts, feedback)


def _entries_within_limit(reader: NodeReader, node: Node) -> bool:
    """False (with the problem) past MAX_DEVICE_ENTRIES: the entries are not read further."""
    if not isinstance(node, SequenceNode) or len(node.value) <= MAX_DEVICE_ENTRIES:
        return True
    message = (
        f"{len(node.value)} entries, more than {MAX_DEVICE_ENTRIES}: a reload would hold up "
        "the outputs while it reads them"
    )
    reader.error(node, "devices", message, f"1..{MAX_DEVICE_ENTRIES} entries")
    return False


# --------------------------------------------------------------------------- outputs


def _read_output(reader: NodeReader, node: Node, path: str) -> OutputConfig | None:
    items = reader.mapping(node, path, OUTPUT_KEYS)
    if items is None:
        return None
    if "protocol" not in items:
        reader.error(node, f"{path}.protocol", "missing", ", ".join(PROTOCOLS))
        return None
    name = reader.choice(items["protocol"][1], f"{path}.protocol", PROTOCOLS, PROTOCOL_ALIASES)
    if name is None:
        return None
    entry = output_protocol(name)
    own = {*COMMON_OUTPUT_KEYS, *entry.options, *(("channels",) if entry.channels else ())}
    for key in items:
        if key not in own:
            reader.error(items[key][0], f"{path}.{key}", f"not an option of {name} outputs")
    values: dict[str, Any] = {
        "protocol": name,
        "where": reader.where(node, path),
        "rate_hz": entry.default_rate_hz,
        "baudrate": entry.default_baudrate,
    }
    if "port" in items:
        values["port"] = _read_port(reader, items["port"][1], f"{path}.port")
    if "baudrate" in items:
        values["baudrate"] = reader.integer(
            items["baudrate"][1], f"{path}.baudrate", 1200, 4_000_000
        )
    if "rate_hz" in items:
        values["rate_hz"] = reader.number(items["rate_hz"][1], f"{path}.rate_hz", 1, 1000)
    options: list[tuple[str, Any]] = []
    for key, option in entry.options.items():
        if key in items:
            value = option.read(reader, items[key][1], f"{path}.{key}")
            if value is not None and key in _CONFIG_FIELDS:
                values[key] = value
            elif value is not None:
                options.append((key, value))
    values["options"] = tuple(options)
    if entry.channels and "channels" in items:
        counted = entry.own_checks is None  # else the protocol's own check counts them
        channels = _read_channels(reader, items["channels"][1], f"{path}.channels", entry, counted)
        if channels is not None:
            values["channels"], values["channel_wheres"] = channels
    elif entry.channels_required:
        reader.error(node, f"{path}.channels", f"missing: {name} outputs list their channels")
    values = {key: value for key, value in values.items() if value is not None}
    output = OutputConfig(**values)
    if entry.own_checks is not None:
        entry.check(reader, node, items, path, output)
    else:
        _check_bandwidth(reader, entry, output, items, path)
    return output


def _check_bandwidth(
    reader: NodeReader, entry: OutputProtocol, output: OutputConfig, items: Any, path: str
) -> None:
    """One frame a tick must fit the line: frame bytes × rate × bit times a byte ≤ baud."""
    if not entry.channels:
        return  # C2-16B sends as many nodes a tick as fit, round-robin (docs/ICD.md)
    count = len(output.channels) if output.channels is not None else len(SUMD_DEFAULT_SLOTS)
    problem = entry.bandwidth_problem(output.baudrate, output.rate_hz, count)
    if problem is None:
        return
    key = "rate_hz" if "rate_hz" in items else "baudrate" if "baudrate" in items else None
    if key is None:
        reader.error(items["protocol"][0], f"{path}.protocol", problem)
    else:
        reader.error(items[key][1], f"{path}.{key}", problem)


def _read_port(reader: NodeReader, node: Node, path: str) -> str | None:
    """A port name pyserial can parse (usb2rc.config.port_url): `foo://bar` is a config
    error, and so is a device's bare name (`ttyUSB0`: did you mean /dev/ttyUSB0?)."""
    port = reader.string(node, path)
    problem = None if port is None else port_name_problem(port)
    if problem is not None:
        reader.error(node, path, problem)
        return None
    return port


def _read_channels(
    reader: NodeReader, node: Node, path: str, output: OutputProtocol, counted: bool = True
) -> tuple[tuple[ChannelRef | MixRef, ...], tuple[Where, ...]] | None:
    """The channel references (parsed here, once) and where each is; bad names reported."""
    entries = reader.sequence(node, path)
    if entries is None:
        return None
    assert output.channels is not None
    low, high = output.channels
    if counted and not low <= len(entries) <= high:
        reader.error(node, path, f"{len(entries)} channels", f"{low}..{high}")
    refs: list[ChannelRef | MixRef] = []
    wheres: list[Where] = []
    for i, entry in enumerate(entries):
        if isinstance(entry, MappingNode):  # {mix: [...]} (usb2rc.config.controls)
            mix = read_mix(reader, entry, f"{path}[{i}]")
            if mix is not None:
                refs.append(mix)
                wheres.append(reader.where(entry, f"{path}[{i}]"))
            continue
        name = reader.string(entry, f"{path}[{i}]")
        if name is None:
            continue
        ref = ChannelRef.parse(name)
        if ref is None:
            allowed = f"{CHANNEL_ALLOWED}, switch.NAME, {{mix: [...]}}"
            reader.error(entry, f"{path}[{i}]", f"bad channel {name!r}", allowed)
            continue
        refs.append(ref)
        wheres.append(reader.where(entry, f"{path}[{i}]"))
    return tuple(refs), tuple(wheres)
