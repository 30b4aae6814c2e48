"""Node-ID allocation (docs/ICD.md, "Node-IDs").

- A device whose config entry pins `node_id:` gets that ID; pinned IDs are reserved from the
  start, so automatic IDs never take them (several devices may share one pinned ID).
- Other devices get the lowest free ID from 0 upwards (0xFF is the startup node, so 0..254).
  Call `assign` in USB port-path order for the devices present at start, in plug order after.
- A re-plugged device gets its previous ID back when that ID is free: the same vid:pid:serial
  (when the device has a serial) or else the same USB port path.
"""

from __future__ import annotations

from collections.abc import Iterable

from usb2rc.config.layout import MAX_NODE_ID
from usb2rc.hid.backend import DeviceInfo


class NodeIdError(ValueError):
    """No free Node-ID, or a pinned ID out of range."""


def _check_range(node_id: int) -> int:
    if not 0 <= node_id <= MAX_NODE_ID:
        raise NodeIdError(f"node_id {node_id} is out of range 0..{MAX_NODE_ID}")
    return node_id


class NodeIdAllocator:
    """Not thread-safe: only the lifecycle thread (usb2rc.nodes.lifecycle) calls it."""

    def __init__(self, pinned: Iterable[int] = ()) -> None:
        self._pinned = {_check_range(n) for n in pinned}
        self._assigned: dict[str, int] = {}  # DeviceInfo.key -> id, while plugged
        self._by_port: dict[str, int] = {}  # port path -> last automatic id
        self._by_identity: dict[str, int] = {}  # vid:pid:serial -> last automatic id

    def _in_use(self, taken: Iterable[int] = ()) -> set[int]:
        return set(self._assigned.values()) | self._pinned | set(taken)

    def _remembered(self, info: DeviceInfo, in_use: set[int]) -> int | None:
        candidates = []
        if info.serial:
            candidates.append(self._by_identity.get(info.identity))
        if info.port_path:
            candidates.append(self._by_port.get(info.port_path))
        return next((n for n in candidates if n is not None and n not in in_use), None)

    def _lowest_free(self, in_use: set[int]) -> int:
        free = next((n for n in range(MAX_NODE_ID + 1) if n not in in_use), None)
        if free is None:
            raise NodeIdError(f"all Node-IDs 0..{MAX_NODE_ID} are in use")
        return free

    def reserve(self, pinned: Iterable[int]) -> None:
        """Pins of a reloaded config: automatic IDs never take them from now on."""
        self._pinned |= {_check_range(n) for n in pinned}

    def assign(self, info: DeviceInfo, pinned: int | None = None, taken: Iterable[int] = ()) -> int:
        """The device's Node-ID; the same while it stays plugged. `taken`: IDs the caller
        knows to be busy besides those assigned here (nodes still in failsafe for a lost
        device keep their ID; no other device may take it)."""
        if info.key in self._assigned:
            return self._assigned[info.key]
        if pinned is not None:
            node_id = _check_range(pinned)
            self._pinned.add(node_id)  # a pin not announced up front is reserved from now on
        else:
            in_use = self._in_use(taken)
            remembered = self._remembered(info, in_use)
            node_id = self._lowest_free(in_use) if remembered is None else remembered
            if info.serial:
                self._by_identity[info.identity] = node_id
            if info.port_path:
                self._by_port[info.port_path] = node_id
        self._assigned[info.key] = node_id
        return node_id

    def release(self, info: DeviceInfo) -> None:
        """The device is gone; its ID is free again but remembered for a re-plug."""
        self._assigned.pop(info.key, None)
