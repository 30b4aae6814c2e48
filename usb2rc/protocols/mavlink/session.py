"""The MAVLink line session: a heartbeat a second and the control message each tick, as one
write (one datagram on UDP: MAVLink receivers parse the packets of a datagram back to back,
docs/ICD.md "MAVLink output"); the failsafe is what is (not) sent (`outputs.mavlink`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from usb2rc.lines.session import Backpressure, LineBase
from usb2rc.outputs.mavlink import MavlinkChannels, MavlinkSession, stats_record
from usb2rc.session import Delivered
from usb2rc.state import NodeSnapshot


class MavlinkLine(LineBase):
    engine: MavlinkSession

    def __init__(
        self,
        name: str,
        channels: MavlinkChannels,
        engine: MavlinkSession,
        tick_bytes: int,
        rate_hz: float,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(name, engine, Backpressure(tick_bytes), 1.0 / rate_hz)
        self.channels = channels
        self.tick_bytes = tick_bytes
        self.wall_clock = wall_clock  # signing timestamps follow the wall clock
        self._lengths: list[int] = []  # the last tick's messages, in order

    def tick(self, now: float, snapshot: NodeSnapshot) -> bytes:
        self._lengths = []
        if not self.can_add(self.tick_bytes):
            return b""
        values = self.channels.evaluate(self.latch.frames(snapshot))
        messages = self.engine.tick(now, values, self.wall_clock())
        self._lengths = [len(m) for m in messages]
        return b"".join(messages)

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        """The engine hears of each message in turn: whole, or the one cut short (a stall:
        the rest of the tick is not sent)."""
        lengths, self._lengths = self._lengths, []
        data = 0
        stalled = False
        for length in lengths:
            delivered = self.engine.wrote(min(length, max(0, sent)))
            sent -= length
            data += delivered.data_frames
            if delivered.stalled or not self.engine.line_open:
                stalled = delivered.stalled
                break
        return Delivered(0, data, stalled)

    def received(self, data: bytes, now: float) -> None:
        self.engine.received(data)

    def stats(self, now: float) -> dict[str, Any]:
        return {**super().stats(now), **stats_record(self.engine)}
