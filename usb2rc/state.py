"""Node state: the one lock-guarded place where devices (hot-plug and reader threads) meet
the outputs (scheduler threads).

Devices are attached to Node-IDs; each output subscribes and gets, per tick and under one
lock, the service events queued for it and the current frame of every node. Readers never
take this lock: each publishes one immutable `ReaderRecord` by a single assignment, and the
table reads it once per device when a frame is built. Devices are added and removed only by
the lifecycle thread (usb2rc.lifecycle); a device is removed by its reader, not by a path
that the kernel may already have given to another device.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

from usb2rc.binding import DeviceBinding, NodeInputs
from usb2rc.config_model import HandoverConfig
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.reader import ReaderRecord
from usb2rc.protocol.c2_16b import AXIS_COUNT

log = logging.getLogger("usb2rc.nodes")


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
class NodeFrame:
    node_id: int
    failsafe: bool
    axes: tuple[int, ...]
    group1: int
    group2: int
    unsigned_slots: int = 0  # bit k set: axis slot k is a uint16 (binding.unsigned_slots)
    # the status a live node asks for (the session decides: docs/ICD.md, "Status priority")
    handover: HandoverConfig | None = None  # a handover button is down: `&`, and where to
    low_battery: bool = False  # a device's battery is low: `%`


@dataclass(frozen=True)
class ExpectedEntry:
    """A config entry pinned to a node whose device has not come (yet)."""

    inputs: NodeInputs  # what it sends meanwhile: its failsafe values
    unsigned_slots: int = 0  # the entry's (mapping.CompiledEntry.unsigned_slots)


class SnapshotSource(Protocol):
    """A DeviceReader, as the table sees it: its last published record, read once."""

    @property
    def record(self) -> ReaderRecord: ...


@dataclass
class _Attached:
    """One device feeding a node; kept (not present) after an unplug, for failsafe."""

    info: DeviceInfo
    binding: DeviceBinding
    source: SnapshotSource
    device_type: str
    present: bool = True
    last_inputs: NodeInputs | None = None  # held values (from before an unplug / re-plug)

    @property
    def live(self) -> bool:
        """Present and its state known: at least one report decoded since it was plugged.

        Decision: until then the node stays in failsafe with the held (or failsafe) values;
        a re-plugged throttle must not jump to mid-scale before it has said where it is."""
        return self._live(self.source.record)

    def _live(self, record: ReaderRecord) -> bool:
        return self.present and record.reports > 0

    def inputs(self) -> NodeInputs:
        record = self.source.record  # read once: liveness and values from the same record
        if self._live(record):
            return self.binding.apply(record.state)
        return self.binding.failsafe(self.last_inputs)

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
    logged_failsafe: bool | None = None  # the state last logged, to log transitions once

    @property
    def failsafe(self) -> bool:
        """`!` unless every device feeding the node is present and known. A node nothing
        feeds any more (a reload removed its entry) is failsafe too, never `>` on nothing."""
        if not self.attached and not self.expected:
            return True
        return bool(self.expected) or not all(a.live for a in self.attached)

    def frame(self) -> NodeFrame:
        axes = [0] * AXIS_COUNT
        group1 = group2 = unsigned = 0
        handover: HandoverConfig | None = None
        low_battery = False
        for entry in self.expected.values():
            _merge_axes(axes, entry.inputs)
            unsigned |= entry.unsigned_slots
        for attached in self.attached:
            inputs = attached.inputs()
            _merge_axes(axes, inputs)
            group1 |= inputs.group1
            group2 |= inputs.group2
            unsigned |= attached.binding.unsigned_slots  # computed once, with the binding
            if inputs.handover:  # one handover button per node (config_status)
                handover = attached.binding.handover
            low_battery = low_battery or inputs.low_battery
        return NodeFrame(
            self.node_id,
            self.failsafe,
            tuple(axes),
            group1,
            group2,
            unsigned,
            handover,
            low_battery,
        )

    def failsafe_change(self) -> str | None:
        """A log line when the node entered or left failsafe since the last call."""
        now = self.failsafe
        before, self.logged_failsafe = self.logged_failsafe, now
        if before is None or before == now:
            return None
        if now:
            why = [a.info.product or "device" for a in self.attached if not a.live]
            why += [f"{name} (not plugged)" for name in self.expected]
            return f"node {self.node_id} enters failsafe: waiting for {', '.join(why) or '-'}"
        return f"node {self.node_id} leaves failsafe: all its devices are live"


def _merge_axes(axes: list[int], inputs: NodeInputs) -> None:
    for slot, value in enumerate(inputs.axes):
        if value is not None:
            axes[slot] = value


Expected = dict[int, dict[str, ExpectedEntry]]


class NodeTable:
    """Node-IDs, the devices feeding them, and the service events each output still owes."""

    def __init__(self, expected: Expected | None = None) -> None:
        self._lock = threading.Lock()
        self._nodes: dict[int, _Node] = {}
        self._by_key: dict[str, tuple[int, _Attached]] = {}
        self._outbox: list[list[ServiceEvent]] = []
        for node_id, entries in (expected or {}).items():
            self._nodes[node_id] = _Node(node_id, expected=dict(entries))

    # --- outputs -------------------------------------------------------------------------

    def subscribe(self) -> int:
        with self._lock:
            self._outbox.append([])
            return len(self._outbox) - 1

    def collect(self, subscriber: int) -> tuple[list[ServiceEvent], list[NodeFrame]]:
        """The events owed to this output and every node's frame, taken together."""
        with self._lock:
            events = self._outbox[subscriber]
            self._outbox[subscriber] = []
            frames, changes = self._frames_locked()
        _log_changes(changes)
        return events, frames

    def frames(self) -> list[NodeFrame]:
        with self._lock:
            frames, changes = self._frames_locked()
        _log_changes(changes)
        return frames

    def _frames_locked(self) -> tuple[list[NodeFrame], list[str]]:
        frames, changes = [], []
        for node_id in sorted(self._nodes):
            node = self._nodes[node_id]
            frames.append(node.frame())
            change = node.failsafe_change()
            if change:
                changes.append(change)
        return frames, changes

    def request_connect_sequences(self, subscriber: int, node_id: int | None = None) -> int:
        """Answer a `<` (node_id None: every present node) or a `4` poll for one node.

        A connect sequence already owed to this output is not queued twice, so a far end
        that keeps asking cannot fill the line with service frames."""
        with self._lock:
            box = self._outbox[subscriber]
            queued = 0
            for nid in sorted(self._nodes):
                if node_id is not None and nid != node_id:
                    continue
                for attached in self._nodes[nid].attached:
                    event = _connected(nid, attached)
                    if attached.present and event not in box:
                        box.append(event)
                        queued += 1
            if node_id is not None and not any(
                a.present for a in self._nodes.get(node_id, _Node(node_id)).attached
            ):
                box.append(ServiceEvent(EventKind.DISCONNECTED, node_id))
            return queued

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
        log.info(
            "device plugged: %s (%04x:%04x, port %s) -> Node-ID %d",
            info.product or "?",
            info.vid,
            info.pid,
            info.port_path or "?",
            node_id,
        )

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
            node_id, attached = entry
            attached.last_inputs = attached.inputs()
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
                }
                for nid, node in sorted(self._nodes.items())
            }

    def rebind(self, rebind_one: Any, expected: Expected) -> None:
        """After a config reload: give every attached device its new binding (same node)."""
        with self._lock:
            for node in self._nodes.values():
                for attached in node.attached:
                    new_binding = rebind_one(attached.info)
                    if new_binding is not None:
                        attached.binding = new_binding
                node.expected = {
                    name: entry
                    for name, entry in expected.get(node.node_id, {}).items()
                    if not any(a.binding.name == name for a in node.attached)
                }
            for node_id, entries in expected.items():
                if node_id not in self._nodes:
                    self._nodes[node_id] = _Node(node_id, expected=dict(entries))

    def _broadcast(self, event: ServiceEvent) -> None:
        for box in self._outbox:
            box.append(event)


def _log_changes(changes: list[str]) -> None:
    for change in changes:
        level = logging.WARNING if "enters failsafe" in change else logging.INFO
        log.log(level, "%s", change)


def _connected(node_id: int, attached: _Attached) -> ServiceEvent:
    return ServiceEvent(EventKind.CONNECTED, node_id, attached.info, attached.device_type)
