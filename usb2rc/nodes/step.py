"""The node step's result and its readers: one immutable snapshot of every node per step.

The node table (usb2rc.nodes.table) runs one *step* at a time (nodes.table.step_if_due): it reads
each reader's record once, arms the neutral guard, steps the trims, decides each node's
failsafe and publishes a `TableSnapshot` with one assignment. Reading a snapshot changes
nothing (docs/DESIGN.md, "Node state: one step per period").

Decisions:
- the base period is fixed, BASE_PERIOD_S (4 ms, 250 Hz): the grid steps are memoised on
  (at most one per period and set of reader records), faster than every output's default
  rate;
- the grid (these steps, every output's ticks, the node clock, the status socket) counts
  its multiples from GRID_EPOCH_S, three quarters of a kernel tick, so that no tick falls on the
  kernel's own (bench/README.md, "Issue 21: the grid half a kernel tick off the kernel's");
- the step for a period runs exactly once, whoever triggers it: each driver before each of
  its ticks (so a frame carries the newest records), or the `NodeClock` thread once per
  fastest output's period, at a phase away from every output's ticks (so arming and trims
  never wait for an output to tick: a `udpin` output nobody called, `monitor`; and no tick
  waits for the clock), under the table lock, memoised. The clock
  does not run at the base period: between two ticks of the fastest output no one reads
  a step, and stepping 250 times a second for a 50 Hz line was a third of the daemon's CPU
  (bench/README.md, "Issue 22, second pass");
- "every tap since my last frame" is per output state, and lives with the output: its
  `TapLatch` remembers, per device, the last press serial it showed, and shows the presses
  the snapshot's records logged since. Whichever output reads first, each sees each tap in
  exactly one of its frames (docs/ICD.md, "Taps").
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Final, NamedTuple

from usb2rc.config.model import HandoverConfig
from usb2rc.hid.descriptor import InputState
from usb2rc.hid.reader import ReaderRecord
from usb2rc.nodes.binding import DeviceBinding, NodeInputs
from usb2rc.nodes.scaling import add_trim
from usb2rc.runtime.worker import Worker

BASE_PERIOD_S = 0.004  # the step's grid: at most one step per period and set of records
# With no output (`monitor`, the status socket alone): the snapshot stepped at 50 Hz.
LIVENESS_PERIOD_S = 0.02
# The clock's phase: this many offsets tried, over about a second of steps (at most this
# many), once when the outputs are built.
PHASE_CANDIDATES = 20
PHASE_HORIZON_S = 1.0
PHASE_HORIZON_STEPS = 250
EARLY_WAKE_S = 0.0001  # the node clock's wake-up may come this much early (float rounding)
CLOCK_MONOTONIC_COARSE = 6  # Linux's id for it (uapi/linux/time.h); `time` does not name it
MAX_KERNEL_TICK_S = 0.01  # HZ is at least 100: a coarser resolution is not the tick


def kernel_tick_s() -> float:
    """The kernel's timer tick, 1/HZ (4 ms at HZ=250, 10 ms on a 100 Hz kernel), where the
    platform tells it: on Linux the resolution of CLOCK_MONOTONIC_COARSE, which that tick
    advances. 0 where it is not known (another OS)."""
    if not sys.platform.startswith("linux"):
        return 0.0
    try:
        tick = time.clock_getres(CLOCK_MONOTONIC_COARSE)
    except OSError:
        return 0.0
    return tick if 0.0 < tick <= MAX_KERNEL_TICK_S else 0.0


# The grid's epoch: every output's ticks and the node steps fall on the multiples of their
# period counted from here on the monotonic clock. Three quarters of a kernel tick, not 0:
# Linux aligns its tick to the multiples of 1/HZ on the same clock (kernel/time/tick-sched.c,
# `tick_init_jiffy_update`), and the tick wakes the kernel's timer-wheel work there
# (`schedule_timeout` sleepers, delayed work: kworkers, kdamond). A write on a multiple of
# 20 ms woke the far end's reader onto a CPU that such a thread held for up to 2.8 ms,
# 1-5 frames in 1,000 (bench/README.md, "Issue 21: the grid half a kernel tick off the
# kernel's"). Not half a tick: the periods that are an odd number of half ticks (SUMD's
# 10 ms, CRSF's 2 ms at 500 Hz, at HZ=250) then fell on every other kernel tick; from three
# quarters, every multiple of half a tick is a quarter tick off the kernel's, and a whole
# number of ticks is the longest after the tick's work began (bench/README.md, "Issue 21:
# one thread for every output").
GRID_EPOCH_S = kernel_tick_s() * 3 / 4


def aligned(now: float, period_s: float) -> float:
    """The first multiple of `period_s` from the grid's epoch at or after `now` (monotonic
    clock, GRID_EPOCH_S: 3/4 of a kernel tick, off the kernel's own ticks)."""
    return GRID_EPOCH_S + math.ceil((now - GRID_EPOCH_S) / period_s - 1e-9) * period_s


class NodeFrame(NamedTuple):
    node_id: int
    failsafe: bool
    axes: tuple[int, ...]
    group1: int
    group2: int
    unsigned_slots: int = 0  # bit k set: axis slot k is a uint16 (binding.unsigned_slots)
    # the status a live node asks for (the session decides: docs/ICD.md, "Status priority")
    handover: HandoverConfig | None = None  # a handover button is down: `&`, and where to
    low_battery: bool = False  # a device's battery is low: `%`
    # the node's switches: (name, int16 value), by name (outputs built before a reload
    # read them by name, usb2rc.nodes.switches)
    switches: tuple[tuple[str, int], ...] = ()
    # What may act as a press (docs/ICD.md, "A held button is not a press"): the node
    # buttons held now that went down while the node was live, and the switches a press set
    # since then. Group bits above show every held button; a held-over one is not here.
    pressed: tuple[int, int] = (0, 0)
    pressed_switches: tuple[str, ...] = ()


class DeviceView(NamedTuple):
    """One device feeding a node, as the step left it."""

    device_id: int  # the table's number for this attachment (a re-plug is a new one)
    binding: DeviceBinding
    inputs: NodeInputs  # what it sends (trimmed; held or failsafe values unless live)
    live: bool
    known: bool  # its state is from a report (its taps count, live or not)
    record: ReaderRecord  # the reader's record the step read (its press log)
    trims: tuple[tuple[int, float], ...] = ()  # stepped trims of its trim-switch slots
    # usb2rc.nodes.presses: node buttons held since before its node went live (shown, never
    # a press), and the press serial after which its presses count
    held_over: tuple[int, int] = (0, 0)
    counts_from: int = 0

    @property
    def pressed(self) -> tuple[int, int]:
        """Its node buttons held now that went down while its node was live."""
        inputs, held = self.inputs, self.held_over
        return inputs.group1 & ~held[0], inputs.group2 & ~held[1]

    def tapped_since(self, serial: int) -> int:
        """HID buttons pressed after press `serial` and already released."""
        return self.record.pressed_since(serial) & ~self.record.state.buttons

    def with_taps(self, taps: int) -> NodeInputs:
        """Its inputs with the buttons in `taps` shown pressed."""
        state = self.record.state
        inputs = self.binding.apply(InputState(state.values, state.buttons | taps))
        if (
            inputs.handover
            and not self.inputs.handover
            and self.binding.holds_handover(state.buttons)
        ):  # held over, not tapped (usb2rc.nodes.presses): no `&`
            inputs = inputs._replace(handover=False)
        return trimmed(inputs, dict(self.trims), self.binding) if self.trims else inputs


class NodeView(NamedTuple):
    """One node after a step: its frame, and what it is made of (for a latch's taps)."""

    frame: NodeFrame
    devices: tuple[DeviceView, ...] = ()
    base_axes: tuple[int, ...] = ()  # the expected entries' failsafe axes under the devices'
    base_unsigned: int = 0
    waiting_for: tuple[str, ...] = ()  # why it is `!` (`monitor`, stats)
    overrides: tuple[tuple[int, int], ...] = ()  # (slot, value): switch slots, throttle cuts


class TableSnapshot:
    """Every node after step `period` (sorted by Node-ID). Immutable (`Final`). A plain
    class with its own `__init__`: compiled, one is made in C, where a dataclass's
    generated `__init__` would run as Python at every step. Keyword-only: a field added
    later cannot shift what positional arguments meant."""

    def __init__(
        self,
        *,
        period: int = -1,
        at: float = 0.0,
        nodes: tuple[NodeView, ...] = (),
        switches: tuple[tuple[str, int], ...] = (),
    ) -> None:
        self.period: Final = period
        self.at: Final = at  # the clock's time of the step
        self.nodes: Final = nodes
        self.switches: Final = switches  # every switch's position, by name
        # When the newest report a live device published was read (monotonic): what a
        # frame made from this snapshot carries at the freshest. None: no live device.
        # Worked out here, once (every output due with it asks).
        self.newest_report_at: Final = _newest_report_at(nodes)

    @property
    def frames(self) -> list[NodeFrame]:
        return [node.frame for node in self.nodes]

    def _fields(self) -> tuple[object, ...]:
        return (self.period, self.at, self.nodes, self.switches)

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        assert isinstance(other, TableSnapshot)
        return self._fields() == other._fields()

    def __hash__(self) -> int:
        return hash(self._fields())

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(period={self.period}, at={self.at}, nodes={self.nodes}, "
            f"switches={self.switches})"
        )


def _newest_report_at(nodes: tuple[NodeView, ...]) -> float | None:
    newest: float | None = None
    for node in nodes:
        for device in node.devices:
            at = device.record.at
            if device.live and at is not None and (newest is None or at > newest):
                newest = at
    return newest


EMPTY = TableSnapshot()


def compose(
    node_id: int,
    failsafe: bool,
    base_axes: Sequence[int],
    base_unsigned: int,
    devices: Sequence[tuple[DeviceBinding, NodeInputs]],
    pressed: tuple[int, int] = (0, 0),
) -> NodeFrame:
    """A node's frame from its devices' inputs, merged in order onto the base axes;
    `pressed`: what of it may act as a press (`NodeFrame.pressed`)."""
    axes = list(base_axes)
    group1 = group2 = 0
    unsigned = base_unsigned
    handover: HandoverConfig | None = None
    low_battery = False
    for binding, inputs in devices:
        merge_axes(axes, inputs)
        group1 |= inputs.group1
        group2 |= inputs.group2
        unsigned |= binding.unsigned_slots  # computed once, with the binding
        if inputs.handover:  # one handover button per node (config/status.py)
            handover = binding.handover
        low_battery = low_battery or inputs.low_battery
    return NodeFrame(
        node_id,
        failsafe,
        tuple(axes),
        group1,
        group2,
        unsigned,
        handover,
        low_battery,
        pressed=pressed,
    )


def merge_axes(axes: list[int], inputs: NodeInputs) -> None:
    for slot, value in enumerate(inputs.axes):
        if value is not None:
            axes[slot] = value


def trimmed(inputs: NodeInputs, trims: dict[int, float], binding: DeviceBinding) -> NodeInputs:
    axes = list(inputs.axes)
    for slot, trim in trims.items():
        value, info = axes[slot], binding.axis_info[slot]
        if value is not None and info is not None:
            axes[slot] = add_trim(value, trim, info.unsigned)
    return inputs._replace(axes=tuple(axes))


class TapLatch:
    """One output's "buttons tapped since my last frame": owned by that output, advanced
    only by its own reads. A tap over before the next step still shows: the record's press
    log keeps it, and the latch shows every press after the serial it last showed."""

    def __init__(self) -> None:
        self._seen: dict[int, int] = {}  # device_id -> the press serial last shown

    def frames(
        self, snapshot: TableSnapshot, node_ids: frozenset[int] | None = None
    ) -> list[NodeFrame]:
        """The snapshot's frames (those of `node_ids` only, when given: the nodes its
        output reads), each live device's taps since this latch's last call shown
        pressed. One latch is always asked for the same nodes (its output's)."""
        seen: dict[int, int] = {}
        nodes = snapshot.nodes
        if node_ids is not None:
            nodes = tuple([node for node in nodes if node.frame.node_id in node_ids])
        frames = [self._latched(node, seen) for node in nodes]
        self._seen = seen  # devices gone from the snapshot are forgotten
        return frames

    def _latched(self, node: NodeView, seen: dict[int, int]) -> NodeFrame:
        taps_of: dict[int, int] = {}  # device_id -> HID buttons tapped since this latch saw it
        for device in node.devices:
            before = self._seen.get(device.device_id, 0)
            seen[device.device_id] = device.record.press_serial if device.known else before
            taps = device.tapped_since(before) if device.live else 0
            if taps:
                taps_of[device.device_id] = taps
        if not taps_of:
            return node.frame
        frame = node.frame
        added = [
            d.binding.tap_groups(taps_of[d.device_id])
            for d in node.devices
            if d.device_id in taps_of
        ]
        if None not in added:  # the taps add button bits and change nothing else
            group1, group2 = frame.group1, frame.group2
            for bits in added:
                assert bits is not None
                group1 |= bits[0]
                group2 |= bits[1]
            return frame._replace(group1=group1, group2=group2)
        inputs = [
            (d.binding, d.with_taps(taps_of[d.device_id]) if d.device_id in taps_of else d.inputs)
            for d in node.devices
        ]
        latched = compose(
            frame.node_id, frame.failsafe, node.base_axes, node.base_unsigned, inputs, frame.pressed
        )
        if not node.overrides and not frame.switches:
            return latched
        axes = list(latched.axes)
        for slot, value in node.overrides:  # the step's switches and cuts win over the taps
            axes[slot] = value
        switches, pressed_switches = frame.switches, frame.pressed_switches
        return latched._replace(
            axes=tuple(axes), switches=switches, pressed_switches=pressed_switches
        )


def clock_period(output_periods: Iterable[float]) -> float:
    """The node clock's period for outputs of these periods: the fastest output's, rounded
    down onto the base grid (a whole number of BASE_PERIOD_S, at least one), and never
    shorter than LIVENESS_PERIOD_S (with no output, that). Every driver steps the table
    itself before each of its ticks, so the clock only keeps the snapshot live for those
    that read it without ticking (`monitor`, the status socket, a `udpin` output nobody
    called): beside CRSF's 4 ms it would wake 250 times a second to find a fresh step."""
    fastest = min(output_periods, default=LIVENESS_PERIOD_S)
    on_grid = max(1, int(fastest / BASE_PERIOD_S + 1e-9)) * BASE_PERIOD_S
    return max(on_grid, LIVENESS_PERIOD_S)


def clock_phase(period_s: float, output_periods: Iterable[float]) -> float:
    """Where in its period the node clock steps: of PHASE_CANDIDATES offsets from the grid,
    the one whose steps stay farthest from every output's ticks (each output ticks on the
    multiples of its own period) over PHASE_HORIZON_S; of equal ones, the nearest to half
    the period. Half the period when the outputs tick only on the clock's own grid (one
    output: always). With SUMD's 10 ms beside CRSF's 4 ms, half of 4 ms falls on every
    other SUMD tick; 1 ms off the grid falls on none."""
    periods = list(output_periods)
    steps = max(1, min(PHASE_HORIZON_STEPS, round(PHASE_HORIZON_S / period_s)))

    def clearance(phase: float) -> float:
        """The step's closest approach to any tick (rounded: a float's residue is no gap)."""
        closest = period_s
        for k in range(steps):
            at = k * period_s + phase
            for period in periods:
                left = at % period
                closest = min(closest, left, period - left)
        return round(closest, 7)

    offsets = [period_s * i / PHASE_CANDIDATES for i in range(PHASE_CANDIDATES)]
    return max(offsets, key=lambda phase: (clearance(phase), -abs(phase - period_s / 2)))


class NodeClock(Worker):
    """The clock that keeps the snapshot live whether or not an output reads: `step`
    (the daemon's: `NodeTable.step_if_stale`, no step when a driver's ran within its
    period: every step drains the devices, and two steps a period would drain and compute
    twice what one frame carries) once per `period_s` (`clock_period`), `phase_s` (`clock_phase`)
    off its multiples from the grid's epoch (GRID_EPOCH_S), where the outputs' ticks are
    not: the clock's wake-up and step keep away from every tick. (On the grid, they fell
    on every tick; just before it, next to the readers' last call: bench/README.md,
    "Issue 21, the period error".)"""

    def __init__(
        self,
        step: Callable[[], object],
        clock: Callable[[], float],
        period_s: float = BASE_PERIOD_S,
        phase_s: float | None = None,
    ) -> None:
        super().__init__("node-clock")
        self._step = step
        self._clock = clock
        self.period_s = period_s
        self.phase_s = period_s / 2 if phase_s is None else phase_s

    def run(self) -> None:
        while not self.stopping:
            self._step()
            if self.sleep(self.until_next_step(self._clock())):
                return

    def until_next_step(self, now: float) -> float:
        """From `now` to the next step: `phase_s` after a multiple of the period, the first
        such moment more than EARLY_WAKE_S away (a wake-up a hair early, or a float's
        rounding, must not step twice for one period; a step taken late waits for the next
        one)."""
        period, phase = self.period_s, GRID_EPOCH_S + self.phase_s
        step = (math.floor((now - phase + EARLY_WAKE_S) / period) + 1) * period + phase
        return step - now
