"""Node state: the one lock-guarded place where devices (hot-plug and reader threads) meet
the outputs (driver threads).

Devices are attached to Node-IDs. One step at a time (usb2rc.nodes.step: before each output
tick, and on the node clock between them; at most one per base period and records) reads each
reader's record once, runs the neutral guard and the trims, and publishes an immutable
snapshot of every node with the service event log (`NodeSnapshot`, `EventLog`); each
output's session reads it with its own event cursor and its own tap latch.
Reading never changes the nodes: which outputs exist, or tick, does not change when a
device arms. Readers never take this lock: each publishes one immutable `ReaderRecord` by a
single assignment. Devices are added and removed only by the lifecycle thread
(usb2rc.nodes.lifecycle); a device is removed by its reader, not by a path that the kernel may
already have given to another device.
"""

from __future__ import annotations

import logging
import math
import operator
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Final, Protocol

from usb2rc.config.controls_model import SwitchConfig, ThrottleCut
from usb2rc.config.layout import AXIS_COUNT, AXIS_NAMES
from usb2rc.hid.backend import DeviceInfo, ErrorCode
from usb2rc.hid.reader import ReaderRecord
from usb2rc.nodes import steady
from usb2rc.nodes.binding import DeviceBinding, NodeInputs
from usb2rc.nodes.guard import RestWatch
from usb2rc.nodes.presses import NO_BUTTONS, SINCE_RELOAD, PressGate, button_mapping_changed
from usb2rc.nodes.silence import SilenceWatch
from usb2rc.nodes.step import (
    BASE_PERIOD_S,
    GRID_EPOCH_S,
    DeviceView,
    NodeView,
    TableSnapshot,
    compose,
    merge_axes,
    trimmed,
)
from usb2rc.nodes.step import (
    NodeFrame as NodeFrame,  # re-exported: the sessions speak in it
)
from usb2rc.nodes.switches import SwitchBank
from usb2rc.nodes.trims import TrimStore

log = logging.getLogger("usb2rc.nodes")

EVENTS_KEPT = 1024  # the service event log's bound: a line further behind announces again


class EventKind(Enum):
    CONNECTED = "connected"  # -> service frames 1, 6, 5, 7
    DISCONNECTED = "disconnected"  # -> 2
    ERROR = "error"  # -> 3 with the error code


@dataclass(frozen=True)
class ServiceEvent:
    kind: EventKind
    node_id: int
    info: DeviceInfo | None = None
    device_type: str = ""
    error_code: int = 0


@dataclass(frozen=True)
class EventLog:
    """The table's service events, append-only and bounded, as one immutable value: event
    number `start + i` is `events[i]`. A line session keeps its own cursor (the number of
    the next event it has not seen); a cursor before `start` fell behind (`since` says
    None) and must announce everything again from `present`: the CONNECTED event of every
    device present, in Node-ID order (what a line that opens announces)."""

    start: int = 0
    events: tuple[ServiceEvent, ...] = ()
    present: tuple[ServiceEvent, ...] = ()

    @property
    def end(self) -> int:
        """The number the next event will get: a cursor here has seen everything."""
        return self.start + len(self.events)

    def since(self, cursor: int) -> tuple[ServiceEvent, ...] | None:
        """The events from number `cursor` on; None if some of them were dropped already."""
        if cursor < self.start:
            return None
        return self.events[cursor - self.start :]

    def appended(self, event: ServiceEvent, present: tuple[ServiceEvent, ...]) -> EventLog:
        """This log with `event` added (the oldest dropped past EVENTS_KEPT)."""
        events = (*self.events, event)
        drop = max(0, len(events) - EVENTS_KEPT)
        return EventLog(self.start + drop, events[drop:], present)


EMPTY_LOG = EventLog()


class NodeSnapshot(TableSnapshot):
    """A step's snapshot (`nodes.step.TableSnapshot`) with the service event log as it was
    when the step ran: a line session reads both from one value, so a device's `2` is in
    the same snapshot as the first frame that has it gone."""

    def __init__(
        self,
        *,
        period: int = -1,
        at: float = 0.0,
        nodes: tuple[NodeView, ...] = (),
        switches: tuple[tuple[str, int], ...] = (),
        log: EventLog = EMPTY_LOG,
    ) -> None:
        super().__init__(period=period, at=at, nodes=nodes, switches=switches)
        self.log: Final = log

    def _fields(self) -> tuple[object, ...]:
        return (self.period, self.at, self.nodes, self.switches, self.log)

    def __repr__(self) -> str:
        return f"{super().__repr__()[:-1]}, log={self.log})"


@dataclass(frozen=True)
class ExpectedEntry:
    """A config entry pinned to a node whose device has not come (yet)."""

    inputs: NodeInputs  # what it sends meanwhile: its failsafe values
    unsigned_slots: int = 0  # the entry's (mapping.CompiledEntry.unsigned_slots)
    match: str = ""  # what its `match:` asks for, as the log and `monitor` say it
    where: str = ""  # the entry in its config file ("usb2rc.yaml:55: devices[2]")


@dataclass(frozen=True)
class MissingEntry:
    """A pinned config entry whose device has not come: its node sends `!` for it."""

    node_id: int
    name: str
    match: str
    where: str

    def record(self) -> dict[str, Any]:
        """For `stats` and the log (usb2rc.runtime.stats_text.missing_line), and JSON stats."""
        return {
            "node_id": self.node_id,
            "entry": self.name,
            "match": self.match,
            "where": self.where,
        }


class SnapshotSource(Protocol):
    """A DeviceReader, as the table sees it: its last published record, read once, after
    `pull` (a pulled reader decodes what its device queued; otherwise nothing)."""

    @property
    def record(self) -> ReaderRecord: ...

    def pull(self) -> None: ...


@dataclass
class _Attached:
    """One device feeding a node; kept (not present) after an unplug, for failsafe."""

    info: DeviceInfo
    binding: DeviceBinding
    source: SnapshotSource
    device_type: str
    present: bool = True
    last_inputs: NodeInputs | None = None  # held values (from before an unplug / re-plug)
    # Neutral guard (usb2rc.nodes.guard, docs/ICD.md "Neutral guard"): False from the plug until
    # the guarded axes rest; `waiting` names those that did not, at the last frame.
    armed: bool = False
    waiting: tuple[str, ...] = ()
    rest: RestWatch = field(default_factory=RestWatch)  # how long it has rested (guard.py)
    device_id: int = 0  # the table's number for this attachment (TapLatch's key)
    trim_serial: int = 0  # the press serial the trims have stepped on
    bad_spells_seen: int = 0  # the reader's runs of bad reports this device has answered
    trim_positions: dict[int, int] = field(default_factory=dict)  # hat switches: slot -> -1/0/1
    gate: PressGate = field(default_factory=PressGate)  # which held buttons are presses
    silence: SilenceWatch = field(default_factory=SilenceWatch)  # nodes/silence.py
    silent_since: float | None = None  # when it was found silent (None: it reports)
    silence_news: str = ""  # "silent" or "back" at the step it changed, for the node

    @property
    def live(self) -> bool:
        """Present, its state known (at least one report decoded since it was plugged) and
        its guarded axes at rest once since then (`armed`).

        Decision: until then the node stays in failsafe with the held (or failsafe) values;
        a re-plugged throttle must not jump to mid-scale before it has said where it is, nor
        go live at full before it was pulled back."""
        return self._known(self.source.record) and self.armed

    def _known(self, record: ReaderRecord) -> bool:
        """Present, with a state from a report, and not refusing its reports now."""
        return self.present and record.reports > 0 and not record.in_error

    def last_step(self, now: float) -> NodeInputs:
        """What the device sends at its last step (under the table lock): the unplug, the
        stop, or a reload that changed its axes steps it once more, on its reader's last
        record, for the values it holds (trims aside, as a held value never had them)."""
        return self.step(self.source.record, None, now).inputs

    def step(self, record: ReaderRecord, trims: dict[int, float] | None, now: float) -> DeviceView:
        """The device in this step (under the table lock): what it sends and whether that
        is live, both from one reader record (a record published between two reads must
        not give a frame marked live that carries the held values). `trims`: the node's
        stepped trims of the slots this device has trim switches for; `now`: the step's
        time (the neutral guard's rest has a time); `record`: its reader's, read once."""
        if record.bad_spells != self.bad_spells_seen:
            self._bad_reports_began(record)
        if self._silent(record, now):
            return self._view(record, self.binding.failsafe(self.last_inputs), False)
        if not self._known(record):
            return self._view(record, self.binding.failsafe(self.last_inputs), False)
        if not self.armed:
            # the guard looks at its own axes only: the rest of `apply` waits for the arming
            guarded: Sequence[int | None] = self.binding.guarded_axes(record.state)
            if trims:
                guarded = trimmed(NodeInputs(tuple(guarded), 0, 0), trims, self.binding).axes
            timed = (record, record.reports, record.at)
            self.waiting = self.rest.check(self.binding.guard, guarded, trims, timed, now)
            if self.waiting:
                return self._view(record, self.binding.failsafe(self.last_inputs), False)
            self.armed = True
        inputs = self.binding.apply(record.state)
        if trims:
            inputs = trimmed(inputs, trims, self.binding)
        return self._view(record, inputs, True, trims)

    def _view(
        self,
        record: ReaderRecord,
        inputs: NodeInputs,
        live: bool,
        trims: dict[int, float] | None = None,
    ) -> DeviceView:
        known = self._known(record)
        own_trims = tuple(sorted(trims.items())) if trims else ()
        gate = self.gate
        return DeviceView(
            self.device_id,
            self.binding,
            inputs,
            live,
            known,
            record,
            own_trims,
            gate.held_groups,
            gate.counts_from,
        )

    def _silent(self, record: ReaderRecord, now: float) -> bool:
        """Whether the device is silent now (nodes/silence.py). Going silent it holds its
        last values (buttons cleared) and goes back through the neutral guard; its node
        hears of both changes (`silence_news`)."""
        self.silence.kind = self.binding.reports
        silent = self.present and self.silence.silent(record, now)
        if silent and self.silent_since is None:
            self.silent_since, self.silence_news = now, "silent"
            self.disarm()
            self.last_inputs = self.binding.apply(record.state)
        elif not silent and self.silent_since is not None:
            self.silent_since, self.silence_news = None, "back"
        return silent

    def _bad_reports_began(self, record: ReaderRecord) -> None:
        """The device refused BAD_REPORTS_LIMIT reports in a row (docs/ICD.md "Device error
        codes", 0x06): it holds its last good values, `!`, and when its reports are good
        again it goes live through the neutral guard, as a re-plugged device. Decided on
        the reader's count of such runs, not on what a frame happened to see: a run that
        began and ended between two frames still re-arms the guard."""
        self.bad_spells_seen = record.bad_spells
        self.disarm()
        if record.reports:
            self.last_inputs = self.binding.apply(record.state)  # held; buttons cleared

    def disarm(self) -> None:
        """Through the neutral guard again, as a re-plugged device: a new rest from here (a
        rest or a report run seen before, by the old binding or before the bad reports,
        must not arm it)."""
        self.armed = False
        self.rest = RestWatch()

    def step_trims(self, node_id: int, store: TrimStore, record: ReaderRecord) -> None:
        """Step the node's trims from this device's trim switches: a button press steps once
        (every press, from the reader's press log), a hat steps when pushed (sampled). Only
        while the node is live, from presses after it went live (usb2rc.nodes.presses): a
        hat or button held since before is not a step."""
        switches = self.binding.trim_switches
        if not switches or not self._known(record):
            return
        after = max(self.trim_serial, self.gate.counts_from)
        rising = record.presses_after(after)
        self.trim_serial = record.press_serial
        for switch in switches:
            if switch.hat_index >= 0:
                position = switch.position(record.state)
                before = self.trim_positions.get(switch.slot, 0)
                self.trim_positions[switch.slot] = position
                steps = [position] if position and position != before else []
            else:
                steps = switch.presses(rising)  # one step per press, in order
            if steps and self.gate.is_open:
                for step in steps:  # each within the limit, as a transmitter's trim
                    value = store.step(node_id, switch, step)
                log.info("node %d: %s trim %+.3f", node_id, AXIS_NAMES[switch.slot], value)

    def same_device(self, info: DeviceInfo, binding: DeviceBinding) -> bool:
        """The same physical device come back: same model on the same port, or the same
        non-empty serial number, or the same pinned config entry."""
        same_model = (self.info.vid, self.info.pid) == (info.vid, info.pid)
        return (
            (same_model and bool(info.port_path) and self.info.port_path == info.port_path)
            or (bool(info.serial) and self.info.identity == info.identity)
            or (binding.node_id is not None and self.binding.name == binding.name)
        )


@dataclass
class _Node:
    node_id: int
    attached: list[_Attached] = field(default_factory=list)
    # config entries pinned here whose device has not come yet
    expected: dict[str, ExpectedEntry] = field(default_factory=dict)
    logged: tuple[bool, tuple[str, ...]] | None = None  # state and reasons last logged
    stepped_reasons: list[tuple[str, str]] = field(default_factory=list)  # at the last step
    silenced: list[_Attached] = field(default_factory=list)  # went silent, `3` not sent yet
    plan: steady.Plan | None = None  # its next steps' compiled path, while it is steady

    @property
    def failsafe(self) -> bool:
        """`!` unless every device feeding the node is present and known. A node nothing
        feeds any more (a reload removed its entry) is failsafe too, never `>` on nothing."""
        if not self.attached and not self.expected:
            return True
        return bool(self.expected) or not all(a.live for a in self.attached)

    def step(
        self, trims: TrimStore, now: float, records: Sequence[ReaderRecord], layout: int
    ) -> tuple[NodeView, list[str]]:
        """The node in this step: each device stepped once (trims, guard, press gate) on its
        record in `records`, then merged; the log lines of its press gates. A steady node
        takes the compiled path (usb2rc.nodes.steady) while its plan is of this `layout`
        (the table's devices); every other step is this one, which plans the next."""
        plan = self.plan
        if plan is not None and plan[0] == layout:
            view = steady.step(plan, records, now)
            if view is not None:
                return view, []
        view, notes = self._step(trims, now, iter(records))
        self.plan = steady.plan_for(self, view, layout, plan) if steady.compiled() else None
        return view, notes

    def _step(
        self, trims: TrimStore, now: float, records: Iterator[ReaderRecord]
    ) -> tuple[NodeView, list[str]]:
        """The step, every decision in it (see `step`)."""
        base = [0] * AXIS_COUNT
        base_unsigned = 0
        for entry in self.expected.values():
            merge_axes(base, entry.inputs)
            base_unsigned |= entry.unsigned_slots
        devices = []
        for attached in self.attached:
            own_trims = None
            record = next(records)
            if attached.binding.trim_switches:
                attached.step_trims(self.node_id, trims, record)
                own_trims = trims.of_switches(self.node_id, attached.binding.trim_switches)
            devices.append(attached.step(record, own_trims, now))
        # as `failsafe` says
        failsafe = not self.attached or bool(self.expected) or not all([d.live for d in devices])
        devices, notes = self._gated(devices, not failsafe)
        notes += self._silence_notes()
        merged = [(d.binding, d.inputs) for d in devices]
        pressed = NO_BUTTONS if failsafe else _pressed(devices)
        frame = compose(self.node_id, failsafe, base, base_unsigned, merged, pressed)
        self.stepped_reasons = self.reasons() if failsafe else []
        waiting = tuple([text for _, text in self.stepped_reasons])
        return NodeView(frame, tuple(devices), tuple(base), base_unsigned, waiting), notes

    def _silence_notes(self) -> list[str]:
        """A line for each device that went silent or reports again at this step; the
        silent ones are in `silenced` until the table has sent their `3`."""
        notes = []
        for a in self.attached:
            news = a.silence_news
            if not news:
                continue  # the common step
            a.silence_news = ""
            name = a.info.product or "device"
            if news == "silent":
                self.silenced.append(a)
                every = (
                    f"every {a.silence.interval_s * 1000:.0f} ms" if a.silence.interval_s else ""
                )
                notes.append(
                    f"node {self.node_id}: {name} went silent: no report for "
                    f"{a.silence.limit_s():.2f} s though it streamed {every}".rstrip()
                    + "; `!` until it reports again (docs/ICD.md, error 0x07 SILENT)"
                )
            elif news == "back":
                notes.append(
                    f"node {self.node_id}: {name} reports again: live once its guarded axes rest"
                )
        return notes

    def _gated(self, devices: list[DeviceView], live: bool) -> tuple[list[DeviceView], list[str]]:
        """Each device's press gate stepped (usb2rc.nodes.presses): its view with what is held
        over, and the log lines of gates that opened on held buttons."""
        gated, notes = [], []
        for attached, view in zip(self.attached, devices, strict=True):
            view, note = attached.gate.step(view, live)
            gated.append(view)
            if note:
                notes.append(f"node {self.node_id}: {note}")
        return gated, notes

    def reasons(self) -> list[tuple[str, str]]:
        """Why the node is `!`: (kind, text) per device or entry it waits for."""
        why = []
        for a in self.attached:
            name = a.info.product or "device"
            if not a.present:
                why.append(("lost", name))
            elif a.silent_since is not None:
                limit = a.silence.limit_s()
                why.append(("silent", f"{name} to report again (silent for over {limit:.2f} s)"))
            elif a.source.record.in_error:
                bad = a.source.record.refused_in_a_row
                why.append(
                    ("bad reports", f"good reports from {name} (its last {bad} were refused)")
                )
            elif a.waiting:
                kind = f"guard {name}" + (" fixed" if a.rest.fixed else "")
                why.append((kind, f"{', '.join(a.waiting)} ({name})"))
            elif not a.live:
                why.append(("unknown", f"{name} (no report yet)"))
        why += [("expected", _not_plugged(name, entry)) for name, entry in self.expected.items()]
        if not self.attached and not self.expected:
            why.append(("unfed", "a device or config entry (a reload moved or removed them)"))
        return why

    def failsafe_change(self, now: bool) -> str | None:
        """A log line when the node entered or left failsafe (`now`: the state its frame
        just gave), or waits for something else now (the neutral guard: what must rest),
        since the last call; `now` is the state of its last step (`step`)."""
        reasons = self.stepped_reasons if now else []
        key = (now, tuple([kind for kind, _ in reasons]))
        before, self.logged = self.logged, key
        if before == key:
            return None
        if before is None and not any(kind.startswith("guard") for kind, _ in reasons):
            return None  # a new node says nothing until it waits for the pilot, or is live
        texts = ", ".join(text for _, text in reasons) or "-"
        if not now:
            return f"node {self.node_id} leaves failsafe: all its devices are live"
        if before is None or before[0]:  # still `!`, for another reason: it must rest
            return f"node {self.node_id} waits for {texts}"
        return f"node {self.node_id} enters failsafe: waiting for {texts}"


def _pressed(devices: Sequence[DeviceView]) -> tuple[int, int]:
    group1 = group2 = 0
    for device in devices:
        pressed = device.pressed
        group1 |= pressed[0]
        group2 |= pressed[1]
    return group1, group2


def _not_plugged(name: str, entry: ExpectedEntry) -> str:
    return f"{name} (not plugged: {entry.match})" if entry.match else f"{name} (not plugged)"


Expected = dict[int, dict[str, ExpectedEntry]]


class NodeTable:
    """Node-IDs, the devices feeding them, and the log of their service events."""

    def __init__(
        self, expected: Expected | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._lock = threading.Lock()
        self._clock = clock  # the frames' time: the neutral guard's rest (the readers' clock)
        self._nodes: dict[int, _Node] = {}
        self._by_key: dict[str, tuple[int, _Attached]] = {}
        self._trims = TrimStore()
        self._switches = SwitchBank()  # switches and throttle cuts (nodes/switches.py)
        self._stopping = False
        # The step (docs/DESIGN.md, "Node state: one step per period"): the latest snapshot,
        # and what each node's view in it was made from: the period, the devices' layout,
        # the readers' records, and when (the table's clock).
        self._snapshot: NodeSnapshot = NodeSnapshot()
        self._log = EMPTY_LOG  # replaced whole by `_broadcast`, published by each step
        self._layout = 0  # bumped whenever devices, entries or bindings change
        self._snapshot_layout = -1  # the layout the snapshot's set of nodes is from
        self._stepped: dict[int, tuple[int, int, tuple[ReaderRecord, ...]]] = {}
        self._stepped_at: dict[int, float] = {}
        # per node, its devices resting, not long enough yet at its last step: a step of
        # the node when one has
        self._resting: dict[int, list[RestWatch]] = {}
        self._attachments = 0  # device ids handed out
        for node_id, entries in (expected or {}).items():
            self._nodes[node_id] = _Node(node_id, expected=dict(entries))

    # --- outputs -------------------------------------------------------------------------

    def frames(self) -> list[NodeFrame]:
        """Every node's frame in the latest step (buttons as they are: an output shows the
        taps between its frames through its own `TapLatch`, docs/ICD.md "Taps")."""
        return self.step_if_due().frames

    def snapshot(self) -> NodeSnapshot:
        """The latest step's snapshot, as it is: reading it changes nothing."""
        return self._snapshot

    def step_if_due(self, node_ids: frozenset[int] | None = None) -> NodeSnapshot:
        """Step each node unless it was already stepped for this period, these reader
        records and these devices (each driver's call before its tick, and the node
        clock's); the latest snapshot. `node_ids`: the nodes the caller reads (an output's
        channels), None: every node. The others keep their view from their last step; a
        change of devices or entries steps every node."""
        with self._lock:
            changes = self._step_if_due_locked(node_ids)
            snapshot = self._snapshot
        _log_changes(changes)
        return snapshot

    def step_if_stale(self, age_s: float) -> NodeSnapshot:
        """The node clock's call: the step (as `step_if_due`) of the nodes not stepped in
        the last `age_s`, by a driver before its tick. No view in the snapshot is older than
        `age_s`, and a clock beside outputs that step the nodes as often does not step them
        again for nobody (the five default outputs: a second step every 4 ms, ~3 % of a
        core)."""
        with self._lock:
            now = self._clock()
            at = self._stepped_at
            stale = frozenset(i for i in self._nodes if now - at.get(i, -math.inf) >= age_s)
            if now - self._snapshot.at >= age_s:  # no node at all: the snapshot's time moves
                changes = self._step_if_due_locked(None)
            elif stale or self._layout != self._snapshot_layout:
                changes = self._step_if_due_locked(stale)
            else:
                changes = []
            snapshot = self._snapshot
        _log_changes(changes)
        return snapshot

    def stop(self) -> None:
        """usb2rc stops: every device counts as gone from now on (no service events), so
        every node sends `!` with its failsafe or held values (docs/ICD.md, "Stop")."""
        with self._lock:
            self._stopping = True
            self._layout += 1
            for node in self._nodes.values():
                for attached in node.attached:
                    if attached.present:
                        attached.last_inputs = attached.last_step(self._clock())
                        attached.present = False
            self._by_key.clear()

    def _step_if_due_locked(self, node_ids: frozenset[int] | None) -> list[str]:
        """The step of the nodes asked for (all of them after a change of devices or
        entries), each memoised: a node is stepped once per (period, devices, records),
        whoever calls, and again within the period when a device's rest is long enough."""
        if node_ids is None or self._layout != self._snapshot_layout:
            ids = sorted(self._nodes)
        else:
            ids = sorted(self._nodes.keys() & self._switches.with_cut_switches(node_ids))
        nodes = [self._nodes[node_id] for node_id in ids]
        for node in nodes:  # what their devices queued until now, decoded
            for attached in node.attached:
                if attached.present:
                    attached.source.pull()
        now = self._clock()
        period = int((now - GRID_EPOCH_S) // BASE_PERIOD_S)  # the drivers' grid
        due = []
        for node in nodes:
            # each reader's record read once: the step uses these (values and liveness agree)
            records = tuple([a.source.record for a in node.attached])
            if not self._stepped_again(node.node_id, period, records, now):
                continue
            self._stepped[node.node_id] = (period, self._layout, records)
            self._stepped_at[node.node_id] = now
            due.append((node, records))
        fresh = node_ids is not None or period == self._snapshot.period
        if not due and fresh and self._layout == self._snapshot_layout:
            return []  # every node asked for is as its last step left it, in this period
        return self._step_locked(period, now, due)

    def _stepped_again(
        self, node_id: int, period: int, records: tuple[ReaderRecord, ...], now: float
    ) -> bool:
        """Whether the node is due a step: not stepped in this period, on these records and
        devices, or a rest of one of its devices is long enough by now."""
        last = self._stepped.get(node_id)
        same = (
            last is not None
            and last[0] == period
            and last[1] == self._layout
            and _same(last[2], records)
        )
        if not same:
            return True
        resting = self._resting.get(node_id)
        if not resting:
            return False  # no device of it resting, not long enough yet
        return any(rest.rested_by(now) for rest in resting)

    def _step_locked(
        self, period: int, now: float, due: list[tuple[_Node, tuple[ReaderRecord, ...]]]
    ) -> list[str]:
        """One step: each node due once, in Node-ID order, on the records read for it; the
        snapshot (those views, the others' from their last step) published with one
        assignment; the lines to log (a node entered or left failsafe)."""
        views, changes = [], []
        for node, records in due:
            view, notes = node.step(self._trims, now, records, self._layout)
            views.append(view)
            change = None if self._stopping else node.failsafe_change(view.frame.failsafe)
            if change:
                changes.append(change)
            changes += notes
            for attached in node.silenced:
                code = int(ErrorCode.SILENT)
                self._broadcast(
                    ServiceEvent(EventKind.ERROR, node.node_id, attached.info, "", code)
                )
            node.silenced.clear()
            self._resting[node.node_id] = _resting(node, now)
        every = len(due) == len(self._nodes)
        stepped = self._switches.step(views, every)
        if not every:  # the others as their last step left them
            fresh = {view.frame.node_id: view for view in stepped}
            stepped = tuple(fresh.get(v.frame.node_id, v) for v in self._snapshot.nodes)
        else:
            self._snapshot_layout = self._layout
            self._resting = {node.node_id: self._resting[node.node_id] for node, _ in due}
        positions = tuple(sorted(self._switches.positions.items()))
        self._snapshot = NodeSnapshot(
            period=period, at=now, nodes=stepped, switches=positions, log=self._log
        )
        return changes

    # --- devices -------------------------------------------------------------------------

    def add_device(
        self,
        node_id: int,
        info: DeviceInfo,
        binding: DeviceBinding,
        source: SnapshotSource,
        device_type: str,
    ) -> None:
        attached = _Attached(info, binding, source, device_type)
        with self._lock:
            if self._stopping:
                return  # its reader is stopped with the others
            self._attach_locked(node_id, attached)
        log.info(
            "device plugged: %s (%04x:%04x, port %s) -> Node-ID %d",
            info.product or "?",
            info.vid,
            info.pid,
            info.port_path or "?",
            node_id,
        )

    def _attach_locked(self, node_id: int, attached: _Attached) -> None:
        """The device feeds node_id from now on; the node announces it (`1`,`6`,`5`,`7`)."""
        info, binding = attached.info, attached.binding
        self._attachments += 1
        attached.device_id = self._attachments
        self._layout += 1
        node = self._nodes.setdefault(node_id, _Node(node_id))
        kept = []
        for old in node.attached:
            if not old.present and old.same_device(info, binding):
                attached.last_inputs = old.last_inputs  # held until it reports
            else:
                kept.append(old)
        node.attached = [*kept, attached]
        node.expected.pop(binding.name, None)
        self._by_key[info.key] = (node_id, attached)
        self._broadcast(_connected(node_id, attached))

    def move_device(
        self, key: str, node_id: int, binding: DeviceBinding, source: SnapshotSource
    ) -> int | None:
        """A reload pinned the live device to another node (docs/ICD.md "A reload and the
        live devices"): it leaves its node (`2`; the node sends `!`, nothing feeds it) and
        is announced on node_id as a new device there: connect sequence, its entry's
        failsafe values until it is known, and the neutral guard from the start. Returns
        the node it left (None: not the device `source` feeds)."""
        with self._lock:
            entry = self._by_key.get(key)
            if self._stopping or entry is None or entry[1].source is not source:
                return None
            old_id, old = entry
            self._nodes[old_id].attached.remove(old)
            self._broadcast(ServiceEvent(EventKind.DISCONNECTED, old_id, old.info))
            moved = _Attached(old.info, binding, source, old.device_type)
            moved.bad_spells_seen = source.record.bad_spells  # a run before the move is old
            self._attach_locked(node_id, moved)
        log.warning(
            "config reload: %s (%04x:%04x, port %s) moves from Node-ID %d to Node-ID %d "
            "(config entry %r): node %d sends `!`, node %d announces it and goes live once its "
            "guarded axes rest",
            old.info.product or "?",
            old.info.vid,
            old.info.pid,
            old.info.port_path or "?",
            old_id,
            node_id,
            binding.name,
            old_id,
            node_id,
        )
        return old_id

    def remove_device(
        self, key: str, error_code: int | None = None, source: SnapshotSource | None = None
    ) -> int | None:
        """The device is gone (unplugged, or failed to read: error_code). With `source`, only
        if the device under `key` is still the one that reader feeds: the kernel reuses
        hidraw paths, and a late exit must not take a newer device off its node."""
        with self._lock:
            entry = self._by_key.get(key)
            if entry is None or (source is not None and entry[1].source is not source):
                return None
            del self._by_key[key]
            self._layout += 1
            node_id, attached = entry
            attached.last_inputs = attached.last_step(self._clock())
            attached.present = False
            if error_code:
                event = ServiceEvent(EventKind.ERROR, node_id, attached.info, "", error_code)
                self._broadcast(event)
            self._broadcast(ServiceEvent(EventKind.DISCONNECTED, node_id, attached.info))
        info = attached.info
        how = f"failed (error code {error_code})" if error_code else "unplugged"
        log.warning(
            "device %s: %s (%04x:%04x, port %s, Node-ID %d)",
            how,
            info.product or "?",
            info.vid,
            info.pid,
            info.port_path or "?",
            node_id,
        )
        return node_id

    def device_error(self, key: str, error_code: int, source: SnapshotSource) -> int | None:
        """`3` with error_code on the node of the live device `source` feeds; its node."""
        with self._lock:
            entry = self._by_key.get(key)
            if self._stopping or entry is None or entry[1].source is not source:
                return None
            node_id, attached = entry
            self._broadcast(ServiceEvent(EventKind.ERROR, node_id, attached.info, "", error_code))
            return node_id

    def node_of(self, key: str) -> int | None:
        """The node the present device under `key` feeds."""
        with self._lock:
            entry = self._by_key.get(key)
            return entry[0] if entry else None

    def missing_entries(self) -> list[MissingEntry]:
        """Pinned config entries whose device has not come (their nodes send `!`)."""
        with self._lock:
            return [
                MissingEntry(node_id, name, entry.match, entry.where)
                for node_id, node in sorted(self._nodes.items())
                for name, entry in node.expected.items()
            ]

    def report_error(self, node_id: int, info: DeviceInfo | None, error_code: int) -> None:
        """A device that could not be used at all (open failed, descriptor unusable)."""
        with self._lock:
            self._broadcast(ServiceEvent(EventKind.ERROR, node_id, info, "", error_code))

    def entry_in_use(self, node_id: int, entry_name: str) -> DeviceInfo | None:
        """The present device that already feeds node_id through the config entry, if any."""
        with self._lock:
            node = self._nodes.get(node_id)
            for attached in node.attached if node else ():
                if attached.present and attached.binding.name == entry_name:
                    return attached.info
        return None

    def automatic_device_on(self, node_id: int) -> DeviceInfo | None:
        """A device without a pinned entry that feeds (or fed) node_id, if any."""
        with self._lock:
            node = self._nodes.get(node_id)
            for attached in node.attached if node else ():
                if attached.binding.node_id is None:
                    return attached.info
        return None

    def lost_node_of(self, info: DeviceInfo, binding: DeviceBinding) -> int | None:
        """The node a re-plugged device fed before it was lost (see `_Attached.same_device`)."""
        with self._lock:
            for node_id in sorted(self._nodes):
                for attached in self._nodes[node_id].attached:
                    if not attached.present and attached.same_device(info, binding):
                        return node_id
        return None

    def attachments(self) -> list[tuple[int, DeviceInfo, DeviceBinding, bool, str]]:
        """(node, device, binding, present, device type) for every device a node holds."""
        with self._lock:
            return [
                (nid, a.info, a.binding, a.present, a.device_type)
                for nid, node in sorted(self._nodes.items())
                for a in node.attached
            ]

    def present_sources(self) -> list[tuple[int, str, SnapshotSource]]:
        """(node, binding name, reader) of every present device, by node, then in the order
        they joined it (feedback: whose outputs a node's downlink drives, in order)."""
        with self._lock:
            return [
                (nid, a.binding.name, a.source)
                for nid, node in sorted(self._nodes.items())
                for a in node.attached
                if a.present
            ]

    def node_ids(self) -> list[int]:
        with self._lock:
            return sorted(self._nodes)

    def describe(self) -> dict[str, Any]:
        with self._lock:
            return {
                str(nid): {
                    "failsafe": node.failsafe,
                    "devices": [
                        {"product": a.info.product, "present": a.present, "live": a.live}
                        for a in node.attached
                    ],
                    "expected": sorted(node.expected),
                    "waiting_for": [text for _, text in node.reasons()] if node.failsafe else [],
                    "trims": {
                        AXIS_NAMES[slot]: value
                        for slot, value in sorted(self._trims.of_node(nid).items())
                    },
                }
                for nid, node in sorted(self._nodes.items())
            }

    def set_controls(self, switches: Sequence[SwitchConfig], cuts: Sequence[ThrottleCut]) -> None:
        """The config's switches and throttle cuts (at start and on a reload): positions
        are kept by switch name (usb2rc.nodes.switches)."""
        with self._lock:
            self._switches.configure(switches, cuts)
            self._layout += 1

    def rebind(self, rebind_one: Any, expected: Expected) -> None:
        """After a config reload: give every attached device its new binding (same node)."""
        with self._lock:
            self._layout += 1
            for node in self._nodes.values():
                for attached in node.attached:
                    new_binding = rebind_one(attached.info)
                    if new_binding is not None:
                        _rebind_attached(node.node_id, attached, new_binding, self._clock())
                switches = [t for a in node.attached for t in a.binding.trim_switches]
                for change in self._trims.keep(node.node_id, switches):
                    log.warning("config reload: node %d: %s", node.node_id, change)
                node.expected = {
                    name: entry
                    for name, entry in expected.get(node.node_id, {}).items()
                    if not any(a.binding.name == name for a in node.attached)
                }
            for node_id, entries in expected.items():
                if node_id not in self._nodes:
                    self._nodes[node_id] = _Node(node_id, expected=dict(entries))

    def _broadcast(self, event: ServiceEvent) -> None:
        """Append `event` to the log the next step publishes (the layout changed: a step is
        due even within this period); each line session reads it with its own cursor."""
        present = tuple(
            _connected(node_id, attached)
            for node_id in sorted(self._nodes)
            for attached in self._nodes[node_id].attached
            if attached.present
        )
        self._log = self._log.appended(event, present)
        self._layout += 1


def _same(before: tuple[ReaderRecord, ...], now: tuple[ReaderRecord, ...]) -> bool:
    """The same reader records, one by one (each a new object when a reader publishes)."""
    return len(before) == len(now) and all(map(operator.is_, before, now))


def _rebind_attached(node_id: int, attached: _Attached, binding: DeviceBinding, now: float) -> None:
    """A reload's new binding for a device that stays on its node (docs/ICD.md "A reload
    and the live devices"): an armed device stays armed while its axes map as before; one
    whose axis mapping changed is a new stick to the receiver (inverted, another usage, a
    new calibration: a deflected stick would step), so it holds what it sent and waits for
    its guarded axes to rest, as a re-plugged device. At rest, that is the next frame."""
    if attached.present and not binding.same_axes(attached.binding):
        attached.last_inputs = attached.last_step(now)  # what it sent under the old mapping
        attached.disarm()
        log.warning(
            "config reload: node %d: %s's axes map differently now: the neutral guard "
            "checks it again (%s) before it goes live",
            node_id,
            attached.info.product or "device",
            binding.guard.describe(),
        )
    if button_mapping_changed(attached.binding, binding):
        attached.gate.close(SINCE_RELOAD)  # a held button must be released first
    attached.binding = binding


def _log_changes(changes: list[str]) -> None:
    for change in changes:
        level = logging.INFO if "leaves failsafe" in change else logging.WARNING
        log.log(level, "%s", change)


def _connected(node_id: int, attached: _Attached) -> ServiceEvent:
    return ServiceEvent(EventKind.CONNECTED, node_id, attached.info, attached.device_type)


def _resting(node: _Node, now: float) -> list[RestWatch]:
    """The node's waiting devices' rests not long enough at `now`: a step of the node is due
    once one is, even inside a period that had its step (a rest long enough by now was seen
    by this step)."""
    return [
        a.rest
        for a in node.attached
        if not a.armed and a.rest.since is not None and not a.rest.rested_by(now)
    ]
