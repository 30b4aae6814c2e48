"""What a receiver sees on a C2-16B line: the decoded frames folded into per-node state.

Used by `usb2rc demo` (the far end of its pseudo-terminal) and by tests; sans-IO: feed bytes,
read the model.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

from usb2rc.protocols.c2_16b import codec as c2_16b


@dataclass
class NodeView:
    node_id: int
    status: str = "?"
    code: int = 0
    axes: tuple[int, ...] = (0,) * 10
    group1: int = 0
    group2: int = 0
    frames: int = 0
    code_gaps: int = 0
    coded: bool = False  # a frame with a message code came (`&` frames carry none)
    handover_to: int | None = None  # the destination of the last `&` frame
    product: str = ""
    device_type: str = ""
    vid_pid: str = ""
    last_seen: float = 0.0

    def pressed_buttons(self) -> list[int]:
        """Node button numbers 1..56 that are on (hat bits 25..32 of group 1 excluded)."""
        pressed = [n + 1 for n in range(24) if self.group1 >> n & 1]
        pressed += [25 + n for n in range(32) if self.group2 >> n & 1]
        return pressed

    def hat(self) -> str:
        names = ("UP", "UP-RIGHT", "RIGHT", "DOWN-RIGHT", "DOWN", "DOWN-LEFT", "LEFT", "UP-LEFT")
        on = [names[n] for n in range(8) if self.group1 >> (24 + n) & 1]
        return ",".join(on) or "centre"


@dataclass
class ReceiverModel:
    nodes: dict[int, NodeView] = field(default_factory=dict)
    events: deque[str] = field(default_factory=lambda: deque(maxlen=12))
    decoder: c2_16b.Decoder = field(default_factory=c2_16b.Decoder)
    startups: int = 0
    event_total: int = 0  # events ever logged (the deque keeps the last few)

    def feed(self, data: bytes) -> list[c2_16b.DataFrame | c2_16b.ServiceFrame]:
        frames = self.decoder.feed(data)
        now = time.monotonic()
        for frame in frames:
            if isinstance(frame, c2_16b.DataFrame):
                self._data(frame, now)
            else:
                self._service(frame)
        return frames

    def _node(self, node_id: int) -> NodeView:
        return self.nodes.setdefault(node_id, NodeView(node_id))

    def _data(self, frame: c2_16b.DataFrame, now: float) -> None:
        node = self._node(frame.node_id)
        if frame.status == c2_16b.HANDOVER:
            # byte 4 is the destination, not a code: the code count goes on after the `&`s
            # (docs/ICD.md, "Handover")
            node.handover_to = frame.code
        else:
            if node.coded and frame.code != (node.code + 1) & 0xFF:
                node.code_gaps += 1
            node.code, node.coded = frame.code, True
        node.status = chr(frame.status)
        node.axes = tuple(frame.axes)
        node.group1, node.group2 = frame.group1, frame.group2
        node.frames += 1
        node.last_seen = now

    def _service(self, frame: c2_16b.ServiceFrame) -> None:
        name = frame.service.service_name
        if frame.service == c2_16b.Service.STARTUP:
            self.startups += 1
            self._log(f"startup: {frame.text}")
            return
        node = self._node(frame.node_id)
        detail = ""
        if frame.service == c2_16b.Service.VID_PID:
            node.vid_pid = f"{frame.vid:04x}:{frame.pid:04x}"
            detail = node.vid_pid
        elif frame.service == c2_16b.Service.DEVICE_STRING:
            node.product = frame.text or ""
            detail = node.product
        elif frame.service == c2_16b.Service.DEVICE_TYPE:
            node.device_type = frame.text or ""
            detail = node.device_type
        elif frame.service == c2_16b.Service.ERROR:
            detail = f"error code {frame.error_code}"
        if frame.code:  # a service code (byte 4): usb2rc sends none, others may
            detail = f"{detail} (service code {frame.code})".lstrip()
        self._log(f"node {frame.node_id}: {name} {detail}".rstrip())

    def _log(self, event: str) -> None:
        self.events.append(event)
        self.event_total += 1

    def events_since(self, seen: int) -> list[str]:
        """The events logged after the first `seen` ones (as many as are still kept)."""
        new = self.event_total - seen
        return list(self.events)[-new:] if new > 0 else []
