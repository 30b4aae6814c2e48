"""Node state: the one lock-guarded place where devices (hot-plug and reader threads) meet
the outputs (scheduler threads).

Devices are attached to Node-IDs; each output subscribes and gets, per tick and under one
lock, the service events queued for it and the current frame of every node. Readers never
take this lock: they publish their `snapshot` by swapping one attribute, and the table reads
it when a frame is built.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import InputState
from usb2rc.mapping import DeviceBinding, NodeInputs

log = logging.getLogger("usb2rc.nodes")

AXIS_COUNT = 10


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


class SnapshotSource(Protocol):
    snapshot: InputState


@dataclass
class _Attached:
    """One device feeding a node; kept (not present) after an unplug, for failsafe."""

    info: DeviceInfo
    binding: DeviceBinding
    source: SnapshotSource
    device_type: str
    present: bool = True
    last_inputs: NodeInputs | None = None

    def inputs(self) -> NodeInputs:
        if self.present:
            return self.binding.apply(self.source.snapshot)
        assert self.last_inputs is not None
        return self.binding.failsafe(self.last_inputs)

    def same_device(self, info: DeviceInfo, binding: DeviceBinding) -> bool:
        return (
            self.info.port_path == info.port_path
            or self.info.identity == info.identity
            or (binding.node_id is not None and self.binding.name == binding.name)
        )


@dataclass
class _Node:
    node_id: int
    attached: list[_Attached] = field(default_factory=list)
    # config entries pinned here whose device has not come yet: name -> failsafe inputs
    expected: dict[str, NodeInputs] = field(default_factory=dict)

    @property
    def failsafe(self) -> bool:
        return bool(self.expected) or any(not a.present for a in self.attached)

    def frame(self) -> NodeFrame:
        axes = [0] * AXIS_COUNT
        group1 = group2 = 0
        for inputs in self.expected.values():
            _merge_axes(axes, inputs)
        for attached in self.attached:
            inputs = attached.inputs()
            _merge_axes(axes, inputs)
            group1 |= inputs.group1
            group2 |= inputs.group2
        return NodeFrame(self.node_id, self.failsafe, tuple(axes), group1, group2)


def _merge_axes(axes: list[int], inputs: NodeInputs) -> None:
    for slot, value in enumerate(inputs.axes):
        if value is not None:
            axes[slot] = value


class NodeTable:
    """Node-IDs, the devices feeding them, and the service events each output still owes."""

    def __init__(self, expected: dict[int, dict[str, NodeInputs]] | None = None) -> None:
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
            frames = [self._nodes[n].frame() for n in sorted(self._nodes)]
        return events, frames

    def frames(self) -> list[NodeFrame]:
        with self._lock:
            return [self._nodes[n].frame() for n in sorted(self._nodes)]

    def request_connect_sequences(self, subscriber: int, node_id: int | None = None) -> int:
        """Answer a `<` (node_id None: every present node) or a `4` poll for one node."""
        with self._lock:
            queued = 0
            for nid in sorted(self._nodes):
                if node_id is not None and nid != node_id:
                    continue
                for attached in self._nodes[nid].attached:
                    if attached.present:
                        self._outbox[subscriber].append(_connected(nid, attached))
                        queued += 1
            if node_id is not None and queued == 0:
                self._outbox[subscriber].append(ServiceEvent(EventKind.DISCONNECTED, node_id))
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
            was_failsafe = node.failsafe and bool(node.attached or node.expected)
            node.attached = [a for a in node.attached if not _replaced_by(a, info, binding)]
            node.expected.pop(binding.name, None)
            node.attached.append(attached)
            self._by_key[info.key] = (node_id, attached)
            self._broadcast(_connected(node_id, attached))
            now_failsafe = node.failsafe
        log.info(
            "device plugged: %s (%04x:%04x, port %s) -> Node-ID %d",
            info.product or "?",
            info.vid,
            info.pid,
            info.port_path or "?",
            node_id,
        )
        if was_failsafe and not now_failsafe:
            log.warning("node %d leaves failsafe: all its devices are back", node_id)

    def remove_device(self, key: str, error_code: int | None = None) -> int | None:
        """The device is gone (unplugged, or failed to read: error_code)."""
        with self._lock:
            entry = self._by_key.pop(key, None)
            if entry is None:
                return None
            node_id, attached = entry
            node = self._nodes[node_id]
            was_failsafe = node.failsafe
            attached.last_inputs = attached.binding.apply(attached.source.snapshot)
            attached.present = False
            if error_code:
                self._broadcast(
                    ServiceEvent(EventKind.ERROR, node_id, attached.info, "", error_code)
                )
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
        if not was_failsafe:
            log.warning("node %d enters failsafe: %s %s", node_id, info.product or "device", how)
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

    def lost_node_of(self, info: DeviceInfo, binding: DeviceBinding) -> int | None:
        """The node a re-plugged device fed before it was lost (same port, serial or entry)."""
        with self._lock:
            for node_id in sorted(self._nodes):
                for attached in self._nodes[node_id].attached:
                    if _replaced_by(attached, info, binding):
                        return node_id
        return None

    def present_devices(self) -> list[tuple[int, DeviceInfo]]:
        with self._lock:
            return [(nid, a.info) for _key, (nid, a) in sorted(self._by_key.items())]

    def node_ids(self) -> list[int]:
        with self._lock:
            return sorted(self._nodes)

    def describe(self) -> dict[str, Any]:
        with self._lock:
            return {
                str(nid): {
                    "failsafe": node.failsafe,
                    "devices": [
                        {"product": a.info.product, "present": a.present} for a in node.attached
                    ],
                    "expected": sorted(node.expected),
                }
                for nid, node in sorted(self._nodes.items())
            }

    def rebind(self, rebind_one: Any, expected: dict[int, dict[str, NodeInputs]]) -> None:
        """After a config reload: give every attached device its new binding (same node)."""
        with self._lock:
            for node in self._nodes.values():
                for attached in node.attached:
                    new_binding = rebind_one(attached.info)
                    if new_binding is not None:
                        attached.binding = new_binding
                node.expected = {
                    name: inputs
                    for name, inputs in expected.get(node.node_id, {}).items()
                    if not any(a.binding.name == name for a in node.attached)
                }
            for node_id, entries in expected.items():
                if node_id not in self._nodes:
                    self._nodes[node_id] = _Node(node_id, expected=dict(entries))

    def _broadcast(self, event: ServiceEvent) -> None:
        for box in self._outbox:
            box.append(event)


def _connected(node_id: int, attached: _Attached) -> ServiceEvent:
    return ServiceEvent(EventKind.CONNECTED, node_id, attached.info, attached.device_type)


def _replaced_by(old: _Attached, info: DeviceInfo, binding: DeviceBinding) -> bool:
    return not old.present and old.same_device(info, binding)
