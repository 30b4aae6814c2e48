"""A device's compiled map onto its node: `DeviceBinding` and the plans it runs.

`DeviceBinding.apply(state)` is the per-report hot path: a few precomputed closures over
usb2rc.nodes.scaling (docs/ICD.md, "Axis scaling"), shift-and-mask button runs and hat lookup
tables, nothing read from the config per tick. `default_binding` is the default layout
(docs/ICD.md, "Default axis layout"); `configured_binding` a config entry's (usb2rc.nodes.mapping
compiles the entries and picks one). Whether an axis slot is unsigned is answered once, by
`unsigned_slots`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple, Protocol

from usb2rc.config.layout import AXIS_NAMES, GROUP1_BUTTONS, HAT1_SHIFT, NODE_BUTTONS
from usb2rc.config.model import (
    AUTO_LOW_BATTERY,
    HAT_DIRECTIONS,
    AxisConfig,
    DeviceConfig,
    HandoverConfig,
    HatConfig,
    LowBatteryConfig,
    TrimSwitchConfig,
)
from usb2rc.config.yamlnodes import Where
from usb2rc.hid.descriptor import DeviceLayout, InputField, InputState
from usb2rc.hid.usages import (
    GD_DIAL,
    GD_HAT_SWITCH,
    GD_RX,
    GD_RY,
    GD_RZ,
    GD_SLIDER,
    GD_WHEEL,
    GD_X,
    GD_Y,
    GD_Z,
    SIMULATION_PAGE,
    usage_name,
)
from usb2rc.nodes.guard import NO_GUARD, GuardedAxis, NeutralGuard
from usb2rc.nodes.known_devices import KnownDevice, guard_axis
from usb2rc.nodes.scaling import (
    INT16_MAX,
    INT16_MIN,
    UINT16_MAX,
    hat_component,
    hat_direction,
    linear_field,
    node_button_bit,
    normalize,
    shape,
    to_wire,
)
from usb2rc.nodes.trims import TrimSwitch

NUM_AXES = len(AXIS_NAMES)

# Usages the default layout knows.
DEFAULT_SLOT_OF = {
    GD_X: "x", GD_Y: "y", GD_Z: "z", GD_SLIDER: "slider",
    GD_RX: "rx", GD_RY: "ry", GD_RZ: "rz", GD_DIAL: "dial",
}  # fmt: skip
AUX_SLOTS = ("aux1", "aux2")


class MappingError(ValueError):
    """A config entry that does not fit the device it matched; the message names the line."""


# --------------------------------------------------------------------------- value types


class NodeInputs(NamedTuple):
    """What one device contributes to its node: axes already on the wire, button groups."""

    axes: tuple[int | None, ...]  # 10 slots, None: this device does not feed the slot
    group1: int
    group2: int
    handover: bool = False  # the handover button is down (docs/ICD.md, "Handover")
    low_battery: bool = False  # the battery value is below its threshold ("Low battery")


@dataclass(frozen=True)
class AxisInfo:
    """What feeds one axis slot, for `icd`, `monitor` and `describe`."""

    slot: str
    source: str  # "X", "Slider #2", "HatSwitch x", "buttons 3/4"
    raw_min: int
    raw_max: int
    unsigned: bool
    failsafe: int | None  # None: hold the last value
    shaping: str  # "linear" or e.g. "calibration 12/128/250, deadband 0.02, invert"
    field_index: int | None = None  # the raw value's InputState.values index (None: buttons)

    @property
    def wire_range(self) -> tuple[int, int]:
        return (0, UINT16_MAX) if self.unsigned else (INT16_MIN, INT16_MAX)

    def describe(self) -> str:
        lo, hi = self.wire_range
        kind = "unsigned" if self.unsigned else "signed"
        failsafe = "hold last" if self.failsafe is None else str(self.failsafe)
        return (
            f"{self.slot:<6} <- {self.source} (raw {self.raw_min}..{self.raw_max}, {kind} "
            f"{lo}..{hi}, {self.shaping}, failsafe {failsafe})"
        )


class SlotAxis(Protocol):
    """An axis slot and whether it carries a uint16: config.AxisConfig or AxisInfo."""

    @property
    def slot(self) -> str: ...

    @property
    def unsigned(self) -> bool: ...


def unsigned_slots(axes: Iterable[SlotAxis | None]) -> int:
    """Is this slot unsigned, the one answer: bit k set when axis slot k carries a uint16
    (`unsigned: true`; the default layout is signed). `DeviceBinding.unsigned_slots` and
    `mapping.CompiledEntry.unsigned_slots` hold it, computed once; NodeTable frames carry it
    to the outputs, and `Mapping.sumd_channels` reads it for `icd` and `check`."""
    mask = 0
    for axis in axes:
        if axis is not None and axis.unsigned:
            mask |= 1 << AXIS_NAMES.index(axis.slot)
    return mask


# --------------------------------------------------------------------------- compiled plans

AxisFn = Callable[[Sequence[int], int], int]  # (values, buttons) -> wire value


@dataclass(frozen=True)
class ButtonRun:
    """`((buttons >> shift) & mask) << dest` into group `group`: one contiguous run."""

    shift: int
    mask: int
    group: int
    dest: int


@dataclass(frozen=True)
class BatteryPlan:
    """Low battery: the field's raw value below `below` percent of its logical range."""

    index: int  # InputState.values index
    lo: int
    hi: int
    below: float  # percent
    label: str  # "BatteryStrength", for describe()

    def is_low(self, values: Sequence[int]) -> bool:
        # (v - lo) / (hi - lo) < below / 100, without a division (a range of one value
        # is never low: it says nothing)
        return (values[self.index] - self.lo) * 100 < self.below * (self.hi - self.lo)


@dataclass(frozen=True)
class HatPlan:
    index: int  # InputState.values index
    lo: int
    table: tuple[tuple[int, int], ...]  # raw - lo → (group1 bits, group2 bits)


def compile_button_runs(routes: Sequence[tuple[int, int]]) -> tuple[ButtonRun, ...]:
    """(HID button, node button) pairs → the fewest shift-and-mask runs."""
    runs: list[list[int]] = []  # [hid_first, count, group, bit_first]
    for hid, node in sorted(routes):
        group, bit = node_button_bit(node)
        last = runs[-1] if runs else None
        if last and hid == last[0] + last[1] and group == last[2] and bit == last[3] + last[1]:
            last[1] += 1
        else:
            runs.append([hid, 1, group, bit])
    return tuple(ButtonRun(h - 1, (1 << n) - 1, g, b) for h, n, g, b in runs)


DEFAULT_BUTTON_RUNS = compile_button_runs([(b, b) for b in range(1, NODE_BUTTONS + 1)])


def hat_table(field: InputField, to: str | tuple[int | None, ...]) -> HatPlan:
    rows = []
    for v in range(field.logical_min, field.logical_max + 1):
        direction = hat_direction(v, field.logical_min, field.logical_max)
        rows.append(_hat_bits(direction, to))
    return HatPlan(field.index, field.logical_min, tuple(rows))


def _hat_bits(direction: int | None, to: str | tuple[int | None, ...]) -> tuple[int, int]:
    if direction is None:
        return (0, 0)
    if isinstance(to, str):  # "hat1", the only name the config file lets through
        return (1 << (HAT1_SHIFT + direction), 0)
    button = to[direction]
    if button is None:
        return (0, 0)
    group, bit = node_button_bit(button)
    return (1 << bit, 0) if group == 0 else (0, 1 << bit)


def _linear_axis(field: InputField, axis: AxisConfig | None) -> AxisFn:
    unsigned = axis.unsigned if axis else False
    invert = axis.invert if axis else False
    return linear_field(field.index, field.logical_min, field.logical_max, unsigned, invert)


def _shaped_axis(field: InputField, axis: AxisConfig) -> AxisFn:
    i = field.index
    cal = axis.calibration
    lo, hi = (cal.min, cal.max) if cal else (field.logical_min, field.logical_max)
    center = cal.center if cal else (lo + hi) / 2
    if hi <= lo:
        return lambda _v, _b: to_wire(shape(0.0, axis), axis.unsigned)
    return lambda values, _b: to_wire(
        shape(normalize(values[i], lo, center, hi), axis), axis.unsigned
    )


def _is_shaped(axis: AxisConfig) -> bool:
    return bool(axis.calibration or axis.deadband or axis.expo or axis.trim)


def _three_state(axis: AxisConfig) -> tuple[int, int, int]:
    """Wire values for -1, 0, +1 of a hat / button-pair source after invert and trim."""
    return tuple(to_wire(shape(float(x), axis), axis.unsigned) for x in (-1, 0, 1))  # type: ignore[return-value]


def _hat_axis(field: InputField, axis: AxisConfig) -> AxisFn:
    wire = _three_state(axis)
    lo, hi, hat_axis = field.logical_min, field.logical_max, axis.hat_axis or "x"
    table = [wire[hat_component(hat_direction(v, lo, hi), hat_axis) + 1] for v in range(lo, hi + 1)]
    i, centre = field.index, wire[1]

    def value(values: Sequence[int], _b: int) -> int:
        k = values[i] - lo
        return table[k] if 0 <= k < len(table) else centre

    return value


def _button_pair_axis(axis: AxisConfig) -> AxisFn:
    assert axis.buttons is not None
    minus, plus = (1 << (b - 1) for b in axis.buttons)
    wire = _three_state(axis)

    def value(_v: Sequence[int], buttons: int) -> int:
        return wire[bool(buttons & plus) - bool(buttons & minus) + 1]

    return value


# --------------------------------------------------------------------------- binding


class DeviceBinding:
    """One device's compiled map onto its node. `apply` is the per-report hot path."""

    def __init__(
        self,
        name: str,
        node_id: int | None,
        axes: Sequence[tuple[int, AxisFn, AxisInfo, int | None]],
        button_runs: Sequence[ButtonRun],
        hats: Sequence[HatPlan],
        hat_notes: Sequence[str] = (),
        where: Where | None = None,
        handover: HandoverConfig | None = None,
        battery: BatteryPlan | None = None,
        guard: NeutralGuard = NO_GUARD,
        trim_switches: Sequence[TrimSwitch] = (),
        reports: str = "auto",
    ) -> None:
        self.name = name
        self.reports = reports  # how the device reports: auto, streaming, on_change
        self.handover = handover  # what the node's `&` frames say (state.NodeFrame)
        self._handover_mask = 1 << (handover.button - 1) if handover else 0
        self.battery = battery
        self.guard = guard  # axes that must rest before the device goes live (guard.py)
        self.trim_switches = tuple(trim_switches)
        self.node_id = node_id
        self.where = where
        self._axes = tuple((slot, fn) for slot, fn, _, _ in axes)
        self._failsafe = {slot: fs for slot, _, _, fs in axes}
        self.axis_info: tuple[AxisInfo | None, ...] = tuple(
            next((info for slot, _, info, _ in axes if slot == k), None) for k in range(NUM_AXES)
        )
        self._runs = tuple((r.shift, r.mask, r.group, r.dest) for r in button_runs)
        self._hats = tuple(hats)
        self.hat_notes = tuple(hat_notes)
        self.button_runs = tuple(button_runs)
        self.axis_slots = frozenset(AXIS_NAMES[slot] for slot, _ in self._axes)
        self.unsigned_slots = unsigned_slots(self.axis_info)  # bit k: slot k is a uint16
        # an axis made of buttons (`buttons: [A, B]`): a tap moves it, not only button bits
        self._axes_read_buttons = any(
            info is not None and info.field_index is None for info in self.axis_info
        )
        self.group1_mask, self.group2_mask = self._masks()
        # the guard's slots only: what a device waiting in the guard needs of a step
        guarded = {axis.slot for axis in guard.axes}
        self._guarded_axes = tuple((slot, fn) for slot, fn in self._axes if slot in guarded)
        self._failsafe_of: tuple[NodeInputs | None, NodeInputs] | None = None

    def same_axes(self, other: DeviceBinding) -> bool:
        """Whether both send the same axis values for the same reports: the same sources,
        ranges and shaping per slot (`AxisInfo`; the failsafe value aside, it is not sent
        while the device is live). A reload that changes this re-arms the neutral guard."""
        return _sent_axes(self) == _sent_axes(other)

    def same_buttons(self, other: DeviceBinding) -> bool:
        """Whether both map the device's buttons and hats onto the same node buttons, with
        the same handover button and trim switches. A reload that changes this makes every
        button held then a held-over one (usb2rc.nodes.presses)."""
        mine = (self.button_runs, self._hats, self.handover, self.trim_switches)
        return mine == (other.button_runs, other._hats, other.handover, other.trim_switches)

    def button_groups(self, buttons: int) -> tuple[int, int]:
        """The node buttons these HID buttons feed (its button runs; hats aside)."""
        groups = [0, 0]
        for shift, mask, group, dest in self._runs:
            groups[group] |= ((buttons >> shift) & mask) << dest
        return groups[0], groups[1]

    def tap_groups(self, taps: int) -> tuple[int, int] | None:
        """The node buttons HID buttons `taps` add to what `apply` gives, when that is all
        they change (no axis of this binding is made of buttons, and the handover button is
        not among them): `apply` of the state with them pressed is then its inputs with
        these bits ORed in (a button run ORs its bits; axes, hats and the battery come from
        the values). None: `apply` must be asked."""
        if self._axes_read_buttons or taps & self._handover_mask:
            return None
        return self.button_groups(taps)

    def holds_handover(self, buttons: int) -> bool:
        """Whether the handover button is among these HID buttons."""
        return bool(buttons & self._handover_mask)

    def _masks(self) -> tuple[int, int]:
        masks = [0, 0]
        for _shift, mask, group, dest in self._runs:
            masks[group] |= mask << dest
        for plan in self._hats:
            for g1, g2 in plan.table:
                masks[0] |= g1
                masks[1] |= g2
        return masks[0], masks[1]

    def apply(self, state: InputState) -> NodeInputs:
        values, buttons = state.values, state.buttons
        axes: list[int | None] = [None] * NUM_AXES
        for slot, fn in self._axes:
            axes[slot] = fn(values, buttons)
        groups = [0, 0]
        for shift, mask, group, dest in self._runs:
            groups[group] |= ((buttons >> shift) & mask) << dest
        for plan in self._hats:
            k = values[plan.index] - plan.lo
            if 0 <= k < len(plan.table):
                g1, g2 = plan.table[k]
                groups[0] |= g1
                groups[1] |= g2
        low = self.battery is not None and self.battery.is_low(values)
        return NodeInputs(
            tuple(axes), groups[0], groups[1], bool(buttons & self._handover_mask), low
        )

    @property
    def guarded_functions(self) -> tuple[tuple[int, AxisFn], ...]:
        """The guard's slots as (slot, its function of (values, buttons)), in `apply`'s
        order (a slot given twice: the last one counts)."""
        return self._guarded_axes

    def guarded_axes(self, state: InputState) -> list[int | None]:
        """`apply`'s axis values of the guarded slots only (every other slot None): what the
        neutral guard looks at while the device waits, without the rest of `apply`."""
        values, buttons = state.values, state.buttons
        axes: list[int | None] = [None] * NUM_AXES
        for slot, fn in self._guarded_axes:
            axes[slot] = fn(values, buttons)
        return axes

    def failsafe(self, last: NodeInputs | None = None) -> NodeInputs:
        """Axes: the configured failsafe value, else the last value (0 if none); no buttons.
        The same `last` as the call before gives the same value (a waiting device asks at
        every step): worked out again only when `last` is another."""
        memo = self._failsafe_of
        if memo is not None and memo[0] is last:
            return memo[1]
        inputs = self._failsafe_inputs(last)
        self._failsafe_of = (last, inputs)
        return inputs

    def _failsafe_inputs(self, last: NodeInputs | None) -> NodeInputs:
        axes: list[int | None] = [None] * NUM_AXES
        for slot, _ in self._axes:
            configured = self._failsafe[slot]
            held = last.axes[slot] if last is not None else None
            axes[slot] = configured if configured is not None else held
            if axes[slot] is None:
                axes[slot] = 0  # docs/ICD.md, "Failsafe": 0 without a failsafe value
        return NodeInputs(tuple(axes), 0, 0)

    def describe(self) -> list[str]:
        node = "automatic" if self.node_id is None else str(self.node_id)
        lines = [f"{self.name}: node {node}"]
        lines += [f"  axis {info.describe()}" for info in self.axis_info if info is not None]
        lines += [f"  {line}" for line in describe_button_runs(self.button_runs)]
        lines += [f"  {note}" for note in self.hat_notes]
        if self.handover is not None:
            h = self.handover
            how = "while held" if h.frames is None else f"{h.frames} frames a press"
            lines.append(f"  handover: HID button {h.button} -> `&` to {h.destination} ({how})")
        if self.battery is not None:
            b = self.battery
            lines.append(f"  low battery: {b.label} below {b.below:g} % -> `%`")
        lines.append(f"  neutral guard: {self.guard.describe()}")
        lines += [f"  trim switch -> {AXIS_NAMES[t.slot]}" for t in self.trim_switches]
        return lines


def describe_button_runs(runs: Sequence[ButtonRun]) -> list[str]:
    lines = []
    for run in runs:
        count = run.mask.bit_count()
        hid = _span(run.shift + 1, count)
        first = run.dest + 1 + (GROUP1_BUTTONS if run.group else 0)
        bits = _span(run.dest, count)
        lines.append(
            f"buttons HID {hid} -> node {_span(first, count)} (group {run.group + 1} bit {bits})"
        )
    return lines


def _span(first: int, count: int) -> str:
    return str(first) if count == 1 else f"{first}-{first + count - 1}"


def usage_label(usage: int, occurrence: int = 0) -> str:
    name = usage_name(usage)
    return name if occurrence == 0 else f"{name} #{occurrence + 1}"


def shaping_text(axis: AxisConfig | None) -> str:
    if axis is None:
        return "linear"
    parts = []
    if axis.calibration:
        c = axis.calibration
        parts.append(f"calibration {c.min}/{c.center}/{c.max}")
    parts += [f"{k} {getattr(axis, k)}" for k in ("deadband", "expo", "trim") if getattr(axis, k)]
    if axis.invert:
        parts.append("invert")
    return ", ".join(parts) or "linear"


def _field_axis(field: InputField, axis: AxisConfig | None, slot: str) -> tuple[AxisFn, AxisInfo]:
    fn = _shaped_axis(field, axis) if axis and _is_shaped(axis) else _linear_axis(field, axis)
    info = AxisInfo(
        slot,
        usage_label(field.usage, field.occurrence),
        field.logical_min,
        field.logical_max,
        bool(axis and axis.unsigned),
        axis.failsafe if axis else None,
        shaping_text(axis),
        field.index,
    )
    return fn, info


# --------------------------------------------------------------------------- default layout


def default_axis_fields(layout: DeviceLayout) -> list[tuple[str, InputField]]:
    """The default axis layout (docs/ICD.md, "Default axis layout"), plus Simulation-page
    values into a free aux slot.

    X, Y, Z, Slider, Rx, Ry, Rz, Dial → the slot of the same name (the first of each); then
    Wheel and a second Slider / Dial → aux1, aux2 in descriptor order; then (usb2rc's own
    decision) Simulation Controls values (Throttle, Rudder, ...) into what is left of aux1/aux2.
    """
    taken: dict[str, InputField] = {}
    extra: list[InputField] = []
    simulation: list[InputField] = []
    for f in layout.inputs:
        slot = DEFAULT_SLOT_OF.get(f.usage)
        if slot and slot not in taken:
            taken[slot] = f
        elif f.usage == GD_WHEEL or (slot in ("slider", "dial")):
            extra.append(f)
        elif f.usage >> 16 == SIMULATION_PAGE and f.logical_max - f.logical_min >= 2:
            simulation.append(f)
    free = [s for s in AUX_SLOTS]
    for f in extra + simulation:
        if free:
            taken[free.pop(0)] = f
    return [(slot, taken[slot]) for slot in AXIS_NAMES if slot in taken]


def first_hat(layout: DeviceLayout) -> InputField | None:
    return next((f for f in layout.inputs if f.usage == GD_HAT_SWITCH), None)


def battery_plan(layout: DeviceLayout, config: LowBatteryConfig | None) -> BatteryPlan | None:
    """The low-battery plan of a device: the configured field (MappingError if the device
    lacks it), the automatic one where the device reports Battery Strength, or none."""
    if config is None:
        return None
    for f in layout.inputs:
        if f.usage == config.usage and f.occurrence == config.occurrence:
            label = usage_label(f.usage, f.occurrence)
            return BatteryPlan(f.index, f.logical_min, f.logical_max, config.below, label)
    if config.auto or config.where is None:
        return None
    _find_field(layout, config.usage, config.occurrence, config.where, "low_battery usage")
    return None  # not reached: _find_field raised


def handover_of(layout: DeviceLayout, device: DeviceConfig) -> HandoverConfig | None:
    """The entry's handover, checked against the device: its button must exist."""
    handover = device.handover
    if handover is not None and handover.button > layout.button_count:
        raise MappingError(
            f"{handover.where or device.where}: handover button {handover.button} is not in "
            f"this device (its buttons: 1..{layout.button_count})"
        )
    return handover


def default_binding(
    layout: DeviceLayout,
    name: str,
    node_id: int | None = None,
    device: DeviceConfig | None = None,
    known: KnownDevice | None = None,
) -> DeviceBinding:
    """The default layout; `known`: the device's entry in the device database (its guard)."""
    axes, guarded = [], []
    for slot, f in default_axis_fields(layout):
        fn, info = _field_axis(f, None, slot)
        axes.append((AXIS_NAMES.index(slot), fn, info, None))
        axis_guard = guard_axis(
            AXIS_NAMES.index(slot), info.source, f.usage, layout.application, known
        )
        if axis_guard is not None:
            guarded.append(axis_guard)
    hats, notes = [], []
    hat = first_hat(layout)
    if hat is not None:
        hats.append(hat_table(hat, "hat1"))
        notes.append(f"hat {usage_label(hat.usage, hat.occurrence)} -> hat1 (group 1 bits 24-31)")
    handover = handover_of(layout, device) if device else None
    battery = battery_plan(layout, device.low_battery if device else AUTO_LOW_BATTERY)
    where = device.where if device else None
    guard = NeutralGuard(tuple(guarded))
    reports = device.reports if device else "auto"
    return DeviceBinding(
        name,
        node_id,
        axes,
        DEFAULT_BUTTON_RUNS,
        hats,
        notes,
        where,
        handover,
        battery,
        guard,
        reports=reports,
    )


def _sent_axes(binding: DeviceBinding) -> tuple[AxisInfo | None, ...]:
    return tuple(
        None if info is None else replace(info, failsafe=None) for info in binding.axis_info
    )


# --------------------------------------------------------------------------- configured


def _find_field(
    layout: DeviceLayout, usage: int, occurrence: int, where: Where, what: str
) -> InputField:
    for f in layout.inputs:
        if f.usage == usage and f.occurrence == occurrence:
            return f
    have = ", ".join(usage_label(f.usage, f.occurrence) for f in layout.inputs) or "none"
    raise MappingError(
        f"{where}: {what} {usage_label(usage, occurrence)} is not in this device "
        f"(its inputs: {have})"
    )


def _configured_axis(layout: DeviceLayout, axis: AxisConfig) -> tuple[AxisFn, AxisInfo]:
    slot = axis.slot
    if axis.usage is not None:
        f = _find_field(layout, axis.usage, axis.occurrence, axis.where, "usage")
        return _field_axis(f, axis, slot)
    lo, hi = (0, 1) if axis.buttons else (-1, 1)
    index = None
    if axis.hat is not None:
        f = _find_field(layout, axis.hat, axis.occurrence, axis.where, "hat")
        label = f"{usage_label(f.usage, f.occurrence)} {axis.hat_axis}"
        fn, lo, hi, index = _hat_axis(f, axis), f.logical_min, f.logical_max, f.index
    else:
        assert axis.buttons is not None
        label = f"buttons {axis.buttons[0]}/{axis.buttons[1]} (-/+)"
        fn = _button_pair_axis(axis)
    shaping = shaping_text(axis)
    info = AxisInfo(slot, label, lo, hi, axis.unsigned, axis.failsafe, shaping, index)
    return fn, info


def configured_binding(
    layout: DeviceLayout,
    device: DeviceConfig,
    button_runs: Sequence[ButtonRun] | None = None,
    known: KnownDevice | None = None,
) -> DeviceBinding:
    """The entry's binding on this device; `button_runs`: the entry's, compiled already;
    `known`: the device's entry in the device database (where an axis without `arm:` rests).
    Raises MappingError naming the config line when a usage is not in the device."""
    if device.default_layout:
        return default_binding(layout, device.name, device.node_id, device, known)
    if button_runs is None:
        button_runs = compile_button_runs([(r.hid, r.node) for r in device.buttons])
    axes, guarded, trims = [], [], []
    for axis in device.axes:
        fn, info = _configured_axis(layout, axis)
        axes.append((AXIS_NAMES.index(axis.slot), fn, info, axis.failsafe))
        guarded += _guarded_axis(axis, info, layout.application, known)
        if axis.trim_switch is not None:
            trims.append(_trim_switch(layout, axis.trim_switch, AXIS_NAMES.index(axis.slot)))
    hats, notes = [], []
    for hat in device.hats:
        f = _find_field(layout, hat.usage, hat.occurrence, hat.where, "hat")
        hats.append(hat_table(f, hat.to))
        notes.append(_hat_note(f, hat))
    handover = handover_of(layout, device)
    battery = battery_plan(layout, device.low_battery)
    return DeviceBinding(
        device.name,
        device.node_id,
        axes,
        button_runs,
        hats,
        notes,
        device.where,
        handover,
        battery,
        NeutralGuard(tuple(guarded)),
        trims,
        device.reports,
    )


def _guarded_axis(
    axis: AxisConfig, info: AxisInfo, application: int, known: KnownDevice | None
) -> list[GuardedAxis]:
    """The axis's guard: `arm:` as configured, else the device database's, else by its
    usage (known_devices.guard_axis)."""
    slot = AXIS_NAMES.index(axis.slot)
    configured = (axis.arm, axis.arm_tolerance)
    guarded = guard_axis(slot, info.source, axis.usage, application, known, configured)
    if guarded is None:
        return []
    return [replace(guarded, unsigned=axis.unsigned, trim=axis.trim)]


def _trim_switch(layout: DeviceLayout, config: TrimSwitchConfig, slot: int) -> TrimSwitch:
    if config.buttons is not None:
        minus, plus = (1 << (b - 1) for b in config.buttons)
        return TrimSwitch(slot, config.step, config.limit, minus=minus, plus=plus)
    assert config.hat is not None
    f = _find_field(layout, config.hat, config.occurrence, config.where, "trim switch hat")
    return TrimSwitch(
        slot,
        config.step,
        config.limit,
        hat_index=f.index,
        hat_lo=f.logical_min,
        hat_hi=f.logical_max,
        hat_axis=config.hat_axis or "x",
    )


def _hat_note(f: InputField, hat: HatConfig) -> str:
    label = usage_label(f.usage, f.occurrence)
    if hat.to == "hat1":
        return f"hat {label} -> hat1 (group 1 bits 24-31)"
    pairs = [f"{d} {b}" for d, b in zip(HAT_DIRECTIONS, hat.to, strict=True) if b is not None]
    return f"hat {label} -> node buttons " + ", ".join(pairs)
