"""What a loaded config is: plain frozen dataclasses (channel references: channel_ref.py;
the controls': controls/model.py).

The `feedback:` rules' records are here too (read by usb2rc/feedback/rules.py, judged by
usb2rc/feedback/engine.py): the config package imports nothing above it, and the feedback
package, which reads devices and telemetry, sits above the config.

`usb2rc.configfile` reads YAML into these (with config/devices.py and config/checks.py,
which read the device entries and cross-check them); nodes/mapping.py compiles them.
`usb2rc.configfile` re-exports the public names for the commands; the stages below it
import them from here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

from usb2rc.config.channel_ref import CHANNEL_ALLOWED as CHANNEL_ALLOWED  # re-exported
from usb2rc.config.channel_ref import ChannelRef as ChannelRef
from usb2rc.config.controls_model import MixRef, SwitchConfig, ThrottleCut
from usb2rc.config.output_options import option_default
from usb2rc.config.yamlnodes import Where
from usb2rc.hid.usages import GDC_BATTERY_STRENGTH

MAX_HID_BUTTON = 65535
HAT_DIRECTIONS = ("up", "up-right", "right", "down-right", "down", "down-left", "left", "up-left")
DEFAULT_BAUDRATE = 115200
SUMD_MIN_CHANNELS, SUMD_MAX_CHANNELS = 2, 32
SUMD_DEFAULT_SLOTS = ("x", "y", "z", "rz", "slider", "rx", "ry", "dial")

ARM_CHOICES = ("centre", "center", "low", "high", "any")  # an axis's `arm:` (docs/CONFIG.md)


@dataclass(frozen=True)
class Calibration:
    min: int
    center: int
    max: int


@dataclass(frozen=True)
class TrimSwitchConfig:
    """A hat axis or a button pair that steps an axis's trim (docs/CONFIG.md, "Trims").
    Exactly one of hat / buttons is set."""

    where: Where
    hat: int | None = None  # a hat's usage, with hat_axis: -1 steps down, +1 up
    hat_axis: str | None = None  # "x" (left -1 / right +1) or "y" (down -1 / up +1)
    occurrence: int = 0
    buttons: tuple[int, int] | None = None  # HID buttons: first steps down, second up
    step: float = 0.01  # per press, a fraction of the half range
    limit: float = 0.25  # the trim stays within ±limit


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
    arm: str | None = None  # neutral guard: centre, low, high, any; None: by usage (guard.py)
    arm_tolerance: float | None = None  # None: guard.DEFAULT_TOLERANCE
    trim_switch: TrimSwitchConfig | None = None


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
class HandoverConfig:
    """A HID button that makes the node send `&` (handover) frames to `destination`
    (docs/ICD.md, "Handover"): while it is held (`frames` None), or `frames` frames a press."""

    button: int  # HID button of the device, 1-based
    destination: int  # 0..255: byte 4 of the `&` frames
    frames: int | None = None
    where: Where | None = field(default=None, compare=False)


LOW_BATTERY_PERCENT = 20  # the default threshold: below 20 % of the field's range


@dataclass(frozen=True)
class LowBatteryConfig:
    """A value that makes the node send `%` (low battery) frames while it is below `below`
    percent of its logical range (docs/ICD.md, "Low battery"). `auto`: the default, used
    only when the device has the usage (Battery Strength); a configured one must exist."""

    usage: int = GDC_BATTERY_STRENGTH
    occurrence: int = 0
    below: float = LOW_BATTERY_PERCENT
    auto: bool = True
    where: Where | None = field(default=None, compare=False)


AUTO_LOW_BATTERY = LowBatteryConfig()


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
    handover: HandoverConfig | None = None
    low_battery: LowBatteryConfig | None = AUTO_LOW_BATTERY  # None: `low_battery: false`
    # how it reports (docs/ICD.md, "A device that falls silent"): `auto` learns it
    reports: str = "auto"


@dataclass(frozen=True)
class OutputConfig:
    """One serial output. `channels` (SUMD) are typed references; a Config built in code
    may give them as names (`("node0.x", "node0.y")`), parsed here once (ValueError when
    one is not a channel name)."""

    protocol: str = "c2-16b"
    port: str | None = None
    baudrate: int = DEFAULT_BAUDRATE
    rate_hz: float = 50
    line_feed: bool = True
    service_status: str = "ascii"
    channels: tuple[ChannelRef | MixRef, ...] | None = None  # None: the default channel list
    extended: bool = False  # SUMD: axes onto 900-2100 µs instead of 1100-1900 µs
    where: Where | None = None
    channel_wheres: tuple[Where, ...] = field(default=(), compare=False)  # one per channel
    # Protocol-only keys that are not fields above (the registry's `options`), as set.
    options: tuple[tuple[str, Any], ...] = ()

    def option(self, name: str) -> Any:
        """A protocol-only key's value: as configured, else its default (output_options)."""
        for key, value in self.options:
            if key == name:
                return value
        return option_default(self.protocol, name)

    def __post_init__(self) -> None:
        given: tuple[ChannelRef | MixRef | str, ...] | None = self.channels
        if given is not None:
            object.__setattr__(self, "channels", tuple(_channel_ref(c) for c in given))


def _channel_ref(channel: ChannelRef | MixRef | str) -> ChannelRef | MixRef:
    if not isinstance(channel, str):
        return channel
    ref = ChannelRef.parse(channel)
    if ref is None:
        raise ValueError(f"bad SUMD channel name {channel!r}")
    return ref


# --------------------------------------------------------------------------- feedback


class SourceRef(NamedTuple):
    """A value a feedback rule reads (docs/CONFIG.md, "Feedback")."""

    name: str  # as written: "crsf.link_quality", "node3.failsafe", "node.failsafe", "downlink"
    kind: str  # "number", "text" or "flag": what it compares with
    node_id: int | None = None  # nodeN.*: N; None: no node's, or the device's own (node.*)


@dataclass(frozen=True)
class Condition:
    """`source`, or `source op value`: true when the source's value compares so; a bare
    source is true when truthy. A condition on an unknown value is false."""

    source: SourceRef
    op: str | None = None  # < <= > >= == !=
    value: float | str | bool | None = None
    text: str = ""  # as written, for messages and the monitor


@dataclass(frozen=True)
class DeviceRef:
    """Which devices a rule drives: a devices: entry's, a vid:pid's, or the gamepads (the
    zero-config rule's)."""

    entry: str | None = None
    vid: int | None = None
    pid: int | None = None
    gamepads: bool = False

    def label(self) -> str:
        if self.entry is not None:
            return self.entry
        if self.vid is not None and self.pid is not None:
            return f"{self.vid:04x}:{self.pid:04x}"
        return "gamepads" if self.gamepads else "every device"


@dataclass(frozen=True)
class Rumble:
    """Rumble motors' strength, 0..1; `ms`: a pulse on the condition's rising edge, else
    while the condition holds."""

    strong: float = 0.0
    weak: float = 0.0
    ms: int | None = None


class TextPiece(NamedTuple):
    """A display text's literal part, then a source's value (None: none) with its format."""

    literal: str
    source: SourceRef | None = None
    spec: str = ""


@dataclass(frozen=True)
class TextLine:
    line: int  # 1-based
    pieces: tuple[TextPiece, ...]
    template: str  # as written


@dataclass(frozen=True)
class FeedbackRule:
    """One `feedback:` rule: when (None: always), which devices (None: every device that has
    the output), and what they show."""

    when: Condition | None = None
    device: DeviceRef | None = None
    leds: tuple[int | str, ...] = ()  # indicator indexes or names
    blink_hz: float | None = None  # the leds blink; None: steady
    rumble: Rumble | None = None
    force: tuple[float, float] | None = None  # x, y: -1..1
    brightness: float | None = None
    color: tuple[int, int, int] | None = None  # r, g, b: 0..255
    text: TextLine | None = None
    where: Where | None = field(default=None, compare=False)
    key_lines: tuple[tuple[str, int], ...] = field(default=(), compare=False)  # key -> line

    def where_of(self, key: str) -> Where | None:
        """Where one of the rule's keys (`led`, `text.line`) is, for a problem found later."""
        if self.where is None:
            return None
        line = dict(self.key_lines).get(key.partition(".")[0], self.where.line)
        return Where(self.where.source, line, f"{self.where.key}.{key}")


@dataclass(frozen=True)
class Config:
    outputs: tuple[OutputConfig, ...]
    devices: tuple[DeviceConfig, ...] = ()
    defaults: bool = True
    source: str = "<default>"
    switches: tuple[SwitchConfig, ...] = ()  # docs/CONFIG.md, "Switches"
    throttle_cuts: tuple[ThrottleCut, ...] = ()
    # docs/CONFIG.md, "Feedback"; None: no `feedback:` key, the zero-config rule applies
    feedback: tuple[FeedbackRule, ...] | None = None

    @classmethod
    def default(cls) -> Config:
        """Zero config: one C2-16B output (port from the command line), default layout."""
        return cls(outputs=(OutputConfig(),))
