"""The controls' keys in the config (docs/CONFIG.md, "Switches", "Mixes and curves",
"Throttle cut", "MAVLink actions"): top-level `switches:` and `throttle_cut:`, a channel item
`{mix: [...]}`, and a MAVLink output's `actions:`, read into `usb2rc.config.controls_model`; then
`check_controls` cross-checks the names (a switch that does not exist, with a did-you-mean).
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterator
from typing import Any

from yaml.nodes import MappingNode, Node, SequenceNode

from usb2rc.config.actions import button_ref
from usb2rc.config.checks import channel_problem
from usb2rc.config.controls_model import (
    MAX_POSITIONS,
    SWITCH_KINDS,
    Curve,
    MixInput,
    MixRef,
    Rates,
    SwitchConfig,
    ThrottleCut,
)
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.config.model import CHANNEL_ALLOWED, ChannelRef, Config
from usb2rc.config.yamlnodes import NodeReader, Where

SWITCH_KEYS = (*SWITCH_KINDS, "positions", "initial", "failsafe", "reset", "slot")
MIX_KEYS = ("source", "weight", "offset", "curve", "rates")
CUT_KEYS = ("switch", "channel")
MIN_CURVE_POINTS, MAX_CURVE_POINTS = 3, 17
_NAME_RE = re.compile(r"^[a-z_][a-z0-9_]*$")


# --------------------------------------------------------------------------- switches


def read_switches(reader: NodeReader, node: Node) -> tuple[SwitchConfig, ...]:
    items = reader.mapping(node, "switches", None)
    if items is None:
        return ()
    switches = []
    for name, (key_node, value) in items.items():
        if not _NAME_RE.match(name):
            reader.error(key_node, f"switches.{name}", "bad switch name", "a-z, 0-9, _")
            continue
        switch = _read_switch(reader, value, name)
        if switch is not None:
            switches.append(switch)
    return tuple(switches)


def _read_switch(reader: NodeReader, node: Node, name: str) -> SwitchConfig | None:
    path = f"switches.{name}"
    items = reader.mapping(node, path, SWITCH_KEYS)
    if items is None:
        return None
    kinds = [k for k in SWITCH_KINDS if k in items]
    if len(kinds) != 1:
        reader.error(node, path, "give exactly one switch kind", ", ".join(SWITCH_KINDS))
        return None
    kind = kinds[0]
    buttons = _read_buttons(reader, items[kind][1], f"{path}.{kind}")
    if not buttons:
        return None
    if len({b.node_id for b in buttons}) > 1:
        reader.error(items[kind][1], f"{path}.{kind}", "buttons of one node only")
        return None
    positions = _positions(reader, items, path, kind, buttons)
    if positions is None:
        return None
    values: dict[str, Any] = {"positions": positions, "where": reader.where(node, path)}
    for key in ("initial", "failsafe"):
        if key in items:
            value = reader.integer(items[key][1], f"{path}.{key}", 0, positions - 1)
            if value is not None:
                values[key] = value
    if "reset" in items:
        reset = _read_buttons(reader, items["reset"][1], f"{path}.reset")
        values["reset"] = reset[0] if len(reset) == 1 else None
    if "slot" in items:
        values["slot"] = reader.choice(items["slot"][1], f"{path}.slot", AXIS_NAMES)
    return SwitchConfig(name, kind, buttons, **values)  # type: ignore[arg-type]


def _positions(
    reader: NodeReader, items: Any, path: str, kind: str, buttons: tuple[ChannelRef, ...]
) -> int | None:
    count = len(buttons)
    wrong = {
        "toggle": count != 1,
        "latch": count != 1,
        "steps": count > 2,
        "hat_switch": not 2 <= count <= MAX_POSITIONS,
    }[kind]
    if wrong:
        allowed = {"steps": "1 or 2 buttons", "hat_switch": f"2..{MAX_POSITIONS} buttons"}
        reader.error(
            items[kind][1], f"{path}.{kind}", f"{count} buttons", allowed.get(kind, "1 button")
        )
        return None
    default = {"steps": 3, "hat_switch": count}.get(kind, 2)
    if "positions" not in items:
        return default
    if kind != "steps":
        reader.error(items["positions"][0], f"{path}.positions", f"{kind} has {default}")
        return None
    return reader.integer(items["positions"][1], f"{path}.positions", 2, MAX_POSITIONS)


def _read_buttons(reader: NodeReader, node: Node, path: str) -> tuple[ChannelRef, ...]:
    nodes = node.value if isinstance(node, SequenceNode) else [node]
    refs = []
    for i, entry in enumerate(nodes):
        where = f"{path}[{i}]" if isinstance(node, SequenceNode) else path
        ref = button_ref(reader, entry, where)
        if ref is None:
            return ()
        refs.append(ref)
    return tuple(refs)


def read_throttle_cuts(reader: NodeReader, node: Node) -> tuple[ThrottleCut, ...]:
    """`throttle_cut: {switch, channel}` or a list of them."""
    if isinstance(node, SequenceNode):
        return reader.list_of(node, "throttle_cut", _read_cut)
    cut = _read_cut(reader, node, "throttle_cut")
    return () if cut is None else (cut,)


def _read_cut(reader: NodeReader, node: Node, path: str) -> ThrottleCut | None:
    items = reader.mapping(node, path, CUT_KEYS)
    if items is None:
        return None
    if any(key not in items for key in CUT_KEYS):
        reader.error(node, path, "needs both switch and channel", "switch, channel")
        return None
    switch = reader.string(items["switch"][1], f"{path}.switch")
    name = reader.string(items["channel"][1], f"{path}.channel")
    ref = ChannelRef.parse(name) if name is not None else None
    if ref is None or ref.kind != "axis":
        reader.error(
            items["channel"][1],
            f"{path}.channel",
            f"{name!r} is not an axis slot",
            "nodeN.x, .y, .z, ...",
        )
        return None
    if switch is None:
        return None
    return ThrottleCut(switch, ref, reader.where(node, path))


# --------------------------------------------------------------------------- mixes


def read_mix(reader: NodeReader, node: MappingNode, path: str) -> MixRef | None:
    """A channel item `{mix: [{source, weight, offset, curve, rates}, ...]}`."""
    items = reader.mapping(node, path, ("mix",))
    if items is None or "mix" not in items:
        if items is not None:
            reader.error(node, path, "a channel is a name or {mix: [...]}", CHANNEL_ALLOWED)
        return None
    inputs = reader.list_of(items["mix"][1], f"{path}.mix", _read_mix_input, allow_empty=False)
    if not inputs:
        return None
    return MixRef(inputs, "mix(" + ", ".join(i.source.name for i in inputs) + ")")


def _read_mix_input(reader: NodeReader, node: Node, path: str) -> MixInput | None:
    items = reader.mapping(node, path, MIX_KEYS)
    if items is None:
        return None
    if "source" not in items:
        reader.error(node, f"{path}.source", "missing", CHANNEL_ALLOWED + ", switch.NAME")
        return None
    name = reader.string(items["source"][1], f"{path}.source")
    source = ChannelRef.parse(name) if name is not None else None
    if source is None:
        reader.error(
            items["source"][1],
            f"{path}.source",
            f"bad channel {name!r}",
            CHANNEL_ALLOWED + ", switch.NAME",
        )
        return None
    values: dict[str, Any] = {}
    for key, lo, hi in (("weight", -2.0, 2.0), ("offset", -1.0, 1.0)):
        if key in items:
            values[key] = reader.number(items[key][1], f"{path}.{key}", lo, hi)
    if "curve" in items:
        values["curve"] = _read_curve(reader, items["curve"][1], f"{path}.curve")
    if "rates" in items:
        values["rates"] = _read_rates(reader, items["rates"][1], f"{path}.rates")
    if any(value is None for value in values.values()):
        return None
    return MixInput(source, **values)


def _read_curve(reader: NodeReader, node: Node, path: str) -> Curve | None:
    """`{expo: 0.3}` (0..1, as an axis's expo) or a list of 3..17 points in -1..1."""
    if isinstance(node, SequenceNode):
        allowed = f"{MIN_CURVE_POINTS}..{MAX_CURVE_POINTS} points"
        if not MIN_CURVE_POINTS <= len(node.value) <= MAX_CURVE_POINTS:
            reader.error(node, path, f"{len(node.value)} points", allowed)
            return None
        points = [reader.number(p, f"{path}[{i}]", -1, 1) for i, p in enumerate(node.value)]
        clean = [p for p in points if p is not None]
        return Curve(points=tuple(clean)) if len(clean) == len(points) else None
    items = reader.mapping(node, path, ("expo",))
    if items is None or "expo" not in items:
        if items is not None:
            reader.error(node, path, "missing expo", "{expo: 0..1} or a list of points")
        return None
    expo = reader.number(items["expo"][1], f"{path}.expo", 0, 1)
    return None if expo is None else Curve(expo=expo)


def _read_rates(reader: NodeReader, node: Node, path: str) -> Rates | None:
    items = reader.mapping(node, path, ("switch", "weights"))
    if items is None:
        return None
    if "switch" not in items or "weights" not in items:
        reader.error(node, path, "needs switch and weights", "switch, weights")
        return None
    switch = reader.string(items["switch"][1], f"{path}.switch")
    entries = reader.sequence(items["weights"][1], f"{path}.weights") or []
    weights = [reader.number(w, f"{path}.weights[{i}]", -2, 2) for i, w in enumerate(entries)]
    clean = tuple(w for w in weights if w is not None)
    if switch is None or not clean or len(clean) != len(weights):
        return None
    return Rates(switch, clean)


# --------------------------------------------------------------------------- cross-checks


def check_controls(reader: NodeReader, config: Config) -> None:
    """Every switch a channel, mix, cut or action names exists; a switch's `slot` is not fed
    by a pinned entry of its node too."""
    names = [s.name for s in config.switches]
    for where, name, positions in _switch_uses(config):
        _check_name(reader, where, name, names)
        switch = next((s for s in config.switches if s.name == name), None)
        if switch is not None and positions is not None and positions < 0:
            if -positions - 1 >= switch.positions:  # an action's position
                message = f"switch {name!r} has no position {-positions - 1}"
                reader.report(where.problem(message, f"0..{switch.positions - 1}"))
        elif switch is not None and positions is not None and positions != switch.positions:
            reader.report(
                where.problem(
                    f"{positions} rates for switch {name!r} of {switch.positions} positions",
                    f"{switch.positions} weights",
                )
            )
    for where, ref in _node_refs(config):
        problem = channel_problem(config, ref)
        if problem:
            reader.report(where.problem(problem))
    for switch in config.switches:
        if switch.slot is not None and switch.where is not None:
            fed = [
                d.name
                for d in config.devices
                if d.node_id == switch.node_id and any(a.slot == switch.slot for a in d.axes)
            ]
            if fed:
                reader.report(
                    switch.where.problem(
                        f"slot {switch.slot} of node {switch.node_id} is fed by {fed[0]!r} too",
                        key_suffix=".slot",
                    )
                )


def _check_name(reader: NodeReader, where: Where, name: str, names: list[str]) -> None:
    if name in names:
        return
    close = difflib.get_close_matches(name, names, n=1)
    reader.report(
        where.problem(
            f"no switch {name!r}" + (f" (did you mean {close[0]!r}?)" if close else ""),
            ", ".join(names) or "none configured: add it under switches:",
        )
    )


def _switch_uses(config: Config) -> Iterator[tuple[Where, str, int | None]]:
    """(where, switch name, n) of every use of a switch: n the count of a rates' weights,
    -1 - position for an action's position, None for a plain use."""
    fallback = Where(config.source, 0, "")
    for output in config.outputs:
        wheres = output.channel_wheres or ()
        for i, channel in enumerate(output.channels or ()):
            where = wheres[i] if i < len(wheres) else fallback
            if isinstance(channel, MixRef):
                for line in channel.inputs:
                    if line.source.kind == "switch":
                        yield where, switch_name(line.source), None
                    if line.rates is not None:
                        yield where, line.rates.switch, len(line.rates.weights)
            elif channel.kind == "switch":
                yield where, switch_name(channel), None
        for action in output.option("actions") if output.protocol == "mavlink" else ():
            if action.switch is not None:  # its position, encoded as -1 - position
                yield action.where or fallback, action.switch, -1 - action.position
    for cut in config.throttle_cuts:
        yield cut.where or fallback, cut.switch, None


def _node_refs(config: Config) -> Iterator[tuple[Where, ChannelRef]]:
    """The node buttons and axes the switches, cuts and actions read (the pinned entries
    must feed them, as a channel's)."""
    fallback = Where(config.source, 0, "")
    for switch in config.switches:
        for ref in (*switch.buttons, *((switch.reset,) if switch.reset else ())):
            yield switch.where or fallback, ref
    for cut in config.throttle_cuts:
        yield cut.where or fallback, cut.channel
    for output in config.outputs:
        for action in output.option("actions") if output.protocol == "mavlink" else ():
            if action.button is not None:
                yield action.where or fallback, action.button


def switch_name(ref: ChannelRef) -> str:
    """`switch.gear` -> `gear`."""
    return ref.name.strip().lower().removeprefix("switch.")
