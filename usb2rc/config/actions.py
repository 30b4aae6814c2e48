"""A MAVLink output's `actions:` (docs/CONFIG.md, "MAVLink actions"), read into
`config.controls_model.ActionConfig`. Imported by `config.mavlink` (the MAVLink options'
reader), so it imports neither config.model nor pymavlink; `config.controls` checks the
switch names actions use."""

from __future__ import annotations

from typing import Any

from yaml.nodes import Node, ScalarNode

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.config.controls_model import MAX_POSITIONS, ActionConfig
from usb2rc.config.yamlnodes import NodeReader

ACTION_KEYS = ("button", "switch", "position", "do", "hold")
SIMPLE_ACTIONS = ("arm", "disarm", "rtl", "land")
ACTION_ALLOWED = "arm, disarm, rtl, land, {mode: NAME}, {command_long: {command, params}}"
DEFAULT_ARM_HOLD_S = 1.0
BUTTON_ALLOWED = "nodeN.buttonK (K 1..56)"


def button_ref(reader: NodeReader, node: Node, path: str) -> ChannelRef | None:
    name = reader.string(node, path)
    if name is None:
        return None
    ref = ChannelRef.parse(name)
    if ref is None or ref.kind != "button":
        reader.error(node, path, f"{name!r} is not a node button", BUTTON_ALLOWED)
        return None
    return ref


def read_actions(reader: NodeReader, node: Node, path: str) -> tuple[ActionConfig, ...] | None:
    """A MAVLink output's `actions:` list."""
    return reader.list_of(node, path, _read_action)


def _read_action(reader: NodeReader, node: Node, path: str) -> ActionConfig | None:
    items = reader.mapping(node, path, ACTION_KEYS)
    if items is None:
        return None
    triggers = [key for key in ("button", "switch") if key in items]
    if len(triggers) != 1 or "do" not in items:
        reader.error(node, path, "needs do and one of button, switch", "button|switch, do")
        return None
    values: dict[str, Any] = {"where": reader.where(node, path)}
    if "button" in items:
        values["button"] = button_ref(reader, items["button"][1], f"{path}.button")
        if values["button"] is None:
            return None
    else:
        values["switch"] = reader.string(items["switch"][1], f"{path}.switch")
        if "position" in items:
            values["position"] = reader.integer(
                items["position"][1], f"{path}.position", 0, MAX_POSITIONS - 1
            )
    what = _read_do(reader, items["do"][1], f"{path}.do")
    if what is None or any(v is None for v in values.values()):
        return None
    values.update(what)
    default_hold = DEFAULT_ARM_HOLD_S if values["kind"] in ("arm", "disarm") else 0.0
    values["hold"] = default_hold
    if "hold" in items:
        values["hold"] = reader.number(items["hold"][1], f"{path}.hold", 0, 10)
        if values["hold"] is None:
            return None
        if values["kind"] in ("arm", "disarm") and values["hold"] <= 0:
            reader.error(
                items["hold"][1],
                f"{path}.hold",
                "arm and disarm need a hold",
                "0 < hold <= 10 (seconds)",
            )
            return None
    return ActionConfig(**values)


def _read_do(reader: NodeReader, node: Node, path: str) -> dict[str, Any] | None:
    if isinstance(node, ScalarNode):
        kind = reader.choice(node, path, SIMPLE_ACTIONS)
        return None if kind is None else {"kind": kind}
    items = reader.mapping(node, path, ("mode", "command_long"))
    if items is None or len(items) != 1:
        if items is not None:
            reader.error(node, path, "one action", ACTION_ALLOWED)
        return None
    if "mode" in items:
        mode = reader.string(items["mode"][1], f"{path}.mode")
        return None if mode is None else {"kind": "mode", "mode": mode.upper()}
    return _read_command_long(reader, items["command_long"][1], f"{path}.command_long")


def _read_command_long(reader: NodeReader, node: Node, path: str) -> dict[str, Any] | None:
    items = reader.mapping(node, path, ("command", "params"))
    if items is None:
        return None
    if "command" not in items:
        reader.error(node, f"{path}.command", "missing", "a MAV_CMD number 0..65535")
        return None
    command = reader.integer(items["command"][1], f"{path}.command", 0, 65535)
    params: list[float | None] = []
    if "params" in items:
        entries = reader.sequence(items["params"][1], f"{path}.params") or []
        if len(entries) > 7:
            reader.error(items["params"][1], f"{path}.params", f"{len(entries)} params", "0..7")
            return None
        params = [reader.number(p, f"{path}.params[{i}]", -1e9, 1e9) for i, p in enumerate(entries)]
    if command is None or any(p is None for p in params):
        return None
    return {"kind": "command_long", "command": command, "params": tuple(params)}
