"""The YAML config: load → validate → (mapping.py) compile.

`load_config(path)` / `load_config_text(text, source)` return a `Config` of plain frozen
dataclasses, or raise `ConfigError` listing *every* problem found, each as
`file:line: key.path: message (allowed: ...)`. Lines come from the YAML node tree
(`yaml.compose`), so each error points at the key the user has to change.

`Config.default()` is zero config: one C2-16B output, every device on the default layout.
docs/CONFIG.md describes every key.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from usb2rc.hid.usages import GD_HAT_SWITCH
from usb2rc.protocol.c2_16b import AXIS_NAMES as AXIS_SLOTS
from usb2rc.protocol.c2_16b import MAX_NODE_ID as NODE_ID_MAX
from usb2rc.protocol.c2_16b import NODE_BUTTONS

MAX_HID_BUTTON = 65535
HAT_DIRECTIONS = ("up", "up-right", "right", "down-right", "down", "down-left", "left", "up-left")
PROTOCOLS = ("c2-16b", "sumd")
DEFAULT_RATE_HZ = {"c2-16b": 50, "sumd": 100}
DEFAULT_BAUDRATE = 115200
SUMD_MIN_CHANNELS, SUMD_MAX_CHANNELS = 2, 32
SUMD_DEFAULT_SLOTS = ("x", "y", "z", "rz", "slider", "rx", "ry", "dial")

_CHANNEL_RE = re.compile(r"^node(\d+)\.(?:(button)(\d+)|([a-z0-9]+))$")


class ConfigError(ValueError):
    """One or more config errors, each `file:line: key.path: message`."""

    def __init__(self, errors: list[str]) -> None:
        self.errors = list(errors)
        super().__init__("\n".join(self.errors))


# --------------------------------------------------------------------------- dataclasses


@dataclass(frozen=True)
class Where:
    """Where a value came from: for error messages after validation (bind, clashes)."""

    source: str
    line: int
    key: str

    def __str__(self) -> str:
        return f"{self.source}:{self.line}: {self.key}"


@dataclass(frozen=True)
class Calibration:
    min: int
    center: int
    max: int


@dataclass(frozen=True)
class AxisConfig:
    """One axis slot's source and pipeline. Exactly one of usage / hat / buttons is set."""

    slot: str
    where: Where
    usage: int | None = None  # an InputField usage, (page << 16) | id
    occurrence: int = 0  # 0: the first field with that usage, 1: the second ...
    hat: int | None = None  # a hat's usage, with hat_axis
    hat_axis: str | None = None  # "x" (left -1 / right +1) or "y" (down -1 / up +1)
    buttons: tuple[int, int] | None = None  # HID buttons: first -> -1, second -> +1
    calibration: Calibration | None = None
    deadband: float = 0.0
    expo: float = 0.0
    invert: bool = False
    trim: float = 0.0
    unsigned: bool = False
    failsafe: int | None = None  # None: hold the last value


@dataclass(frozen=True)
class ButtonRoute:
    """HID button `hid` (1-based) -> node button `node` (1..56)."""

    hid: int
    node: int
    where: Where


@dataclass(frozen=True)
class HatConfig:
    usage: int
    occurrence: int
    to: str | tuple[int | None, ...]  # "hat1" or 8 node buttons (None: direction unused)
    where: Where


@dataclass(frozen=True)
class MatchConfig:
    vid: int | None = None
    pid: int | None = None
    serial: str | None = None
    port: str | None = None
    product: str | None = None  # a glob, case-insensitive


@dataclass(frozen=True)
class DeviceConfig:
    name: str
    match: MatchConfig
    node_id: int | None
    axes: tuple[AxisConfig, ...]
    buttons: tuple[ButtonRoute, ...]
    hats: tuple[HatConfig, ...]
    default_layout: bool  # True when the entry lists none of axes / buttons / hats
    where: Where


@dataclass(frozen=True)
class OutputConfig:
    protocol: str = "c2-16b"
    port: str | None = None
    baudrate: int = DEFAULT_BAUDRATE
    rate_hz: float = 50
    line_feed: bool = True
    service_status: str = "ascii"
    channels: tuple[str, ...] | None = None  # SUMD; None: the default channel list
    extended: bool = False  # SUMD: axes onto 900-2100 µs instead of 1100-1900 µs
    where: Where | None = None
    channel_wheres: tuple[Where, ...] = field(default=(), compare=False)


@dataclass(frozen=True)
class Config:
    outputs: tuple[OutputConfig, ...]
    devices: tuple[DeviceConfig, ...] = ()
    defaults: bool = True
    source: str = "<default>"

    @classmethod
    def default(cls) -> Config:
        """Zero config: one C2-16B output (port from the command line), default layout."""
        return cls(outputs=(OutputConfig(),))


# --------------------------------------------------------------------------- reader


class _Reader:
    """Walks the YAML node tree, converting and checking; collects every error.

    One per load, with its own constructor: a SafeConstructor remembers every node it has
    built (`constructed_objects`) until a whole document is constructed, which we never do.
    A shared one kept every config ever loaded alive (~100 KB per SIGHUP, issue 11).
    """

    def __init__(self, source: str) -> None:
        self.source = source
        self.errors: list[str] = []
        self._constructor = yaml.constructor.SafeConstructor()

    def where(self, node: Node, path: str) -> Where:
        return Where(self.source, node.start_mark.line + 1, path)

    def error(self, node: Node, path: str, message: str, allowed: str = "") -> None:
        suffix = f" (allowed: {allowed})" if allowed else ""
        self.errors.append(f"{self.where(node, path)}: {message}{suffix}")

    def mapping(
        self, node: Node, path: str, allowed_keys: Iterable[str] | None
    ) -> dict[str, tuple[Node, Node]] | None:
        """A mapping's items by key (key node, value node); unknown / duplicate keys reported."""
        if not isinstance(node, MappingNode):
            self.error(node, path, f"expected a mapping, got {_kind(node)}")
            return None
        allowed = list(allowed_keys) if allowed_keys is not None else None
        items: dict[str, tuple[Node, Node]] = {}
        for key_node, value_node in node.value:
            key = str(self.scalar(key_node)) if isinstance(key_node, ScalarNode) else "?"
            key_path = f"{path}.{key}" if path else key
            if key in items:
                self.error(key_node, key_path, "duplicate key")
            elif allowed is not None and key not in allowed:
                self.error(key_node, key_path, _unknown_key(key, allowed), ", ".join(allowed))
            else:
                items[key] = (key_node, value_node)
        return items

    def scalar(self, node: Node) -> Any:
        if not isinstance(node, ScalarNode):
            return node
        try:
            return self._constructor.construct_object(node, deep=True)
        except (yaml.YAMLError, ValueError, TypeError, OverflowError, AttributeError):
            return node.value  # e.g. `!!int abc`: the type check names the line

    def sequence(self, node: Node, path: str) -> list[Node] | None:
        if not isinstance(node, SequenceNode):
            self.error(node, path, f"expected a list, got {_kind(node)}")
            return None
        return list(node.value)

    def integer(self, node: Node, path: str, lo: int, hi: int) -> int | None:
        value = self.scalar(node)
        if not isinstance(value, int) or isinstance(value, bool):
            self.error(node, path, f"expected an integer, got {_show(node)}", f"{lo}..{hi}")
            return None
        if not lo <= value <= hi:
            self.error(node, path, f"{value} is out of range", f"{lo}..{hi}")
            return None
        return value

    def number(self, node: Node, path: str, lo: float, hi: float) -> float | None:
        value = self.scalar(node)
        if not isinstance(value, int | float) or isinstance(value, bool):
            self.error(node, path, f"expected a number, got {_show(node)}", f"{lo}..{hi}")
            return None
        if not lo <= value <= hi:
            self.error(node, path, f"{value} is out of range", f"{lo}..{hi}")
            return None
        return float(value)

    def boolean(self, node: Node, path: str) -> bool | None:
        value = self.scalar(node)
        if not isinstance(value, bool):
            self.error(node, path, f"expected true or false, got {_show(node)}", "true, false")
            return None
        return value

    def string(self, node: Node, path: str) -> str | None:
        value = self.scalar(node)
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            self.error(node, path, f"expected a string, got {_show(node)}")
            return None
        return str(value)

    def choice(self, node: Node, path: str, choices: Iterable[str]) -> str | None:
        options = list(choices)
        value = self.string(node, path)
        if value is None:
            return None
        if value not in options:
            self.error(node, path, f"{value!r} is not valid", ", ".join(options))
            return None
        return value

    def usage(self, node: Node, path: str) -> int | None:
        from usb2rc.hid.usages import usage_from_name

        value = self.scalar(node)
        text = f"0x{value:08X}" if isinstance(value, int) and not isinstance(value, bool) else None
        text = text or (value if isinstance(value, str) else None)
        if text is not None:
            try:
                return usage_from_name(text)
            except (KeyError, ValueError):
                pass
        self.error(node, path, f"unknown usage {_show(node)}", _USAGES_ALLOWED)
        return None


_USAGES_ALLOWED = (
    "a usage name such as X, Y, Z, Rx, Ry, Rz, Slider, Dial, Wheel, HatSwitch, Throttle, "
    "Rudder, Aileron, Elevator, Accelerator, Brake, Steering, or 0xPPPPUUUU"
)


def _kind(node: Node) -> str:
    if isinstance(node, MappingNode):
        return "a mapping"
    if isinstance(node, SequenceNode):
        return "a list"
    return _show(node)


def _show(node: Node) -> str:
    if isinstance(node, ScalarNode):
        return repr(node.value) if node.value != "" else "nothing"
    return _kind(node)


def _unknown_key(key: str, allowed: list[str]) -> str:
    close = difflib.get_close_matches(key, allowed, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown key {key!r}{hint}"


# --------------------------------------------------------------------------- top level

TOP_KEYS = ("outputs", "devices", "defaults")
OUTPUT_KEYS = (
    "protocol", "port", "baudrate", "rate_hz", "line_feed", "service_status", "channels",
    "extended",
)  # fmt: skip
C2_ONLY_KEYS = ("line_feed", "service_status")
SUMD_ONLY_KEYS = ("channels", "extended")
DEVICE_KEYS = ("name", "match", "node_id", "axes", "buttons", "hats")
MATCH_KEYS = ("vid", "pid", "serial", "port", "product")
AXIS_KEYS = (
    "usage", "occurrence", "hat", "axis", "buttons", "calibration", "deadband", "expo",
    "invert", "trim", "unsigned", "failsafe",
)  # fmt: skip
HAT_KEYS = ("usage", "occurrence", "to")


def load_config(path: str) -> Config:
    """Read and validate a config file; raises ConfigError (or OSError if unreadable)."""
    with open(path, "rb") as fh:
        data = fh.read()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            [f"{path}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"]
        ) from None
    return load_config_text(text, str(path))


def load_config_text(text: str, source: str = "<config>") -> Config:
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        raise ConfigError([_yaml_error(exc, source)]) from None
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow
        line = text[: exc.position].count("\n") + 1
        raise ConfigError(
            [f"{source}:{line}: not valid YAML: character {exc.character!r} is not allowed"]
        ) from None
    except RecursionError:
        raise ConfigError([f"{source}:1: not valid YAML: nested too deeply"]) from None
    if root is None:
        return Config(outputs=(OutputConfig(),), source=source)
    reader = _Reader(source)
    try:
        config = _read_config(reader, root)
    except RecursionError:
        raise ConfigError([f"{source}:1: nested too deeply"]) from None
    if config is not None:
        _check_clashes(reader, config)
        _check_channels(reader, config)
    if reader.errors:
        raise ConfigError(sorted(reader.errors, key=_error_line))
    assert config is not None
    return config


def _yaml_error(exc: yaml.MarkedYAMLError, source: str) -> str:
    mark = exc.problem_mark or exc.context_mark
    line = mark.line + 1 if mark else 0
    context = ""
    if exc.context and exc.context_mark:
        context = f" ({exc.context} at line {exc.context_mark.line + 1})"
    return f"{source}:{line}: not valid YAML: {exc.problem}{context}"


def _error_line(error: str) -> int:
    m = re.search(r":(\d+): ", error)
    return int(m.group(1)) if m else 0


def _read_config(reader: _Reader, root: Node) -> Config | None:
    items = reader.mapping(root, "", TOP_KEYS)
    if items is None:
        return None
    outputs: tuple[OutputConfig, ...] = (OutputConfig(),)
    if "outputs" in items:
        outputs = _read_outputs(reader, items["outputs"][1])
    devices: tuple[DeviceConfig, ...] = ()
    if "devices" in items:
        devices = _read_devices(reader, items["devices"][1])
    defaults = True
    if "defaults" in items:
        defaults = reader.boolean(items["defaults"][1], "defaults") is not False
    return Config(outputs=outputs, devices=devices, defaults=defaults, source=reader.source)


def _read_list(
    reader: _Reader,
    node: Node,
    path: str,
    read_one: Callable[[_Reader, Node, str], Any],
    allow_empty: bool = True,
) -> tuple[Any, ...]:
    entries = reader.sequence(node, path)
    if entries is None:
        return ()
    if not entries and not allow_empty:
        reader.error(node, path, "empty list", "at least one entry")
    results = (read_one(reader, entry, f"{path}[{i}]") for i, entry in enumerate(entries))
    return tuple(r for r in results if r is not None)


# --------------------------------------------------------------------------- outputs


def _read_outputs(reader: _Reader, node: Node) -> tuple[OutputConfig, ...]:
    return _read_list(reader, node, "outputs", _read_output, allow_empty=False)


def _read_output(reader: _Reader, node: Node, path: str) -> OutputConfig | None:
    items = reader.mapping(node, path, OUTPUT_KEYS)
    if items is None:
        return None
    if "protocol" not in items:
        reader.error(node, f"{path}.protocol", "missing", ", ".join(PROTOCOLS))
        return None
    protocol = reader.choice(items["protocol"][1], f"{path}.protocol", PROTOCOLS)
    if protocol is None:
        return None
    wrong = SUMD_ONLY_KEYS if protocol == "c2-16b" else C2_ONLY_KEYS
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
        "channels": lambda n, p: _read_channels(reader, n, p),
    }
    if "channels" in items and protocol == "sumd":
        values["channel_wheres"] = _channel_wheres(reader, items["channels"][1], path)
    for key, read in readers.items():
        if key in items and key not in wrong:
            value = read(items[key][1], f"{path}.{key}")
            if value is not None:
                values[key] = value
    return OutputConfig(**values)


def _read_channels(reader: _Reader, node: Node, path: str) -> tuple[str, ...] | None:
    entries = reader.sequence(node, path)
    if entries is None:
        return None
    if not SUMD_MIN_CHANNELS <= len(entries) <= SUMD_MAX_CHANNELS:
        reader.error(
            node, path, f"{len(entries)} channels", f"{SUMD_MIN_CHANNELS}..{SUMD_MAX_CHANNELS}"
        )
    names = []
    for i, entry in enumerate(entries):
        name = reader.string(entry, f"{path}[{i}]")
        if name is not None and _parse_channel_name(name) is None:
            reader.error(entry, f"{path}[{i}]", f"bad channel {name!r}", _CHANNEL_ALLOWED)
        names.append(name or "")
    return tuple(names)


def _channel_wheres(reader: _Reader, node: Node, path: str) -> tuple[Where, ...]:
    if not isinstance(node, SequenceNode):
        return ()
    return tuple(reader.where(e, f"{path}.channels[{i}]") for i, e in enumerate(node.value))


_CHANNEL_ALLOWED = "nodeN.x, .y, .z, .slider, .rx, .ry, .rz, .dial, .aux1, .aux2, nodeN.buttonK"


def _parse_channel_name(name: str) -> tuple[int, str, int | str] | None:
    """`node1.x` -> (1, "axis", "x"); `node1.button5` -> (1, "button", 5); else None."""
    m = _CHANNEL_RE.match(name.strip().lower())
    if m is None:
        return None
    node_id = int(m.group(1))
    if node_id > NODE_ID_MAX:
        return None
    if m.group(2):
        button = int(m.group(3))
        return (node_id, "button", button) if 1 <= button <= NODE_BUTTONS else None
    slot = m.group(4)
    return (node_id, "axis", slot) if slot in AXIS_SLOTS else None


parse_channel_name = _parse_channel_name


# --------------------------------------------------------------------------- devices


def _read_devices(reader: _Reader, node: Node) -> tuple[DeviceConfig, ...]:
    devices = _read_list(reader, node, "devices", _read_device)
    seen: dict[str, DeviceConfig] = {}
    for device in devices:
        if device.name in seen:
            first = seen[device.name].where
            reader.errors.append(
                f"{device.where.source}:{device.where.line}: {device.where.key}.name: "
                f"duplicate device name {device.name!r} (first at line {first.line})"
            )
        seen.setdefault(device.name, device)
    return devices


def _read_device(reader: _Reader, node: Node, path: str) -> DeviceConfig | None:
    items = reader.mapping(node, path, DEVICE_KEYS)
    if items is None:
        return None
    index = path[path.index("[") + 1 : -1]
    name = f"device{int(index) + 1}"
    if "name" in items:
        name = reader.string(items["name"][1], f"{path}.name") or name
    match = _read_match(reader, node, items, path)
    node_id = None
    if "node_id" in items:
        node_id = reader.integer(items["node_id"][1], f"{path}.node_id", 0, NODE_ID_MAX)
    axes: tuple[AxisConfig, ...] = ()
    if "axes" in items:
        axes = _read_axes(reader, items["axes"][1], f"{path}.axes")
    buttons: tuple[ButtonRoute, ...] = ()
    if "buttons" in items:
        buttons = _read_buttons(reader, items["buttons"][1], f"{path}.buttons")
    hats: tuple[HatConfig, ...] = ()
    if "hats" in items:
        hats = _read_list(reader, items["hats"][1], f"{path}.hats", _read_hat)
    default_layout = not any(key in items for key in ("axes", "buttons", "hats"))
    return DeviceConfig(
        name, match, node_id, axes, buttons, hats, default_layout, reader.where(node, path)
    )


def _read_match(
    reader: _Reader, node: Node, items: dict[str, tuple[Node, Node]], path: str
) -> MatchConfig:
    if "match" not in items:
        reader.error(
            node,
            f"{path}.match",
            "missing: which device this entry is for",
            "vid, pid, serial, port, product",
        )
        return MatchConfig()
    match_node = items["match"][1]
    fields = reader.mapping(match_node, f"{path}.match", MATCH_KEYS)
    if fields is None:
        return MatchConfig()
    if not fields:
        reader.error(
            match_node, f"{path}.match", "empty: it would match every device", ", ".join(MATCH_KEYS)
        )
    values: dict[str, Any] = {}
    for key, (_, value_node) in fields.items():
        key_path = f"{path}.match.{key}"
        if key in ("vid", "pid"):
            values[key] = reader.integer(value_node, key_path, 0, 0xFFFF)
        else:
            values[key] = reader.string(value_node, key_path)
    return MatchConfig(**values)


# --------------------------------------------------------------------------- axes


def _read_axes(reader: _Reader, node: Node, path: str) -> tuple[AxisConfig, ...]:
    items = reader.mapping(node, path, AXIS_SLOTS)
    if items is None:
        return ()
    axes = (_read_axis(reader, slot, v, f"{path}.{slot}") for slot, (_, v) in items.items())
    return tuple(a for a in axes if a is not None)


def _read_axis(reader: _Reader, slot: str, node: Node, path: str) -> AxisConfig | None:
    if isinstance(node, ScalarNode):  # shorthand: `x: X`
        usage = reader.usage(node, path)
        return None if usage is None else AxisConfig(slot, reader.where(node, path), usage)
    items = reader.mapping(node, path, AXIS_KEYS)
    if items is None:
        return None
    source = _read_axis_source(reader, node, items, path)
    if source is None:
        return None
    options = _read_axis_options(reader, items, path, shaped_source="usage" not in source)
    if options is None:
        return None
    return AxisConfig(slot, reader.where(node, path), **source, **options)


def _read_axis_source(
    reader: _Reader, node: Node, items: dict[str, tuple[Node, Node]], path: str
) -> dict[str, Any] | None:
    given = [key for key in ("usage", "hat", "buttons") if key in items]
    if len(given) != 1:
        what = "missing" if not given else f"{' and '.join(given)} both given"
        reader.error(node, path, f"axis source {what}: give exactly one of usage, hat, buttons")
        return None
    kind = given[0]
    if kind != "hat" and "axis" in items:
        reader.error(items["axis"][0], f"{path}.axis", "only with a hat source")
    if kind == "buttons" and "occurrence" in items:
        reader.error(items["occurrence"][0], f"{path}.occurrence", "not with a buttons source")
    occurrence = 0
    if "occurrence" in items:
        occurrence = reader.integer(items["occurrence"][1], f"{path}.occurrence", 0, 255) or 0
    if kind == "usage":
        usage = reader.usage(items["usage"][1], f"{path}.usage")
        return None if usage is None else {"usage": usage, "occurrence": occurrence}
    if kind == "hat":
        return _read_hat_axis(reader, node, items, path, occurrence)
    return _read_button_pair(reader, items["buttons"][1], f"{path}.buttons")


def _read_hat_axis(
    reader: _Reader, node: Node, items: dict[str, tuple[Node, Node]], path: str, occurrence: int
) -> dict[str, Any] | None:
    hat = reader.usage(items["hat"][1], f"{path}.hat")
    if "axis" not in items:
        reader.error(node, f"{path}.axis", "missing: which hat axis", "x, y")
        return None
    axis = reader.choice(items["axis"][1], f"{path}.axis", ("x", "y"))
    if hat is None or axis is None:
        return None
    return {"hat": hat, "hat_axis": axis, "occurrence": occurrence}


def _read_button_pair(reader: _Reader, node: Node, path: str) -> dict[str, Any] | None:
    entries = reader.sequence(node, path)
    if entries is None:
        return None
    if len(entries) != 2:
        reader.error(node, path, f"{len(entries)} buttons", "two HID buttons: [minus, plus]")
        return None
    pair = [reader.integer(e, f"{path}[{i}]", 1, MAX_HID_BUTTON) for i, e in enumerate(entries)]
    if pair[0] is None or pair[1] is None:
        return None
    if pair[0] == pair[1]:
        reader.error(node, path, "the same button twice", "two different HID buttons")
        return None
    return {"buttons": (pair[0], pair[1])}


def _read_axis_options(
    reader: _Reader, items: dict[str, tuple[Node, Node]], path: str, shaped_source: bool
) -> dict[str, Any] | None:
    ok = True
    options: dict[str, Any] = {}
    simple: dict[str, Callable[[Node, str], Any]] = {
        "deadband": lambda n, p: reader.number(n, p, 0.0, 0.99),
        "expo": lambda n, p: reader.number(n, p, 0.0, 1.0),
        "trim": lambda n, p: reader.number(n, p, -1.0, 1.0),
        "invert": reader.boolean,
        "unsigned": reader.boolean,
    }
    for key, read in simple.items():
        if key in items:
            value = read(items[key][1], f"{path}.{key}")
            ok = ok and value is not None
            options[key] = value
    if "calibration" in items:
        if shaped_source:
            reader.error(
                items["calibration"][0],
                f"{path}.calibration",
                "only for a usage source (hats and buttons have no raw range)",
            )
        options["calibration"] = _read_calibration(reader, items["calibration"][1], path)
        ok = ok and options["calibration"] is not None and not shaped_source
    if "failsafe" in items:
        unsigned = bool(options.get("unsigned"))
        lo, hi = (0, 65535) if unsigned else (-32768, 32767)
        options["failsafe"] = reader.integer(items["failsafe"][1], f"{path}.failsafe", lo, hi)
        ok = ok and options["failsafe"] is not None
    return options if ok else None


def _read_calibration(reader: _Reader, node: Node, path: str) -> Calibration | None:
    path = f"{path}.calibration"
    items = reader.mapping(node, path, ("min", "center", "max"))
    if items is None:
        return None
    limit = 2**31
    values = {k: reader.integer(v, f"{path}.{k}", -limit, limit - 1) for k, (_, v) in items.items()}
    if any(v is None for v in values.values()):
        return None
    if "min" not in values or "max" not in values:
        reader.error(node, path, "needs min and max", "min, center (optional), max")
        return None
    lo, hi = values["min"], values["max"]
    assert lo is not None and hi is not None
    center = values.get("center")
    if center is None:
        center = (lo + hi) // 2
    if not lo < center < hi:
        reader.error(
            node,
            path,
            f"min {lo}, center {center}, max {hi}",
            "min < center < max (use invert: true to reverse an axis)",
        )
        return None
    return Calibration(lo, center, hi)


# --------------------------------------------------------------------------- buttons, hats


def _read_buttons(reader: _Reader, node: Node, path: str) -> tuple[ButtonRoute, ...]:
    items = reader.mapping(node, path, None)
    if items is None:
        return ()
    routes: list[ButtonRoute] = []
    for key, (key_node, value_node) in items.items():
        key_path = f"{path}.{key}"
        hid = _parse_range(key, 1, MAX_HID_BUTTON)
        if hid is None:
            reader.error(
                key_node,
                key_path,
                f"bad HID button(s) {key!r}",
                f"a number or a range like 1-16, within 1..{MAX_HID_BUTTON}",
            )
            continue
        value = reader.scalar(value_node)
        node_range = _parse_range(str(value), 1, NODE_BUTTONS) if value is not None else None
        if node_range is None:
            reader.error(
                value_node,
                key_path,
                f"bad node button(s) {_show(value_node)}",
                f"a number or a range like 25-38, within 1..{NODE_BUTTONS}",
            )
            continue
        if len(node_range) != len(hid):
            reader.error(
                value_node,
                key_path,
                f"{len(hid)} HID buttons onto {len(node_range)} node buttons",
                "ranges of the same length",
            )
            continue
        where = reader.where(key_node, key_path)
        routes.extend(ButtonRoute(h, n, where) for h, n in zip(hid, node_range, strict=True))
    return tuple(routes)


def _parse_range(text: str, lo: int, hi: int) -> range | None:
    m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", text)
    if m is None:
        return None
    first = int(m.group(1))
    last = int(m.group(2)) if m.group(2) else first
    if not lo <= first <= last <= hi:
        return None
    return range(first, last + 1)


def _read_hat(reader: _Reader, node: Node, path: str) -> HatConfig | None:
    items = reader.mapping(node, path, HAT_KEYS)
    if items is None:
        return None
    usage: int | None = GD_HAT_SWITCH
    if "usage" in items:
        usage = reader.usage(items["usage"][1], f"{path}.usage")
    occurrence = 0
    if "occurrence" in items:
        occurrence = reader.integer(items["occurrence"][1], f"{path}.occurrence", 0, 255) or 0
    if "to" not in items:
        reader.error(node, f"{path}.to", "missing", "hat1, or a list of 8 node buttons")
        return None
    to = _read_hat_target(reader, items["to"][1], f"{path}.to")
    if usage is None or to is None:
        return None
    return HatConfig(usage, occurrence, to, reader.where(node, path))


def _read_hat_target(reader: _Reader, node: Node, path: str) -> str | tuple[int | None, ...] | None:
    allowed = f"hat1, or a list of 8 node buttons 1..{NODE_BUTTONS} (null: unused), in the order "
    allowed += ", ".join(HAT_DIRECTIONS)
    if isinstance(node, ScalarNode):
        if reader.scalar(node) == "hat1":
            return "hat1"
        reader.error(node, path, f"{_show(node)} is not valid", allowed)
        return None
    entries = reader.sequence(node, path)
    if entries is None:
        return None
    if len(entries) != len(HAT_DIRECTIONS):
        reader.error(node, path, f"{len(entries)} entries", allowed)
        return None
    buttons: list[int | None] = []
    for i, entry in enumerate(entries):
        if reader.scalar(entry) is None:
            buttons.append(None)
            continue
        buttons.append(reader.integer(entry, f"{path}[{i}]", 1, NODE_BUTTONS))
        if buttons[-1] is None:
            return None
    return tuple(buttons)


# --------------------------------------------------------------------------- cross checks


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


def _check_clashes(reader: _Reader, config: Config) -> None:
    nodes: dict[int, _NodeUse] = {}
    for device in config.devices:
        axes, bits = device_claims(device)
        _check_own_clashes(reader, device, bits)
        if device.node_id is None:
            continue
        use = nodes.setdefault(device.node_id, _NodeUse())
        _check_node_clash(reader, device, use, axes, bits)


def _check_own_clashes(
    reader: _Reader, device: DeviceConfig, bits: list[tuple[str, Where]]
) -> None:
    seen: dict[str, Where] = {}
    for bit, where in bits:
        if bit in seen:
            reader.errors.append(f"{where}: {bit} is already fed from line {seen[bit].line}")
        seen.setdefault(bit, where)


def _check_node_clash(
    reader: _Reader,
    device: DeviceConfig,
    use: _NodeUse,
    axes: list[tuple[str, Where]],
    bits: list[tuple[str, Where]],
) -> None:
    owner = f"device {device.name!r} (line {device.where.line})"
    node = f"node {device.node_id}"
    if use.everything or (device.default_layout and (use.axes or use.bits)):
        first = use.everything or next(iter({**use.axes, **use.bits}.values()))
        reader.errors.append(
            f"{device.where}.node_id: {node} is already fed by {first}; a device on the "
            "default layout needs a node of its own (or list its axes, buttons and hats)"
        )
        return
    if device.default_layout:
        use.everything = owner
        return
    for slot, where in axes:
        if slot in use.axes:
            reader.errors.append(f"{where}: {node} axis {slot} is already fed by {use.axes[slot]}")
        use.axes.setdefault(slot, owner)
    for bit, where in bits:
        if use.bits.get(bit, owner) != owner:
            reader.errors.append(f"{where}: {node} {bit} is already fed by {use.bits[bit]}")
        use.bits.setdefault(bit, owner)


def _check_channels(reader: _Reader, config: Config) -> None:
    for output in config.outputs:
        if output.channels is None:
            continue
        for name, where in zip(output.channels, output.channel_wheres, strict=False):
            problem = channel_problem(config, name)
            if problem:
                reader.errors.append(f"{where}: {problem}")


def channel_problem(config: Config, name: str) -> str | None:
    """Why a SUMD channel name cannot be fed, or None. Bad syntax is reported elsewhere."""
    parsed = _parse_channel_name(name)
    if parsed is None:
        return None
    node_id, kind, what = parsed
    pinned = [d for d in config.devices if d.node_id == node_id]
    if not pinned:
        if config.defaults:
            return None  # an automatically numbered node may have it
        return f"{name}: no device is pinned to node {node_id} and defaults is false"
    if any(d.default_layout for d in pinned):
        return None
    claims = [device_claims(d) for d in pinned]
    if kind == "axis":
        if any(slot == what for axes, _ in claims for slot, _ in axes):
            return None
        return f"{name}: no device feeds axis {what} of node {node_id}"
    if any(bit == f"button {what}" for _, bits in claims for bit, _ in bits):
        return None
    return f"{name}: no device feeds button {what} of node {node_id}"
