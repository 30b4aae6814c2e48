"""Read the `devices:` entries of a config: match, node_id, axes, buttons, hats.

Part of the config file's schema (docs/CONFIG.md describes each key); `usb2rc.configfile`
calls `read_devices`.
Every problem goes to the NodeReader, which keeps reading after one.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from yaml.nodes import Node, ScalarNode

from usb2rc.config.layout import AXIS_NAMES, MAX_NODE_ID, NODE_BUTTONS
from usb2rc.config.model import (
    ARM_CHOICES,
    AUTO_LOW_BATTERY,
    HAT_DIRECTIONS,
    MAX_HID_BUTTON,
    AxisConfig,
    ButtonRoute,
    Calibration,
    DeviceConfig,
    HatConfig,
    LowBatteryConfig,
    MatchConfig,
    TrimSwitchConfig,
)
from usb2rc.config.status import read_handover, read_low_battery
from usb2rc.config.usages import read_usage, read_usage_occurrence
from usb2rc.config.yamlnodes import Items, NodeReader, show
from usb2rc.hid.usages import GD_HAT_SWITCH

DEVICE_KEYS = (
    "name",
    "match",
    "node_id",
    "axes",
    "buttons",
    "hats",
    "handover",
    "low_battery",
    "reports",
)
REPORT_KINDS = ("auto", "streaming", "on_change")  # usb2rc.nodes.silence
MATCH_KEYS = ("vid", "pid", "serial", "port", "product")
AXIS_KEYS = (
    "usage", "occurrence", "hat", "axis", "buttons", "calibration", "deadband", "expo",
    "invert", "trim", "unsigned", "failsafe", "arm", "arm_tolerance", "trim_switch",
)  # fmt: skip
TRIM_SWITCH_KEYS = ("hat", "axis", "occurrence", "buttons", "step", "limit")
HAT_KEYS = ("usage", "occurrence", "to")
# --------------------------------------------------------------------------- devices


def read_devices(reader: NodeReader, node: Node) -> tuple[DeviceConfig, ...]:
    devices = reader.list_of(node, "devices", _read_device)
    seen: dict[str, DeviceConfig] = {}
    for device in devices:
        if device.name in seen:
            first = seen[device.name].where
            reader.report(
                device.where.problem(
                    f"duplicate device name {device.name!r} (first at line {first.line})",
                    key_suffix=".name",
                )
            )
        seen.setdefault(device.name, device)
    return devices


def _read_device(reader: NodeReader, node: Node, path: str) -> DeviceConfig | None:
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
        node_id = reader.integer(items["node_id"][1], f"{path}.node_id", 0, MAX_NODE_ID)
    axes: tuple[AxisConfig, ...] = ()
    if "axes" in items:
        axes = _read_axes(reader, items["axes"][1], f"{path}.axes")
    buttons: tuple[ButtonRoute, ...] = ()
    if "buttons" in items:
        buttons = _read_buttons(reader, items["buttons"][1], f"{path}.buttons")
    hats: tuple[HatConfig, ...] = ()
    if "hats" in items:
        hats = reader.list_of(items["hats"][1], f"{path}.hats", _read_hat)
    default_layout = not any(key in items for key in ("axes", "buttons", "hats"))
    handover = None
    if "handover" in items:
        handover = read_handover(reader, items["handover"][1], f"{path}.handover")
    low_battery: LowBatteryConfig | None = AUTO_LOW_BATTERY
    if "low_battery" in items:
        low_battery = read_low_battery(reader, items["low_battery"][1], f"{path}.low_battery")
    reports = "auto"
    if "reports" in items:
        reports = reader.choice(items["reports"][1], f"{path}.reports", REPORT_KINDS) or "auto"
    where = reader.where(node, path)
    return DeviceConfig(
        name,
        match,
        node_id,
        axes,
        buttons,
        hats,
        default_layout,
        where,
        handover,
        low_battery,
        reports,
    )


def _read_match(reader: NodeReader, node: Node, items: Items, path: str) -> MatchConfig:
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


def _read_axes(reader: NodeReader, node: Node, path: str) -> tuple[AxisConfig, ...]:
    items = reader.mapping(node, path, AXIS_NAMES)
    if items is None:
        return ()
    axes = (_read_axis(reader, slot, v, f"{path}.{slot}") for slot, (_, v) in items.items())
    return tuple(a for a in axes if a is not None)


def _read_axis(reader: NodeReader, slot: str, node: Node, path: str) -> AxisConfig | None:
    if isinstance(node, ScalarNode):  # shorthand: `x: X`
        usage = read_usage(reader, node, path)
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
    reader: NodeReader, node: Node, items: Items, path: str
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
        usage = read_usage(reader, items["usage"][1], f"{path}.usage")
        return None if usage is None else {"usage": usage, "occurrence": occurrence}
    if kind == "hat":
        return _read_hat_axis(reader, node, items, path, occurrence)
    return _read_button_pair(reader, items["buttons"][1], f"{path}.buttons")


def _read_hat_axis(
    reader: NodeReader, node: Node, items: Items, path: str, occurrence: int
) -> dict[str, Any] | None:
    hat = read_usage(reader, items["hat"][1], f"{path}.hat")
    if "axis" not in items:
        reader.error(node, f"{path}.axis", "missing: which hat axis", "x, y")
        return None
    axis = reader.choice(items["axis"][1], f"{path}.axis", ("x", "y"))
    if hat is None or axis is None:
        return None
    return {"hat": hat, "hat_axis": axis, "occurrence": occurrence}


def _read_button_pair(reader: NodeReader, node: Node, path: str) -> dict[str, Any] | None:
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
    reader: NodeReader, items: Items, path: str, shaped_source: bool
) -> dict[str, Any] | None:
    ok = True
    options: dict[str, Any] = {}
    simple: dict[str, Callable[[Node, str], Any]] = {
        "deadband": lambda n, p: reader.number(n, p, 0.0, 0.99),
        "expo": lambda n, p: reader.number(n, p, 0.0, 1.0),
        "trim": lambda n, p: reader.number(n, p, -1.0, 1.0),
        "invert": reader.boolean,
        "unsigned": reader.boolean,
        "arm": lambda n, p: reader.choice(n, p, ARM_CHOICES),
        "arm_tolerance": lambda n, p: reader.number(n, p, 0.0, 1.0),
        "trim_switch": lambda n, p: _read_trim_switch(reader, n, p),
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


def _read_trim_switch(reader: NodeReader, node: Node, path: str) -> TrimSwitchConfig | None:
    """`trim_switch: {buttons: [minus, plus]}` or `{hat: HatSwitch, axis: x|y}`, with
    `step` and `limit` (fractions of the half range)."""
    items = reader.mapping(node, path, TRIM_SWITCH_KEYS)
    if items is None:
        return None
    given = [key for key in ("hat", "buttons") if key in items]
    if len(given) != 1:
        what = "missing" if not given else "hat and buttons both given"
        reader.error(node, path, f"trim switch {what}: give exactly one of hat, buttons")
        return None
    source: dict[str, Any] | None
    if given[0] == "hat":
        occurrence = 0
        if "occurrence" in items:
            occurrence = reader.integer(items["occurrence"][1], f"{path}.occurrence", 0, 255) or 0
        source = _read_hat_axis(reader, node, items, path, occurrence)
    else:
        for key in ("axis", "occurrence"):
            if key in items:
                reader.error(items[key][0], f"{path}.{key}", "only with a hat trim switch")
        source = _read_button_pair(reader, items["buttons"][1], f"{path}.buttons")
    options: dict[str, Any] = {}
    for key, lo in (("step", 0.001), ("limit", 0.0)):
        if key in items:
            options[key] = reader.number(items[key][1], f"{path}.{key}", lo, 1.0)
            if options[key] is None:
                return None
    if source is None:
        return None
    return TrimSwitchConfig(reader.where(node, path), **source, **options)


def _read_calibration(reader: NodeReader, node: Node, path: str) -> Calibration | None:
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


def _read_buttons(reader: NodeReader, node: Node, path: str) -> tuple[ButtonRoute, ...]:
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
                f"bad node button(s) {show(value_node)}",
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


def _read_hat(reader: NodeReader, node: Node, path: str) -> HatConfig | None:
    items = reader.mapping(node, path, HAT_KEYS)
    if items is None:
        return None
    usage, occurrence = read_usage_occurrence(reader, items, path, GD_HAT_SWITCH)
    if "to" not in items:
        reader.error(node, f"{path}.to", "missing", "hat1, or a list of 8 node buttons")
        return None
    to = _read_hat_target(reader, items["to"][1], f"{path}.to")
    if usage is None or to is None:
        return None
    return HatConfig(usage, occurrence, to, reader.where(node, path))


def _read_hat_target(
    reader: NodeReader, node: Node, path: str
) -> str | tuple[int | None, ...] | None:
    allowed = f"hat1, or a list of 8 node buttons 1..{NODE_BUTTONS} (null: unused), in the order "
    allowed += ", ".join(HAT_DIRECTIONS)
    if isinstance(node, ScalarNode):
        if reader.scalar(node) == "hat1":
            return "hat1"
        reader.error(node, path, f"{show(node)} is not valid", allowed)
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
