"""The controls' config as plain frozen dataclasses (docs/CONFIG.md, "Switches", "Mixes and
curves", "Throttle cut", "MAVLink actions"); `usb2rc.config.controls` reads them from YAML."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.config.yamlnodes import Where

SWITCH_KINDS = ("toggle", "latch", "steps", "hat_switch")
SwitchKind = Literal["toggle", "latch", "steps", "hat_switch"]
MAX_POSITIONS = 8


@dataclass(frozen=True)
class SwitchConfig:
    """One named switch fed by node buttons of one node.

    toggle: one button, 2 positions, a press flips; latch: one button, position 1 while
    held; steps: one button cycles, two step down / up (no wrap); hat_switch: one button
    per position (a hat's directions routed to node buttons), the last pressed is held."""

    name: str
    kind: SwitchKind
    buttons: tuple[ChannelRef, ...]  # node buttons, all of one node
    positions: int = 2
    initial: int = 0
    failsafe: int | None = None  # position sent while the node is in failsafe; None: held
    reset: ChannelRef | None = None  # a node button that puts the switch back to `initial`
    slot: str | None = None  # an axis slot of its node the switch's value is written to
    where: Where | None = field(default=None, compare=False)

    @property
    def node_id(self) -> int:
        return self.buttons[0].node_id


@dataclass(frozen=True)
class Curve:
    """`expo` (a value -1..1) or 3..17 points over -1..1, evenly spaced."""

    expo: float | None = None
    points: tuple[float, ...] = ()


@dataclass(frozen=True)
class Rates:
    """Weights chosen by a switch's position (dual / triple rates)."""

    switch: str
    weights: tuple[float, ...]


@dataclass(frozen=True)
class MixInput:
    """One line of a mix: `weight × curve(source) + offset` (docs/CONFIG.md)."""

    source: ChannelRef
    weight: float = 1.0
    offset: float = 0.0
    curve: Curve | None = None
    rates: Rates | None = None


@dataclass(frozen=True)
class MixRef:
    """A channel made of a mix of sources, summed and clamped; `name` for `icd`."""

    inputs: tuple[MixInput, ...]
    name: str = "mix"
    kind: Literal["mix"] = "mix"
    node_id: int = -1


@dataclass(frozen=True)
class ThrottleCut:
    """While `switch` is off its position 0, `channel` (an axis slot) is held at its low
    end; after that, until the slot's own value is low again."""

    switch: str
    channel: ChannelRef
    where: Where | None = field(default=None, compare=False)


ActionKind = Literal["arm", "disarm", "mode", "rtl", "land", "command_long"]


@dataclass(frozen=True)
class ActionConfig:
    """A MAVLink button action: when `button` goes down (or `switch` reaches `position`)
    and stays so for `hold` seconds, send `kind` once."""

    kind: ActionKind
    button: ChannelRef | None = None
    switch: str | None = None
    position: int = 1
    hold: float = 0.0
    mode: str | None = None
    command: int = 0
    params: tuple[float, ...] = ()
    where: Where | None = field(default=None, compare=False)

    def describe(self) -> str:
        trigger = self.button.name if self.button else f"switch.{self.switch}={self.position}"
        what = {"mode": f"mode {self.mode}", "command_long": f"command {self.command}"}
        text = f"{trigger}: {what.get(self.kind, self.kind)}"
        return text + (f" (hold {self.hold:g} s)" if self.hold else "")
