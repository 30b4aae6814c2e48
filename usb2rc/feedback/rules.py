"""The config's `feedback:` rules (docs/CONFIG.md, "Feedback"): the sources a rule may read,
and the reading of the rules from YAML into `usb2rc.config.model.FeedbackRule` records.

A rule is `when` (a condition on a source), `device` (a devices: entry's name or a vid:pid)
and one or more actions (`led` + `blink`, `rumble`, `force`, `brightness`, `color`, `text`).
Every problem is reported with file, line and key through the config's `NodeReader`, which
goes on reading after one. `usb2rc.configfile` calls `read_feedback`; the engine
(usb2rc/feedback/engine.py) judges the records.
"""

from __future__ import annotations

import difflib
import re
import string
from collections.abc import Sequence

from yaml.nodes import Node, SequenceNode

from usb2rc.config.layout import MAX_NODE_ID
from usb2rc.config.model import (
    Condition,
    DeviceRef,
    FeedbackRule,
    Rumble,
    SourceRef,
    TextLine,
    TextPiece,
)
from usb2rc.config.yamlnodes import Items, NodeReader, show
from usb2rc.feedback.model import INDICATOR_BITS
from usb2rc.hid.outputs import Capabilities

NUMBER, TEXT, FLAG = "number", "text", "flag"  # a source's kind: what it compares with

# The telemetry sources: name -> (kind, the field of CrsfTelemetry / MavlinkTelemetry).
TELEMETRY_SOURCES: dict[str, tuple[str, str]] = {
    "crsf.link_quality": (NUMBER, "link_quality"),
    "crsf.rssi": (NUMBER, "rssi_dbm"),
    "crsf.snr": (NUMBER, "snr_db"),
    "crsf.battery_voltage": (NUMBER, "battery_v"),
    "crsf.battery_remaining": (NUMBER, "battery_remaining"),
    "crsf.flight_mode": (TEXT, "flight_mode"),
    "mavlink.armed": (FLAG, "armed"),
    "mavlink.mode": (TEXT, "mode"),
    "mavlink.battery_voltage": (NUMBER, "battery_v"),
    "mavlink.battery_remaining": (NUMBER, "battery_remaining"),
    "mavlink.failsafe": (FLAG, "failsafe"),
}
DOWNLINK = "downlink"  # a fresh downlink for the device's node
NODE_FIELDS = ("failsafe", "waiting")  # nodeN.<field>, node.<field>: a node's own state
SOURCE_NAMES = (
    DOWNLINK,
    *TELEMETRY_SOURCES,
    *(f"node.{f}" for f in NODE_FIELDS),
    *(f"nodeN.{f}" for f in NODE_FIELDS),
)
SOURCES_ALLOWED = ", ".join(SOURCE_NAMES) + f" (N: 0..{MAX_NODE_ID})"
# Names users reach for, beside the sources': the source they mean.
SOURCE_ALIASES = {
    "crsf.lq": "crsf.link_quality",
    "crsf.rssi_dbm": "crsf.rssi",
    "crsf.snr_db": "crsf.snr",
    "crsf.battery": "crsf.battery_remaining",
    "crsf.battery_v": "crsf.battery_voltage",
    "crsf.mode": "crsf.flight_mode",
    "mavlink.battery": "mavlink.battery_remaining",
    "mavlink.battery_v": "mavlink.battery_voltage",
    "mavlink.flight_mode": "mavlink.mode",
}
KIND_WORDS = {NUMBER: "a number", TEXT: "a name", FLAG: "true or false"}

OPERATORS = ("<=", ">=", "==", "!=", "<", ">")  # longest first: the regex tries in order
ORDERING = frozenset({"<", "<=", ">", ">="})
CONDITION_ALLOWED = "a source, or `source OP value` with OP one of < <= > >= == !="
_CONDITION = re.compile(
    r"^\s*(?P<source>[A-Za-z_][\w.]*)\s*"
    r"(?:(?P<op>" + "|".join(re.escape(op) for op in OPERATORS) + r")\s*(?P<value>.*?))?\s*$"
)
_NODE_SOURCE = re.compile(r"^node(?P<id>\d+)\.(?P<field>\w+)$")
_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")
_USB_ID = re.compile(r"^(?P<vid>[0-9a-fA-F]{4}):(?P<pid>[0-9a-fA-F]{4})$")

RULE_KEYS = ("when", "device", "led", "blink", "rumble", "force", "brightness", "color", "text")
ACTION_KEYS = ("led", "rumble", "force", "brightness", "color", "text")
RUMBLE_KEYS = ("strong", "weak", "ms")
FORCE_KEYS = ("x", "y")
TEXT_KEYS = ("line", "text")
MAX_BLINK_HZ = 5.0  # a blink changes twice a period; a device takes 20 writes a second
MIN_BLINK_HZ = 0.1
MAX_PULSE_MS = 10_000
MAX_TEXT_LINE = 16
# What a text field's format is tried with at load, per kind (a bad format is an error then).
FORMAT_SAMPLES: dict[str, tuple[object, ...]] = {
    NUMBER: (1, 1.5),
    TEXT: ("ACRO",),
    FLAG: ("yes",),
}


# --------------------------------------------------------------------------- sources


def parse_source(name: str) -> SourceRef | str:
    """The source `name` refers to, or what is wrong with it (a message)."""
    if name == DOWNLINK:
        return SourceRef(name, FLAG)
    if name in TELEMETRY_SOURCES:
        return SourceRef(name, TELEMETRY_SOURCES[name][0])
    family, _, field = name.partition(".")
    if family == "node" and field in NODE_FIELDS:
        return SourceRef(name, FLAG)
    node = _NODE_SOURCE.match(name)
    if node is not None and node["field"] in NODE_FIELDS:
        node_id = int(node["id"])
        if node_id > MAX_NODE_ID:
            return f"Node-ID {node_id} is out of range"
        return SourceRef(name, FLAG, node_id)
    return f"unknown source {name!r}"


def source_suggestion(name: str) -> str | None:
    """The known source closest to a wrong name (nodeN.* as node3.* when `name` is node3.x)."""
    if name in SOURCE_ALIASES:
        return SOURCE_ALIASES[name]
    node = _NODE_SOURCE.match(name)
    if node is not None and node["field"] in NODE_FIELDS:
        return None  # a Node-ID out of range
    if node is not None:
        close = difflib.get_close_matches(node["field"], NODE_FIELDS, n=1)
        return f"node{node['id']}.{close[0]}" if close else None
    close = difflib.get_close_matches(name, SOURCE_NAMES, n=1)
    return close[0] if close else None


def _source_error(reader: NodeReader, node: Node, path: str, message: str, name: str) -> None:
    reader.error(node, path, message, SOURCES_ALLOWED, source_suggestion(name))


# --------------------------------------------------------------------------- rules


def read_feedback(
    reader: NodeReader, node: Node, entry_names: Sequence[str]
) -> tuple[FeedbackRule, ...]:
    """The `feedback:` list; `entry_names`: the devices: entries a rule's `device` may name."""
    if not isinstance(node, SequenceNode):
        reader.error(node, "feedback", f"expected a list of rules, got {show(node)}", "[] for none")
        return ()
    return reader.list_of(
        node, "feedback", lambda r, entry, path: _read_rule(r, entry, path, entry_names)
    )


def _read_rule(
    reader: NodeReader, node: Node, path: str, entry_names: Sequence[str]
) -> FeedbackRule | None:
    problems = len(reader.problems)
    items = reader.mapping(node, path, RULE_KEYS)
    if items is None:
        return None
    if not any(key in items for key in ACTION_KEYS):
        if len(reader.problems) == problems:  # else a misspelt action was named already
            reader.error(node, path, "a rule needs an action", ", ".join(ACTION_KEYS))
        return None
    when = _read_when(reader, items["when"][1], f"{path}.when") if "when" in items else None
    device = None
    if "device" in items:
        device = _read_device(reader, items["device"][1], f"{path}.device", entry_names)
    leds = _read_leds(reader, items["led"][1], f"{path}.led") if "led" in items else ()
    blink = None
    if "blink" in items:
        blink = reader.number(items["blink"][1], f"{path}.blink", MIN_BLINK_HZ, MAX_BLINK_HZ)
        if "led" not in items:
            reader.error(items["blink"][0], f"{path}.blink", "blink needs a led to blink", "led")
    rumble = (
        _read_rumble(reader, items["rumble"][1], f"{path}.rumble") if "rumble" in items else None
    )
    if rumble is not None and rumble.ms is not None and "when" not in items:
        message = "a pulse starts when the rule's `when` turns true: give a when, or drop ms"
        reader.error(items["rumble"][1], f"{path}.rumble.ms", message)
    force = _read_force(reader, items["force"][1], f"{path}.force") if "force" in items else None
    brightness = None
    if "brightness" in items:
        brightness = reader.number(items["brightness"][1], f"{path}.brightness", 0, 1)
    color = _read_color(reader, items["color"][1], f"{path}.color") if "color" in items else None
    text = _read_text(reader, items["text"][1], f"{path}.text") if "text" in items else None
    if len(reader.problems) > problems:
        return None
    lines = tuple((key, key_node.start_mark.line + 1) for key, (key_node, _) in items.items())
    where = reader.where(node, path)
    return FeedbackRule(
        when, device, leds, blink, rumble, force, brightness, color, text, where, lines
    )


def _read_when(reader: NodeReader, node: Node, path: str) -> Condition | None:
    text = reader.string(node, path)
    if text is None:
        return None
    allowed = CONDITION_ALLOWED
    parsed = _CONDITION.match(text)
    if parsed is None:
        reader.error(node, path, f"not a condition: {text!r}", allowed)
        return None
    source = parse_source(parsed["source"])
    if isinstance(source, str):
        _source_error(reader, node, path, source, parsed["source"])
        return None
    op = parsed["op"]
    if op is None:
        return Condition(source, text=text.strip())
    if not parsed["value"]:
        reader.error(node, path, f"nothing to compare with after {op!r}", allowed)
        return None
    value = _condition_value(reader, node, path, source, op, parsed["value"])
    return None if value is None else Condition(source, op, value, text.strip())


def _condition_value(
    reader: NodeReader, node: Node, path: str, source: SourceRef, op: str, written: str
) -> float | str | bool | None:
    """The value a condition compares its source with, checked against the source's kind."""
    if source.kind != NUMBER and op in ORDERING:
        message = f"{source.name} is {KIND_WORDS[source.kind]}: only == and != compare it"
        reader.error(node, path, message, "== !=")
        return None
    if source.kind == NUMBER:
        if not _NUMBER.match(written):
            message = f"{source.name} compares with a number, not {written!r}"
            reader.error(node, path, message, "a number")
            return None
        number = float(written)
        return int(number) if number.is_integer() else number
    if source.kind == FLAG:
        if written.lower() not in ("true", "false"):
            message = f"{source.name} compares with true or false, not {written!r}"
            reader.error(node, path, message, "true, false")
            return None
        return written.lower() == "true"
    if len(written) >= 2 and written[0] == written[-1] and written[0] in "'\"":
        return written[1:-1]
    return written


def _read_device(
    reader: NodeReader, node: Node, path: str, entry_names: Sequence[str]
) -> DeviceRef | None:
    name = reader.string(node, path)
    if name is None:
        return None
    usb = _USB_ID.match(name)
    if usb is not None:
        return DeviceRef(vid=int(usb["vid"], 16), pid=int(usb["pid"], 16))
    if name not in entry_names:
        close = difflib.get_close_matches(name, entry_names, n=1)
        allowed = ", ".join([*entry_names, "vvvv:pppp (a vid:pid in hex)"])
        reader.error(node, path, f"no devices: entry is named {name!r}", allowed, *close[:1])
        return None
    return DeviceRef(entry=name)


def _read_leds(reader: NodeReader, node: Node, path: str) -> tuple[int | str, ...]:
    """One indicator or a list of them, each an index (0..63) or a name."""
    entries = node.value if isinstance(node, SequenceNode) else [node]
    leds: list[int | str] = []
    for i, entry in enumerate(entries):
        where = f"{path}[{i}]" if isinstance(node, SequenceNode) else path
        value = reader.scalar(entry)
        if isinstance(value, int) and not isinstance(value, bool):
            index = reader.integer(entry, where, 0, INDICATOR_BITS - 1)
            if index is not None:
                leds.append(index)
        else:
            name = reader.string(entry, where)
            if name is not None:
                leds.append(name)
    if not entries:
        reader.error(node, path, "no indicator", "an index 0..63 or a name, or a list of them")
    return tuple(leds)


def _read_rumble(reader: NodeReader, node: Node, path: str) -> Rumble | None:
    items = reader.mapping(node, path, RUMBLE_KEYS)
    if items is None:
        return None
    if "strong" not in items and "weak" not in items:
        reader.error(node, path, "no motor given", "strong, weak (0..1), ms")
        return None
    strong = _fraction(reader, items, "strong", path)
    weak = _fraction(reader, items, "weak", path)
    ms = None
    if "ms" in items:
        ms = reader.integer(items["ms"][1], f"{path}.ms", 1, MAX_PULSE_MS)
    if strong is None or weak is None or ("ms" in items and ms is None):
        return None
    return Rumble(strong, weak, ms)


def _fraction(reader: NodeReader, items: Items, key: str, path: str) -> float | None:
    """A 0..1 value of a mapping; absent: 0."""
    if key not in items:
        return 0.0
    return reader.number(items[key][1], f"{path}.{key}", 0, 1)


def _read_force(reader: NodeReader, node: Node, path: str) -> tuple[float, float] | None:
    items = reader.mapping(node, path, FORCE_KEYS)
    if items is None:
        return None
    if not items:
        reader.error(node, path, "no force given", "x, y (-1..1)")
        return None
    x, y = (
        reader.number(items[k][1], f"{path}.{k}", -1, 1) if k in items else 0.0 for k in FORCE_KEYS
    )
    return None if x is None or y is None else (x, y)


def _read_color(reader: NodeReader, node: Node, path: str) -> tuple[int, int, int] | None:
    entries = reader.sequence(node, path)
    if entries is None:
        return None
    if len(entries) != 3:
        reader.error(node, path, f"{len(entries)} values", "[r, g, b], each 0..255")
        return None
    r, g, b = (reader.integer(e, f"{path}[{i}]", 0, 255) for i, e in enumerate(entries))
    return None if r is None or g is None or b is None else (r, g, b)


def _read_text(reader: NodeReader, node: Node, path: str) -> TextLine | None:
    items = reader.mapping(node, path, TEXT_KEYS)
    if items is None:
        return None
    missing = [key for key in TEXT_KEYS if key not in items]
    if missing:
        reader.error(node, path, f"missing {' and '.join(missing)}", "{line: 1, text: ...}")
        return None
    line = reader.integer(items["line"][1], f"{path}.line", 1, MAX_TEXT_LINE)
    template = reader.string(items["text"][1], f"{path}.text")
    if line is None or template is None:
        return None
    pieces = _text_pieces(reader, items["text"][1], f"{path}.text", template)
    return None if pieces is None else TextLine(line, pieces, template)


def _text_pieces(
    reader: NodeReader, node: Node, path: str, template: str
) -> tuple[TextPiece, ...] | None:
    """A display text's literal parts and `{source}` / `{source:format}` fields."""
    try:
        parsed = list(string.Formatter().parse(template))
    except ValueError as exc:
        reader.error(node, path, f"bad text: {exc}", "text with {source} fields; {{ }} for braces")
        return None
    pieces: list[TextPiece] = []
    for literal, field, spec, conversion in parsed:
        if pieces and pieces[-1].source is None:  # `{{` splits a literal: one again
            literal = pieces.pop().literal + literal
        if field is None:
            pieces.append(TextPiece(literal))
            continue
        source = parse_source(field)
        if isinstance(source, str):
            _source_error(reader, node, path, f"{{{field}}}: {source}", field)
            return None
        if conversion is not None or not _formats(source.kind, spec or ""):
            shown = spec or f"!{conversion}"
            message = f"{{{field}}}: bad format {shown!r} for {KIND_WORDS[source.kind]}"
            reader.error(node, path, message, "a Python format such as {crsf.battery_voltage:.1f}")
            return None
        pieces.append(TextPiece(literal, source, spec or ""))
    return tuple(pieces)


def _formats(kind: str, spec: str) -> bool:
    """Whether a value of this kind can be shown with this format."""
    for sample in FORMAT_SAMPLES[kind]:
        try:
            format(sample, spec)
        except (ValueError, TypeError):
            continue
        return True
    return False


# --------------------------------------------------------------------------- outputs a device lacks


def missing_outputs(rule: FeedbackRule, capabilities: Capabilities) -> list[tuple[str, str]]:
    """What a rule drives that a device does not have: (the rule's key, what is missing)."""
    missing = [("led", what) for what in _missing_leds(rule.leds, capabilities)]
    analog = set(capabilities.analog)
    wanted = {
        "rumble": _rumble_outputs(rule.rumble),
        "force": () if rule.force is None else ("force_x", "force_y"),
        "brightness": () if rule.brightness is None else ("brightness",),
        "color": () if rule.color is None else ("red", "green", "blue"),
    }
    for key, names in wanted.items():
        lacking = [name for name in names if name not in analog]
        if lacking:
            missing.append((key, " or ".join(lacking)))
    if rule.text is not None and rule.text.line > capabilities.text_lines:
        has = f"{capabilities.text_lines} lines" if capabilities.text_lines else "no display"
        missing.append(("text.line", f"display line {rule.text.line} (it has {has})"))
    return missing


def _missing_leds(leds: Sequence[int | str], capabilities: Capabilities) -> list[str]:
    names = [name.casefold() for name in capabilities.indicator_names]
    known = ", ".join(capabilities.indicator_names) or "none"
    count = capabilities.indicators
    indexes = f"0..{count - 1}" if count else "none"
    found = []
    for led in leds:
        if isinstance(led, int) and led >= count:
            found.append(f"indicator {led} (its indicators: {indexes})")
        elif isinstance(led, str) and led.casefold() not in names:
            found.append(f"indicator {led!r} (its indicators: {known})")
    return found


def _rumble_outputs(rumble: Rumble | None) -> tuple[str, ...]:
    if rumble is None:
        return ()
    motors = (("rumble_strong", rumble.strong), ("rumble_weak", rumble.weak))
    return tuple(name for name, value in motors if value > 0)
