"""What a line session keeps of the node table, for tests that read it as an output would:
its own cursor in the service event log and its own tap latch (reading changes nothing)."""

from __future__ import annotations

from usb2rc.nodes.step import NodeFrame, TapLatch
from usb2rc.nodes.table import NodeTable, ServiceEvent


class TableReader:
    def __init__(self, table: NodeTable) -> None:
        self.table = table
        self.cursor = table.snapshot().log.end  # from now on, as a new output
        self.latch = TapLatch()

    def collect(self) -> tuple[list[ServiceEvent], list[NodeFrame]]:
        """The events logged since the last call, and every node's frame with the taps."""
        snapshot = self.table.step_if_due()
        events = snapshot.log.since(self.cursor)
        assert events is not None, "the reader fell behind the event log's bound"
        self.cursor = snapshot.log.end
        return list(events), self.latch.frames(snapshot)

    def frames(self) -> list[NodeFrame]:
        return self.latch.frames(self.table.step_if_due())
