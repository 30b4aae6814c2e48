"""Write axis calibrations into a config's text, changing nothing else in the file.

`usb2rc calibrate` must keep the user's comments, key alignment, quoting and indentation. A
YAML round trip (load, change, dump) re-emits the whole file: ruamel.yaml's round-trip mode
keeps comments but not the alignment `x:  {usage: X}` (it changed 9 lines of
the starter hotas.yaml with no edit at all). So this module edits the text in place: it composes
the file (`yamlnodes.compose`, the parser the config reader uses), finds each axis's node by
its position, and splices new text into exactly the spans that change:

- a flow mapping `x: {usage: X, expo: 0.3}` gets `, calibration: {...}` before its `}`, or
  its existing `calibration` / `deadband` value replaced;
- the shorthand `x: X` becomes `x: {usage: X, calibration: {...}}`;
- a block mapping gets a `calibration: {...}` line after its last key (at the keys' column),
  or its existing values replaced, key by key, inside a block `calibration:` too.

`set_calibrations` then reads the result back as a config and checks that each axis holds
exactly what was written: an edit that would not round-trip raises `EditError` and nothing
is written.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from usb2rc.config.yamlnodes import compose
from usb2rc.configfile import Calibration, ConfigError, load_config_text

# A value to write: scalar text, or a mapping of them (written as a flow mapping).
Value = str | dict[str, "Value"]


class EditError(ValueError):
    """The config's text cannot take the edit (no such axis, or it would not read back)."""


@dataclass(frozen=True)
class AxisCalibration:
    """What to write into `devices[device].axes.<slot>`."""

    device: int  # index in the config's devices list
    slot: str
    calibration: Calibration
    deadband: float | None = None  # None: leave the axis's deadband as it is


@dataclass(frozen=True)
class _Splice:
    start: int
    end: int
    text: str


def flow_text(value: Value) -> str:
    if isinstance(value, str):
        return value
    return "{" + ", ".join(f"{k}: {flow_text(v)}" for k, v in value.items()) + "}"


def deadband_text(deadband: float) -> str:
    return f"{deadband:.2f}".rstrip("0").rstrip(".") if deadband else "0"


def calibration_value(cal: Calibration) -> dict[str, Value]:
    return {"min": str(cal.min), "center": str(cal.center), "max": str(cal.max)}


def _item(node: MappingNode, key: str) -> tuple[ScalarNode, Node] | None:
    for key_node, value_node in node.value:
        if isinstance(key_node, ScalarNode) and key_node.value == key:
            return key_node, value_node
    return None


def _child(node: Node | None, key: str, path: str) -> Node:
    item = _item(node, key) if isinstance(node, MappingNode) else None
    if item is None:
        raise EditError(f"{path}: no `{key}` mapping to write into")
    return item[1]


def _end(node: Node) -> int:
    """Where a node's own text ends. A block collection's end mark lies at the next token
    (past comments and blank lines), so take its last child's end instead."""
    if isinstance(node, MappingNode) and not node.flow_style and node.value:
        return _end(node.value[-1][1])
    if isinstance(node, SequenceNode) and not node.flow_style and node.value:
        return _end(node.value[-1])
    return int(node.end_mark.index)


def _insert_flow(text: str, node: MappingNode, key: str, value: Value) -> _Splice:
    if node.value:
        at = _end(node.value[-1][1])
        return _Splice(at, at, f", {key}: {flow_text(value)}")
    at = int(node.start_mark.index) + 1  # just after `{`
    return _Splice(at, at, f"{key}: {flow_text(value)}")


def _insert_block(text: str, node: MappingNode, key: str, value: Value) -> _Splice:
    """A new line after the mapping's last line, at its keys' column; that line's comment
    stays where it is."""
    column = int(node.value[0][0].start_mark.column)
    end = _end(node.value[-1][1])
    if end > 0 and text[end - 1] == "\n":  # a block scalar ends after its newline
        return _Splice(end, end, " " * column + f"{key}: {flow_text(value)}\n")
    eol = text.find("\n", end)
    eol = len(text) if eol < 0 else eol
    return _Splice(eol, eol, "\n" + " " * column + f"{key}: {flow_text(value)}")


def _set(text: str, node: MappingNode, key: str, value: Value) -> list[_Splice]:
    """Splices that make `node[key]` read as `value`, keeping what is there where it can."""
    item = _item(node, key)
    if item is None:
        insert = _insert_flow if node.flow_style else _insert_block
        return [insert(text, node, key, value)]
    old = item[1]
    if isinstance(value, dict) and isinstance(old, MappingNode) and old.value:
        return [s for k, v in value.items() for s in _set(text, old, k, v)]
    return [_Splice(int(old.start_mark.index), _end(old), flow_text(value))]


def _axis_splices(text: str, root: Node | None, update: AxisCalibration) -> list[_Splice]:
    path = f"devices[{update.device}].axes.{update.slot}"
    devices = _child(root, "devices", path)
    if not isinstance(devices, SequenceNode) or not 0 <= update.device < len(devices.value):
        raise EditError(f"{path}: no such device entry")
    axes = _child(devices.value[update.device], "axes", path)
    axis = _child(axes, update.slot, path)
    wanted: dict[str, Value] = {"calibration": calibration_value(update.calibration)}
    if update.deadband is not None:
        wanted["deadband"] = deadband_text(update.deadband)
    if isinstance(axis, ScalarNode):  # `x: X` -> `x: {usage: X, calibration: ...}`
        source = text[axis.start_mark.index : axis.end_mark.index]
        new = flow_text({"usage": source, **wanted})
        splices = [_Splice(axis.start_mark.index, axis.end_mark.index, new)]
    elif isinstance(axis, MappingNode) and axis.value:
        splices = [s for key, value in wanted.items() for s in _set(text, axis, key, value)]
    else:
        raise EditError(f"{path}: not an axis mapping")
    if isinstance(axis, ScalarNode) or axis.flow_style:
        splices += _keep_comment_column(text, _end(axis), splices)
    return splices


def _keep_comment_column(text: str, end: int, splices: Sequence[_Splice]) -> list[_Splice]:
    """`x: {usage: X}      # comment` grows by what was spliced in: take that many of the
    spaces before the comment away again (keeping one), so comments stay lined up."""
    grown = sum(len(s.text) - (s.end - s.start) for s in splices)
    spaces = len(text[end:]) - len(text[end:].lstrip(" "))
    if grown <= 0 or text[end + spaces : end + spaces + 1] != "#":
        return []
    return [_Splice(end, end + min(grown, spaces - 1), "")]


def apply_splices(text: str, splices: Sequence[_Splice]) -> str:
    ordered = sorted(splices, key=lambda s: (s.start, s.end))
    for before, after in itertools.pairwise(ordered):
        if after.start < before.end:
            raise EditError("two edits overlap (the same axis given twice?)")
    for splice in reversed(ordered):
        text = text[: splice.start] + splice.text + text[splice.end :]
    return text


def set_calibrations(text: str, updates: Sequence[AxisCalibration], source: str) -> str:
    """The config text with each update written in; raises EditError (or ConfigError when
    the text itself is not a valid config)."""
    root = compose(text, source)
    splices = [s for update in updates for s in _axis_splices(text, root, update)]
    edited = apply_splices(text, splices)
    _check_reads_back(edited, updates, source)
    return edited


def _check_reads_back(text: str, updates: Sequence[AxisCalibration], source: str) -> None:
    try:
        config = load_config_text(text, source)
    except ConfigError as exc:
        raise EditError("the edited config does not pass: " + "; ".join(exc.errors)) from None
    for update in updates:
        axis = next(a for a in config.devices[update.device].axes if a.slot == update.slot)
        deadband_ok = update.deadband is None or abs(axis.deadband - update.deadband) < 0.005
        if axis.calibration != update.calibration or not deadband_ok:
            raise EditError(f"devices[{update.device}].axes.{update.slot}: did not read back")
