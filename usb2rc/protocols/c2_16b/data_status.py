"""Which status a C2-16B data frame gets: `!`, `&`, `%` or `>` (docs/ICD.md, "Status
priority", "Handover", "Low battery"), sans-IO like the session that owns it.

`C2Engine` asks `choose(frame, live, code)` for each data frame it composes and tells
`sent(node, status)` for each one that went out. In between, `follow(frames)` sees every
tick's node frames, to find the presses of handover buttons: a button down at a tick after
being up at the one before. With `frames: K` a press owes K `&` frames, counted in frames
that went out; a `!` frame ends what is left of them (never sent later, with stale values).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.nodes.table import NodeFrame
from usb2rc.protocols.c2_16b import codec as c2_16b

log = logging.getLogger("usb2rc.session")


@dataclass
class _Burst:
    """A press of a `frames: K` handover button: the `&` frames still owed to the line."""

    destination: int
    left: int


class DataStatuses:
    """The data statuses of one output line, and its counters (for `stats`)."""

    def __init__(self, name: str = "c2-16b") -> None:
        self.name = name  # for log lines: the port
        self.handover_frames = 0  # `&` frames that went out
        self.handovers_cut = 0  # `&` frames a `!` took from a burst (never sent)
        self.low_battery_frames = 0  # `%` frames that went out
        self._pressed: set[int] = set()  # nodes whose handover button was down last tick
        self._bursts: dict[int, _Burst] = {}  # `&` frames owed for a press (`frames: K`)

    def line_reset(self) -> None:
        """A line opened or lost: a press nobody saw is not kept (the pilot presses again)."""
        self._bursts.clear()

    def follow(self, frames: Sequence[NodeFrame]) -> None:
        """Every tick's node frames: a handover button that went down since the last tick is
        a press; with `frames: K` it owes K `&` frames (a press while a burst runs adds none)."""
        pressed = set()
        for frame in frames:
            handover = frame.handover
            if handover is None:
                continue
            pressed.add(frame.node_id)
            if frame.node_id in self._pressed:
                continue
            how = "while held" if handover.frames is None else f"{handover.frames} frames"
            log.info(
                "%s: node %d asks for a handover to %d (%s)",
                self.name,
                frame.node_id,
                handover.destination,
                how,
            )
            if handover.frames is not None and frame.node_id not in self._bursts:
                self._bursts[frame.node_id] = _Burst(handover.destination, handover.frames)
        self._pressed = pressed

    def choose(self, frame: NodeFrame, live: bool, code: int) -> tuple[int, int]:
        """The frame's status and byte 4, by priority: `!` whenever the node is not live and
        announced (its values are not live: a `&` or `%` would present them as valid; a `!`
        ends a handover burst), then `&` (its destination in byte 4), `%`, `>` (the node's
        message code `code` in byte 4)."""
        node = frame.node_id
        if not live:
            self._end_burst(node)
            return c2_16b.FAILSAFE, code
        burst = self._bursts.get(node)
        if burst is not None:
            return c2_16b.HANDOVER, burst.destination
        if frame.handover is not None and frame.handover.frames is None:
            return c2_16b.HANDOVER, frame.handover.destination
        if frame.low_battery:
            return c2_16b.LOW_BATTERY, code
        return c2_16b.LIVE, code

    def sent(self, node: int, status: int) -> bool:
        """A data frame of `node` with `status` went out; True when it used a message code
        (every status but `&`, whose byte 4 is the destination)."""
        if status == c2_16b.LOW_BATTERY:
            self.low_battery_frames += 1
        if status != c2_16b.HANDOVER:
            return True
        self.handover_frames += 1
        burst = self._bursts.get(node)
        if burst is not None:
            burst.left -= 1
            if burst.left <= 0:
                del self._bursts[node]
        return False

    def _end_burst(self, node: int) -> None:
        burst = self._bursts.pop(node, None)
        if burst is None:
            return
        self.handovers_cut += burst.left
        log.warning(
            "%s: node %d: handover to %d cut short by failsafe (%d `&` frames not sent)",
            self.name,
            node,
            burst.destination,
            burst.left,
        )
