"""Compile a validated Config into plain tables; bind devices; scale axes, buttons and hats.

`compile_mapping(config) -> Mapping`. `Mapping.bind(info, layout)` turns a config entry (or
the default layout) plus a device's DeviceLayout into a `DeviceBinding`, whose `apply(state)`
is the per-report hot path: a few precomputed closures, shift-and-mask button runs and hat
lookup tables, nothing read from the config per tick.

Axis scaling (docs/ICD.md, "Axis scaling"): after clamping,
`out = round((v - lo) * 65535 / (hi - lo)) - 32768`, exact in integers (round half to even, as
Python's `round`). With calibration, deadband, expo or trim set, the value goes through a
normalized x in [-1, 1] and back with
`to_wire(x) = floor((x + 1) * 32767.5 + 0.5) - 32768`: -1 → -32768, 0 → 0, +1 → +32767.
`unsigned: true` drops the `- 32768`. docs/CONFIG.md has the full pipeline.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from usb2rc.config import (
    HAT_DIRECTIONS,
    SUMD_DEFAULT_SLOTS,
    AxisConfig,
    ButtonRoute,
    ChannelRef,
    Config,
    DeviceConfig,
    HatConfig,
    MatchConfig,
    OutputConfig,
    Where,
)
from usb2rc.hid.backend import DeviceInfo
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
)
from usb2rc.protocol.c2_16b import AXIS_NAMES as AXIS_SLOTS
from usb2rc.protocol.c2_16b import GROUP1_BUTTONS, HAT1_SHIFT, NODE_BUTTONS

NUM_AXES = len(AXIS_SLOTS)
INT16_MIN, INT16_MAX, UINT16_MAX = -32768, 32767, 65535

# Usages the default layout knows.
DEFAULT_SLOT_OF = {
    GD_X: "x", GD_Y: "y", GD_Z: "z", GD_SLIDER: "slider",
    GD_RX: "rx", GD_RY: "ry", GD_RZ: "rz", GD_DIAL: "dial",
}  # fmt: skip
AUX_SLOTS = ("aux1", "aux2")


class MappingError(ValueError):
    """A config entry that does not fit the device it matched; the message names the line."""


# --------------------------------------------------------------------------- value types


@dataclass(frozen=True)
class NodeInputs:
    """What one device contributes to its node: axes already on the wire, button groups."""

    axes: tuple[int | None, ...]  # 10 slots, None: this device does not feed the slot
    group1: int
    group2: int


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


@dataclass(frozen=True)
class ChannelSource:
    """One SUMD channel: a node's axis slot (index 0..9) or node button (1..56)."""

    node_id: int
    kind: str  # "axis" or "button"
    index: int
    unsigned: bool = False
    name: str = ""


# --------------------------------------------------------------------------- scaling


def round_div(num: int, den: int) -> int:
    """round(num / den) in exact integers, halves to even (Python's round); den > 0."""
    q, r = divmod(num, den)
    if 2 * r > den or (2 * r == den and q & 1):
        q += 1
    return q


def scale_linear(v: int, lo: int, hi: int, unsigned: bool = False) -> int:
    """Clamp to [lo, hi], `round((v - lo) * 65535 / (hi - lo)) - 32768`
    (docs/ICD.md, "Axis scaling")."""
    if hi <= lo:
        return 32768 if unsigned else 0
    v = lo if v < lo else hi if v > hi else v
    out = round_div((v - lo) * 65535, hi - lo)
    return out if unsigned else out - 32768


def to_wire(x: float, unsigned: bool = False) -> int:
    """A normalized x in [-1, 1] (clamped) onto the wire: -1 → -32768, 0 → 0, +1 → 32767."""
    x = -1.0 if x < -1.0 else 1.0 if x > 1.0 else x
    out = math.floor((x + 1.0) * 32767.5 + 0.5)
    return out if unsigned else out - 32768


def normalize(v: int, lo: int, center: float, hi: int) -> float:
    """Raw v onto [-1, 1]: lo → -1, center → 0, hi → +1, linear on each side, clamped."""
    if v <= lo:
        return -1.0
    if v >= hi:
        return 1.0
    if v < center:
        return (v - center) / (center - lo)
    return (v - center) / (hi - center)


def apply_deadband(x: float, deadband: float) -> float:
    """Zero within ±deadband, then rescaled so ±1 stays ±1 (continuous at the edge)."""
    if deadband <= 0.0:
        return x
    if abs(x) <= deadband:
        return 0.0
    return math.copysign((abs(x) - deadband) / (1.0 - deadband), x)


def apply_expo(x: float, expo: float) -> float:
    """Standard RC expo: (1 - e) * x + e * x³."""
    return (1.0 - expo) * x + expo * x * x * x


def shape(x: float, axis: AxisConfig) -> float:
    """Deadband, expo, invert, trim (in that order) on a normalized value."""
    x = apply_expo(apply_deadband(x, axis.deadband), axis.expo)
    if axis.invert:
        x = -x
    x += axis.trim
    return -1.0 if x < -1.0 else 1.0 if x > 1.0 else x


def hat_direction(v: int, lo: int, hi: int) -> int | None:
    """DESIGN.md: 0 UP, 1 UP-RIGHT, ... 7 UP-LEFT; None when centred (outside [lo, hi])."""
    n = hi - lo + 1
    if n <= 0 or not lo <= v <= hi:
        return None
    angle = (v - lo) * 360 / n
    return round(angle / 45) % 8


def hat_component(direction: int | None, axis: str) -> int:
    """-1, 0 or +1 along x (left/right) or y (down/up) for a hat direction."""
    if direction is None:
        return 0
    if axis == "x":
        return 1 if direction in (1, 2, 3) else -1 if direction in (5, 6, 7) else 0
    return 1 if direction in (7, 0, 1) else -1 if direction in (3, 4, 5) else 0


def node_button_bit(button: int) -> tuple[int, int]:
    """Node button 1..56 → (group 0 or 1, bit)."""
    if not 1 <= button <= NODE_BUTTONS:
        raise ValueError(f"node button {button} is outside 1..{NODE_BUTTONS}")
    return (0, button - 1) if button <= GROUP1_BUTTONS else (1, button - GROUP1_BUTTONS - 1)


def axis_to_sumd(value: int, extended: bool = False) -> int:
    """int16 onto µs×8: -32768 → 1100 µs (8800), 0 → 1500 (12000), 32767 → 1900 (15200)."""
    try:
        from usb2rc.protocol.sumd import axis_to_sumd as codec_axis_to_sumd
    except ImportError:  # same line as protocol/sumd.py: through both ends
        low, high = (7200, 16800) if extended else (8800, 15200)
        return low + round_div((value + 32768) * (high - low), 65535)
    return codec_axis_to_sumd(value, extended)


def button_to_sumd(pressed: bool) -> int:
    """1100 µs released, 1900 µs pressed (µs×8)."""
    try:
        from usb2rc.protocol.sumd import button_to_sumd as codec_button_to_sumd
    except ImportError:
        return 15200 if pressed else 8800
    return codec_button_to_sumd(pressed)


def sumd_value(
    source: ChannelSource,
    axes: Sequence[int | None],
    group1: int,
    group2: int,
    extended: bool = False,
) -> int:
    """The SUMD wire value (µs×8) of one channel from a node's frame values."""
    if source.kind == "button":
        group, bit = node_button_bit(source.index)
        return button_to_sumd(bool(((group1, group2)[group] >> bit) & 1))
    value = axes[source.index]
    if value is None:
        value = 32768 if source.unsigned else 0
    if source.unsigned:
        value -= 32768
    return axis_to_sumd(min(32767, max(-32768, value)), extended)  # never raise on a tick


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
    if isinstance(to, str):  # "hat1", the only name config.py lets through
        return (1 << (HAT1_SHIFT + direction), 0)
    button = to[direction]
    if button is None:
        return (0, 0)
    group, bit = node_button_bit(button)
    return (1 << bit, 0) if group == 0 else (0, 1 << bit)


def _linear_axis(field: InputField, axis: AxisConfig | None) -> AxisFn:
    i, lo, hi = field.index, field.logical_min, field.logical_max
    unsigned = axis.unsigned if axis else False
    invert = axis.invert if axis else False
    if invert:
        return lambda values, _b: scale_linear(lo + hi - values[i], lo, hi, unsigned)
    return lambda values, _b: scale_linear(values[i], lo, hi, unsigned)


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
    ) -> None:
        self.name = name
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
        self.axis_slots = frozenset(AXIS_SLOTS[slot] for slot, _ in self._axes)
        self.group1_mask, self.group2_mask = self._masks()

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
        return NodeInputs(tuple(axes), groups[0], groups[1])

    def failsafe(self, last: NodeInputs | None = None) -> NodeInputs:
        """Axes: the configured failsafe value, else the last value (0 if none); no buttons."""
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
    from usb2rc.hid.usages import usage_name

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
    return [(slot, taken[slot]) for slot in AXIS_SLOTS if slot in taken]


def first_hat(layout: DeviceLayout) -> InputField | None:
    return next((f for f in layout.inputs if f.usage == GD_HAT_SWITCH), None)


def default_binding(layout: DeviceLayout, name: str, node_id: int | None = None) -> DeviceBinding:
    axes = []
    for slot, f in default_axis_fields(layout):
        fn, info = _field_axis(f, None, slot)
        axes.append((AXIS_SLOTS.index(slot), fn, info, None))
    hats, notes = [], []
    hat = first_hat(layout)
    if hat is not None:
        hats.append(hat_table(hat, "hat1"))
        notes.append(f"hat {usage_label(hat.usage, hat.occurrence)} -> hat1 (group 1 bits 24-31)")
    return DeviceBinding(name, node_id, axes, DEFAULT_BUTTON_RUNS, hats, notes)


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
    if axis.hat is not None:
        f = _find_field(layout, axis.hat, axis.occurrence, axis.where, "hat")
        label = f"{usage_label(f.usage, f.occurrence)} {axis.hat_axis}"
        fn, lo, hi = _hat_axis(f, axis), f.logical_min, f.logical_max
    else:
        assert axis.buttons is not None
        label = f"buttons {axis.buttons[0]}/{axis.buttons[1]} (-/+)"
        fn = _button_pair_axis(axis)
    shaping = shaping_text(axis)
    info = AxisInfo(slot, label, lo, hi, axis.unsigned, axis.failsafe, shaping)
    return fn, info


def configured_binding(
    layout: DeviceLayout, device: DeviceConfig, name: str | None = None
) -> DeviceBinding:
    """Raises MappingError naming the config line when a usage is not in the device."""
    name = name or device.name
    if device.default_layout:
        binding = default_binding(layout, name, device.node_id)
        binding.where = device.where
        return binding
    axes = []
    for axis in device.axes:
        fn, info = _configured_axis(layout, axis)
        axes.append((AXIS_SLOTS.index(axis.slot), fn, info, axis.failsafe))
    runs = compile_button_runs([(r.hid, r.node) for r in device.buttons])
    hats, notes = [], []
    for hat in device.hats:
        f = _find_field(layout, hat.usage, hat.occurrence, hat.where, "hat")
        hats.append(hat_table(f, hat.to))
        notes.append(_hat_note(f, hat))
    return DeviceBinding(name, device.node_id, axes, runs, hats, notes, device.where)


def _hat_note(f: InputField, hat: HatConfig) -> str:
    label = usage_label(f.usage, f.occurrence)
    if hat.to == "hat1":
        return f"hat {label} -> hat1 (group 1 bits 24-31)"
    pairs = [f"{d} {b}" for d, b in zip(HAT_DIRECTIONS, hat.to, strict=True) if b is not None]
    return f"hat {label} -> node buttons " + ", ".join(pairs)


# --------------------------------------------------------------------------- Mapping


def matches(match: MatchConfig, info: DeviceInfo) -> bool:
    """Every given match key must agree; product is a case-insensitive glob."""
    if match.vid is not None and match.vid != info.vid:
        return False
    if match.pid is not None and match.pid != info.pid:
        return False
    if match.serial is not None and match.serial != info.serial:
        return False
    if match.port is not None and match.port not in (info.port_path, info.path, info.hidraw):
        return False
    return match.product is None or fnmatch.fnmatchcase(info.product.lower(), match.product.lower())


class Mapping:
    """The compiled config: device entries in order, outputs, SUMD channel sources."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.devices = config.devices

    def entry_for(self, info: DeviceInfo) -> DeviceConfig | None:
        """The first config entry whose match fits the device, or None."""
        return next((d for d in self.devices if matches(d.match, info)), None)

    def bind(self, info: DeviceInfo, layout: DeviceLayout) -> DeviceBinding | None:
        """The device's binding; None when it has no entry and `defaults: false`.

        Raises MappingError (naming the config line) when the entry names a usage the device
        does not have.
        """
        entry = self.entry_for(info)
        if entry is not None:
            return configured_binding(layout, entry)
        if not self.config.defaults:
            return None
        return default_binding(layout, info.product or f"{info.vid:04x}:{info.pid:04x}")

    def pinned_node_ids(self) -> set[int]:
        return {d.node_id for d in self.devices if d.node_id is not None}

    def sumd_channels(self, output: OutputConfig) -> list[ChannelSource]:
        """The output's channel sources; without `channels`, the lowest configured node's
        x, y, z, rz, slider, rx, ry, dial (node 0 when no node is pinned)."""
        refs = output.channels
        if refs is None:
            node = min(self.pinned_node_ids(), default=0)
            refs = tuple(ChannelRef.axis(node, slot) for slot in SUMD_DEFAULT_SLOTS)
        return [self._channel(ref) for ref in refs]

    def _channel(self, ref: ChannelRef) -> ChannelSource:
        if ref.kind == "button":
            return ChannelSource(ref.node_id, "button", ref.index, False, ref.name)
        unsigned = any(
            axis.unsigned
            for d in self.devices
            if d.node_id == ref.node_id
            for axis in d.axes
            if axis.slot == ref.slot
        )
        return ChannelSource(ref.node_id, "axis", ref.index, unsigned, ref.name)


def compile_mapping(config: Config) -> Mapping:
    return Mapping(config)


__all__ = [
    "AxisInfo",
    "ButtonRoute",
    "ChannelSource",
    "DeviceBinding",
    "Mapping",
    "MappingError",
    "NodeInputs",
    "compile_mapping",
    "scale_linear",
    "sumd_value",
    "to_wire",
]
