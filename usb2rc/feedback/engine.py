"""The feedback engine: from the sources (downlinks, telemetry, the nodes' state) and the
`feedback:` rules, what each device should show now. Sans-IO: the caller passes the time
and the sources, and sleeps until `next_change_at`; nothing here reads a clock or a device.

Each device's state is layered (docs/CONFIG.md, "Feedback"): rest, then its node's downlink
while fresh (indicators across the node's devices in their order, axes 1..8 onto
`ANALOG_NAMES`), then each rule that holds, in file order: indicators OR'd, analog outputs
the largest (the forces: the last rule's), text lines the last rule's. A state holds only
what the device has (its `Capabilities`); a device without any gets none.

What the engine remembers between steps is each rule's history per device: whether its
condition has been known, whether it held, and a running pulse's end. So:
- a pulse starts on a rising edge: the condition true after it was false or unknown, once it
  had been known for this device. The first known value is a state, not an edge: a device
  that plugs while the condition holds does not pulse (nor joins a pulse other devices are
  in), and neither does a node already in failsafe when its device plugs;
- blinking is a phase of the caller's monotonic clock: every device blinks together.
Apart from that history, the states depend on (now, sources, slots) alone.

All times are the caller's monotonic clock, the one the sessions stamp telemetry with.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TypeVar

from usb2rc.config.model import Condition, DeviceRef, FeedbackRule, Rumble, SourceRef, TextLine
from usb2rc.feedback.model import INDICATOR_BITS, CrsfTelemetry, Downlink, MavlinkTelemetry
from usb2rc.feedback.rules import DOWNLINK, FLAG, TELEMETRY_SOURCES
from usb2rc.hid.outputs import ANALOG_NAMES, SIGNED_ANALOG, Capabilities, OutputState

DOWNLINK_STALE_S = 1.0  # no downlink frame for a node this long: its outputs back to rest
TELEMETRY_STALE_S = 3.0  # no telemetry this long: its values are unknown
INT16_FULL = 32767
UNKNOWN_TEXT = "--"  # a text field whose value is unknown
COLOR_NAMES = ("red", "green", "blue")
FORCE_NAMES = ("force_x", "force_y")

# The zero-config rule (no `feedback:` key): a node entering failsafe pulses its gamepads'
# rumble once.
DEFAULT_RULES = (
    FeedbackRule(
        when=Condition(SourceRef("node.failsafe", FLAG), text="node.failsafe"),
        device=DeviceRef(gamepads=True),
        rumble=Rumble(strong=1.0, weak=1.0, ms=300),
    ),
)


class DeviceSlot(NamedTuple):
    """A plugged device as the engine sees it. Slots come in their node's order: config
    entry order, then plug order (the downlink's indicators run across them so)."""

    key: str  # the device's unique key
    node_id: int
    entry: str | None  # its devices: entry's name; None: no entry (default layout)
    vid: int
    pid: int
    gamepad: bool  # application usage Generic Desktop / Game Pad
    capabilities: Capabilities

    def label(self) -> str:
        return self.entry or f"{self.vid:04x}:{self.pid:04x}"


class NodeFacts(NamedTuple):
    node_id: int
    failsafe: bool
    waiting: bool  # the neutral guard waits for a stick to come back to neutral


class Sources(NamedTuple):
    """Everything the rules read, as the line sessions and the node table publish it."""

    downlinks: tuple[Downlink, ...] = ()
    crsf: CrsfTelemetry | None = None
    mavlink: MavlinkTelemetry | None = None
    nodes: tuple[NodeFacts, ...] = ()


class RuleAction(NamedTuple):
    """What a rule did last: e.g. "rumble pulse 300 ms on pad", at `at`."""

    rule: int  # its index in the engine's rules
    text: str
    at: float


class FeedbackResult(NamedTuple):
    states: tuple[tuple[str, OutputState], ...]  # (slot key, state), one per capable slot
    next_change_at: float | None  # a blink, a pulse's end or a staleness changes a state
    actions: tuple[RuleAction, ...]  # the last one per rule, by rule index


@dataclass
class _Track:
    """One rule's history for one device."""

    known: bool = False  # its condition has had a known value
    held: bool = False  # it held at the last step
    pulse_until: float = -math.inf


# --------------------------------------------------------------------------- source values


class _View:
    """The sources as of `now`: stale ones gone, downlinks and nodes by Node-ID."""

    def __init__(self, now: float, sources: Sources) -> None:
        self.now = now
        self.crsf = _fresh(sources.crsf, now)
        self.mavlink = _fresh(sources.mavlink, now)
        self.downlinks: dict[int, Downlink] = {}
        for downlink in sources.downlinks:
            newest = self.downlinks.get(downlink.node_id)
            fresh = now < downlink.at + DOWNLINK_STALE_S  # as next_change_at counts it
            if fresh and (newest is None or newest.at < downlink.at):
                self.downlinks[downlink.node_id] = downlink
        self.nodes = {facts.node_id: facts for facts in sources.nodes}

    def value(self, source: SourceRef, node_id: int | None) -> object:
        """The source's value for a device of node `node_id`; None: unknown."""
        if source.name == DOWNLINK:
            return node_id in self.downlinks
        if source.name in TELEMETRY_SOURCES:
            family = self.crsf if source.name.startswith("crsf.") else self.mavlink
            return None if family is None else getattr(family, TELEMETRY_SOURCES[source.name][1])
        wanted = node_id if source.node_id is None else source.node_id
        facts = None if wanted is None else self.nodes.get(wanted)
        return None if facts is None else getattr(facts, source.name.rpartition(".")[2])


News = TypeVar("News", CrsfTelemetry, MavlinkTelemetry)


def _fresh(telemetry: News | None, now: float) -> News | None:
    if telemetry is None or now >= telemetry.at + TELEMETRY_STALE_S:
        return None
    return telemetry


def judge(condition: Condition | None, value: object) -> bool | None:
    """Whether the condition holds for this value; None: the value is unknown."""
    if condition is None:
        return True
    if value is None:
        return None
    if condition.op is None:
        return bool(value)
    wanted = condition.value
    if isinstance(value, str) and isinstance(wanted, str):
        value, wanted = value.casefold(), wanted.casefold()
    try:
        return bool(_COMPARE[condition.op](value, wanted))
    except TypeError:  # a value of another kind than the source's: no answer
        return None


_COMPARE: dict[str, Callable[[Any, Any], object]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "==": operator.eq,
    "!=": operator.ne,
}


def show_value(value: object, spec: str = "") -> str:
    """A value in a display text: true/false as yes/no, unknown as `--`."""
    if value is None:
        return UNKNOWN_TEXT
    if isinstance(value, bool):
        value = "yes" if value else "no"
    elif isinstance(value, float) and not spec:
        return format(round(value, 2), "g")
    try:
        return format(value, spec)
    except (ValueError, TypeError):  # e.g. `:d` for a float: the value as it is
        return str(value)


# --------------------------------------------------------------------------- layering


@dataclass
class _Layers:
    """One device's state being built, within what it has."""

    capabilities: Capabilities
    indicators: int = 0
    analog: dict[str, float] = field(default_factory=dict)
    texts: dict[int, str] = field(default_factory=dict)

    def light(self, bits: int) -> None:
        self.indicators |= bits & ((1 << self.capabilities.indicators) - 1)

    def drive(self, name: str, value: float) -> None:
        """An analog output at least at `value` (a force: at `value`)."""
        if name not in self.capabilities.analog:
            return
        if name in SIGNED_ANALOG:
            self.analog[name] = max(-1.0, min(1.0, value))
        else:
            self.analog[name] = max(self.analog.get(name, 0.0), max(0.0, min(1.0, value)))

    def show(self, line: int, text: str) -> None:
        if line <= self.capabilities.text_lines:
            width = self.capabilities.text_width
            self.texts[line] = text[:width] if width else text

    def state(self) -> OutputState:
        """Analog outputs at rest left out; text lines up to the last one shown."""
        analog = tuple((n, self.analog[n]) for n in ANALOG_NAMES if self.analog.get(n, 0.0))
        last = max((line for line, text in self.texts.items() if text), default=0)
        texts = tuple(self.texts.get(line, "") for line in range(1, last + 1))
        return OutputState(self.indicators, analog, texts)


def downlink_analog(axis: int, name: str) -> float:
    """A downlink axis (int16) as the analog output's value: 0..32767 onto 0..1, negatives
    to 0; the forces -1..1."""
    if name in SIGNED_ANALOG:
        return max(-1.0, axis / INT16_FULL)
    return min(1.0, max(0, axis) / INT16_FULL)


def apply_downlink(layers: _Layers, downlink: Downlink, first_indicator: int) -> None:
    """The node's downlink onto one of its devices, whose indicators start at bit
    `first_indicator` of the frame's 64."""
    if first_indicator < INDICATOR_BITS:
        layers.light(downlink.indicators >> first_indicator)
    for axis, name in zip(downlink.axes, ANALOG_NAMES, strict=False):
        layers.drive(name, downlink_analog(axis, name))


def indicator_offsets(slots: Sequence[DeviceSlot]) -> dict[str, int]:
    """Each device's first bit of its node's downlink: the node's devices in order, each
    taking as many bits as it has indicators."""
    taken: dict[int, int] = {}
    offsets: dict[str, int] = {}
    for slot in slots:
        offsets[slot.key] = taken.get(slot.node_id, 0)
        taken[slot.node_id] = offsets[slot.key] + slot.capabilities.indicators
    return offsets


def led_bits(leds: Iterable[int | str], capabilities: Capabilities) -> int:
    """A rule's leds on this device: an index, or a name (case aside) of its indicators."""
    names = [name.casefold() for name in capabilities.indicator_names]
    bits = 0
    for led in leds:
        if isinstance(led, str):
            if led.casefold() not in names:
                continue  # `check` warns when it knows the device
            led = names.index(led.casefold())
        bits |= 1 << led
    return bits


def blink_phase(now: float, hz: float) -> tuple[bool, float]:
    """Whether a blink at `hz` is lit at `now` (lit the first half of each period, from 0
    on the clock), and when it next changes (always after `now`)."""
    half_period = 0.5 / hz
    half = math.floor(now / half_period)
    # the division may round across a boundary: the half is the one the products bound, so
    # that every time before the returned change is in the same half
    if half * half_period > now:
        half -= 1
    elif (half + 1) * half_period <= now:
        half += 1
    return half % 2 == 0, (half + 1) * half_period


def selects(device: DeviceRef | None, slot: DeviceSlot) -> bool:
    if device is None:
        return True
    if device.entry is not None:
        return slot.entry == device.entry
    if device.vid is not None:
        return (slot.vid, slot.pid) == (device.vid, device.pid)
    return device.gamepads and slot.gamepad


def render(text: TextLine, view: _View, node_id: int) -> str:
    return "".join(
        piece.literal
        + (
            ""
            if piece.source is None
            else show_value(view.value(piece.source, node_id), piece.spec)
        )
        for piece in text.pieces
    )


def describe(rule: FeedbackRule, pulse: bool, steady: bool) -> str:
    """What a rule does, for the monitor: its pulse, its while-true actions, or both."""
    parts = []
    rumble = rule.rumble
    if pulse and rumble is not None and rumble.ms is not None:
        parts.append(f"rumble pulse {rumble.ms} ms")
    if steady:
        if rule.leds:
            leds = " ".join(str(led) for led in rule.leds)
            parts.append(f"led {leds}" + (f" blink {rule.blink_hz:g} Hz" if rule.blink_hz else ""))
        if rumble is not None and rumble.ms is None:
            parts.append(f"rumble {rumble.strong:g}/{rumble.weak:g}")
        if rule.force is not None:
            parts.append(f"force {rule.force[0]:g},{rule.force[1]:g}")
        if rule.brightness is not None:
            parts.append(f"brightness {rule.brightness:g}")
        if rule.color is not None:
            parts.append("color " + ",".join(str(c) for c in rule.color))
        if rule.text is not None:
            parts.append(f"text line {rule.text.line}")
    return ", ".join(parts)


# --------------------------------------------------------------------------- the engine


class FeedbackEngine:
    """The rules (None: the zero-config rule) judged step by step. One caller, one thread."""

    def __init__(self, rules: tuple[FeedbackRule, ...] | None) -> None:
        self.rules: tuple[FeedbackRule, ...] = DEFAULT_RULES if rules is None else rules
        self._tracks: dict[tuple[int, str], _Track] = {}
        self._actions: dict[int, RuleAction] = {}
        self._families = {
            source.name.partition(".")[0] for rule in self.rules for source in rule_sources(rule)
        }

    def step(self, now: float, sources: Sources, slots: Sequence[DeviceSlot]) -> FeedbackResult:
        view = _View(now, sources)
        capable = [slot for slot in slots if slot.capabilities.any]
        self._forget_unplugged({slot.key for slot in capable})
        offsets = indicator_offsets(slots)
        wakes: list[float] = self._staleness(view)
        began: dict[int, dict[str, list[str]]] = {}  # rule -> what it began -> on which
        ended: dict[int, list[str]] = {}
        states = []
        for slot in capable:
            layers = _Layers(slot.capabilities)
            downlink = view.downlinks.get(slot.node_id)
            if downlink is not None:
                apply_downlink(layers, downlink, offsets[slot.key])
                wakes.append(downlink.at + DOWNLINK_STALE_S)
            for index, rule in enumerate(self.rules):
                if selects(rule.device, slot):
                    self._apply(index, rule, slot, view, layers, wakes, began, ended)
            states.append((slot.key, layers.state()))
        self._note_actions(now, began, ended)
        later = [t for t in wakes if t > now]
        return FeedbackResult(
            tuple(states),
            min(later, default=None),
            tuple(self._actions[i] for i in sorted(self._actions)),
        )

    def telemetry_values(self, now: float, sources: Sources) -> dict[str, object]:
        """The sources' values as the rules see them (`telemetry_values`)."""
        return telemetry_values(now, sources)

    def _apply(
        self,
        index: int,
        rule: FeedbackRule,
        slot: DeviceSlot,
        view: _View,
        layers: _Layers,
        wakes: list[float],
        began: dict[int, dict[str, list[str]]],
        ended: dict[int, list[str]],
    ) -> None:
        """One rule on one device: its history stepped, its actions layered."""
        track = self._tracks.setdefault((index, slot.key), _Track())
        source = rule.when.source if rule.when is not None else None
        holds = judge(rule.when, None if source is None else view.value(source, slot.node_id))
        edge = holds is True and track.known and not track.held
        rumble = rule.rumble
        if edge and rumble is not None and rumble.ms is not None:
            track.pulse_until = view.now + rumble.ms / 1000
        what = describe(rule, pulse=edge, steady=holds is True and not track.held)
        if what:
            began.setdefault(index, {}).setdefault(what, []).append(slot.label())
        if track.held and holds is not True and describe(rule, pulse=False, steady=True):
            ended.setdefault(index, []).append(slot.label())
        track.known = track.known or holds is not None
        track.held = holds is True
        if view.now < track.pulse_until:
            wakes.append(track.pulse_until)
            assert rumble is not None
            layers.drive("rumble_strong", rumble.strong)
            layers.drive("rumble_weak", rumble.weak)
        if track.held:
            self._layer(rule, slot, view, layers, wakes)

    def _layer(
        self,
        rule: FeedbackRule,
        slot: DeviceSlot,
        view: _View,
        layers: _Layers,
        wakes: list[float],
    ) -> None:
        """The while-true actions of a rule that holds."""
        if rule.leds:
            lit = True
            if rule.blink_hz is not None:
                lit, change = blink_phase(view.now, rule.blink_hz)
                wakes.append(change)
            if lit:
                layers.light(led_bits(rule.leds, slot.capabilities))
        if rule.rumble is not None and rule.rumble.ms is None:
            layers.drive("rumble_strong", rule.rumble.strong)
            layers.drive("rumble_weak", rule.rumble.weak)
        if rule.force is not None:
            for name, value in zip(FORCE_NAMES, rule.force, strict=True):
                layers.drive(name, value)
        if rule.brightness is not None:
            layers.drive("brightness", rule.brightness)
        if rule.color is not None:
            for name, value in zip(COLOR_NAMES, rule.color, strict=True):
                layers.drive(name, value / 255)
        if rule.text is not None:
            layers.show(rule.text.line, render(rule.text, view, slot.node_id))

    def _staleness(self, view: _View) -> list[float]:
        """When the telemetry the rules read turns unknown, with no news before."""
        return [
            telemetry.at + TELEMETRY_STALE_S
            for family, telemetry in (("crsf", view.crsf), ("mavlink", view.mavlink))
            if telemetry is not None and family in self._families
        ]

    def _forget_unplugged(self, plugged: set[str]) -> None:
        """A device unplugged loses its history: plugged again, it starts afresh."""
        for key in [key for key in self._tracks if key[1] not in plugged]:
            del self._tracks[key]

    def _note_actions(
        self, now: float, began: dict[int, dict[str, list[str]]], ended: dict[int, list[str]]
    ) -> None:
        """A rule's last action: what it began this step (on which devices), else that it
        ended."""
        for index, labels in ended.items():
            self._actions[index] = RuleAction(index, "ended on " + ", ".join(labels), now)
        for index, whats in began.items():
            text = "; ".join(f"{what} on {', '.join(labels)}" for what, labels in whats.items())
            self._actions[index] = RuleAction(index, text, now)


def rule_sources(rule: FeedbackRule) -> tuple[SourceRef, ...]:
    """Every source a rule reads: its condition's and its text's fields."""
    found = [] if rule.when is None else [rule.when.source]
    if rule.text is not None:
        found += [piece.source for piece in rule.text.pieces if piece.source is not None]
    return tuple(found)


# --------------------------------------------------------------------------- for monitor


def telemetry_values(now: float, sources: Sources) -> dict[str, object]:
    """The sources' values as the rules see them (None: unknown or stale), flat, for the
    monitor and the page: `crsf.link_quality`, ..., `crsf.age` / `mavlink.age` (seconds
    since the newest news; None: never heard), `nodeN.failsafe`, `nodeN.waiting`,
    `nodeN.downlink` (fresh) and `nodeN.downlink_age`."""
    view = _View(now, sources)
    values: dict[str, object] = {
        name: view.value(SourceRef(name, kind), None)
        for name, (kind, _) in TELEMETRY_SOURCES.items()
    }
    values["crsf.age"] = None if sources.crsf is None else now - sources.crsf.at
    values["mavlink.age"] = None if sources.mavlink is None else now - sources.mavlink.at
    for facts in sources.nodes:
        values[f"node{facts.node_id}.failsafe"] = facts.failsafe
        values[f"node{facts.node_id}.waiting"] = facts.waiting
    for downlink in sources.downlinks:
        age = now - downlink.at
        previous = values.get(f"node{downlink.node_id}.downlink_age")
        if isinstance(previous, float) and previous < age:
            continue  # an older frame of the same node (two lines)
        values[f"node{downlink.node_id}.downlink"] = now < downlink.at + DOWNLINK_STALE_S
        values[f"node{downlink.node_id}.downlink_age"] = age
    return values
