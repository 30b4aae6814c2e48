"""When to warn that a pinned config entry has no device (docs/ICD.md, "Node-IDs").

A node whose pinned entry has no device sends `!` from the start, and a receiver sees no
reason for it. So the log says it: FIRST_WARNING_S after the entry was first found missing
(start, or the reload that added it), then every REPEAT_S while it stays missing. An entry
whose device came is forgotten: if it goes missing again (a reload), it starts over.

Not thread-safe and without a clock of its own: the lifecycle thread (usb2rc.nodes.lifecycle),
which owns the devices, asks it after each event and when `next_due()` comes.
"""

from __future__ import annotations

from collections.abc import Iterable

from usb2rc.nodes.table import MissingEntry

# Time for the devices plugged at start, and for hot-plug to report the slower ones, before
# an entry counts as missing; under the 5 s in which a user looks for the reason.
FIRST_WARNING_S = 3.0
REPEAT_S = 60.0  # a missing entry is told again this often, not on every tick

_Key = tuple[int, str]  # node, entry name


class MissingWarnings:
    def __init__(self, first_s: float = FIRST_WARNING_S, repeat_s: float = REPEAT_S) -> None:
        self._first_s = first_s
        self._repeat_s = repeat_s
        self._due: dict[_Key, float] = {}  # when each missing entry is told next

    def due(self, missing: Iterable[MissingEntry], now: float) -> list[MissingEntry]:
        """The entries to warn about now, of those missing now; forgets the others."""
        tell = []
        still: dict[_Key, float] = {}
        for entry in missing:
            key = (entry.node_id, entry.name)
            due = self._due.get(key, now + self._first_s)
            if due <= now:
                tell.append(entry)
                due = now + self._repeat_s
            still[key] = due
        self._due = still
        return tell

    def next_due(self) -> float | None:
        return min(self._due.values(), default=None)
