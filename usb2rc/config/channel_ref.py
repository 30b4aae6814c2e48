"""A channel as the config names it, parsed once: `ChannelRef` (`node1.x`, `node1.button5`,
`switch.gear`). Its own module so that the config's dataclasses (`config.model`) and the
controls' (`config.controls_model`) both use it without importing each other; `usb2rc.configfile`
re-exports it."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from usb2rc.config.layout import AXIS_NAMES, MAX_NODE_ID, NODE_BUTTONS

CHANNEL_ALLOWED = "nodeN.x, .y, .z, .slider, .rx, .ry, .rz, .dial, .aux1, .aux2, nodeN.buttonK"
_CHANNEL_RE = re.compile(r"^node(\d+)\.(?:(button)(\d+)|([a-z0-9]+))$")
_SWITCH_RE = re.compile(r"^switch\.([a-z_][a-z0-9_]*)$")


@dataclass(frozen=True)
class ChannelRef:
    """One SUMD channel as configured: a node's axis slot (index 0..9) or button (1..56),
    or a switch (`switch.gear`: node_id and index -1, resolved by `Mapping.sumd_channels`).

    Parsed from its name (`node1.x`, `node1.button5`) once, when the config is read;
    nothing parses a channel name after that.
    """

    node_id: int
    kind: Literal["axis", "button", "switch"]
    index: int  # axis: slot index into AXIS_NAMES; button: node button 1..56
    name: str  # as written in the config, for `check`, `icd` and messages

    @property
    def slot(self) -> str:
        """The axis slot name ("x", "rz", ...); only for kind "axis"."""
        return AXIS_NAMES[self.index]

    @classmethod
    def axis(cls, node_id: int, slot: str) -> ChannelRef:
        return cls(node_id, "axis", AXIS_NAMES.index(slot), f"node{node_id}.{slot}")

    @classmethod
    def parse(cls, name: str) -> ChannelRef | None:
        """`node1.x` -> axis x of node 1; `node1.button5` -> button 5 of node 1;
        `switch.gear` -> the switch gear; else None."""
        if _SWITCH_RE.match(name.strip().lower()):
            return cls(-1, "switch", -1, name)
        m = _CHANNEL_RE.match(name.strip().lower())
        if m is None:
            return None
        node_id = int(m.group(1))
        if node_id > MAX_NODE_ID:
            return None
        if m.group(2):
            button = int(m.group(3))
            return cls(node_id, "button", button, name) if 1 <= button <= NODE_BUTTONS else None
        slot = m.group(4)
        return cls(node_id, "axis", AXIS_NAMES.index(slot), name) if slot in AXIS_NAMES else None
