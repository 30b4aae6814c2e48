"""The C2-16B line session on the one interface: `C2Session`, around its engine
(`c2_16b.engine.C2Engine`: the startup frame, the service frames owed, codes, round-robin,
announcements), fed from the node snapshot and the far end's bytes.

- Service events come from the snapshot's append-only event log (`nodes.table.EventLog`): the
  session keeps its own cursor, so reading the table changes nothing. A cursor the log has
  dropped (the line fell more than `nodes.table.EVENTS_KEPT` events behind) starts the line over
  as a reopened line does: the startup frame, then every present device's connect sequence.
- A line that opens announces the devices present in the snapshot (`EventLog.present`); on
  the first line the events logged before it go out first (an unusable device's `3`).
- What the far end sends is decoded here: `<` and `4` requests, at most REQUESTS_PER_TICK
  a tick (the engine coalesces them anyway); nothing else is answered.
- Its `>` data frames are the downlink (`c2_16b.downlink`): the newest per Node-ID is the
  session's `telemetry`, counted, and never handed to the engine, so they change nothing
  that goes up and take nothing from the requests' limit. Other statuses are ignored.
"""

from __future__ import annotations

from typing import Any

from usb2rc.feedback.model import Downlink
from usb2rc.lines.session import Backpressure, Delivered, EngineSession
from usb2rc.nodes.table import NodeSnapshot, ServiceEvent
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.downlink import Downlinks, OwnFrames, is_downlink
from usb2rc.protocols.c2_16b.engine import C2Engine, C2Settings

REQUESTS_PER_TICK = 512  # 2 per Node-ID: more in one tick only repeat what is asked


def is_request(frame: c2_16b.Frame) -> bool:
    """A `<` config request or a `4` poll request: what the far end may ask.

    Byte 4 does not matter (docs/ICD.md, "UART receive"): a `<`'s is the far end's message
    code, a `4`'s a service code, which the ICD leaves TBD; a poll that carries one is still
    a poll, and answering it costs at most one connect sequence (never queued twice)."""
    if isinstance(frame, c2_16b.DataFrame):
        return frame.status == c2_16b.CONFIG_REQUEST
    return frame.service is c2_16b.Service.POLL


class C2Session(EngineSession[C2Engine]):
    """A C2-16B output's session: its engine fed the snapshot's events and node frames, and
    the far end's requests."""

    # the far end times its frames: one every period, on the grid (docs/ICD.md, "Timing and
    # bandwidth")
    on_deadline = True

    def __init__(self, name: str, settings: C2Settings) -> None:
        engine = C2Engine(settings, name=name)
        tick_bytes = engine.capacity * engine.frame_len
        # its frames carry state: on a pty it waits for the drain, then drops the rest
        backpressure = Backpressure(tick_bytes, drops_unread_each_tick=False)
        super().__init__(name, engine, backpressure, 1.0 / settings.rate_hz)
        self.decoder = c2_16b.Decoder()
        self.downlinks = Downlinks()
        self.own_frames = OwnFrames()  # what it sent lately: an echo of it is no downlink
        self.echoes = 0  # `>` frames that were its own, come back
        self.requests = 0
        self.requests_dropped = 0
        self.data_frames = 0  # frames that went out whole (counted once)
        self.service_frames = 0
        self.log_gaps = 0  # times the event log had dropped what this line had not seen
        self._cursor = 0  # the next event number this line has not seen
        self._announce_present = False  # a line opened: announce the devices present
        self._lines_opened = 0
        self._requests_this_tick = 0

    def line_opened(self) -> None:
        self.engine.line_opened()
        self._announce_present = True

    def received(self, data: bytes, now: float) -> None:
        downlinks = self.downlinks
        for frame in self.decoder.feed(data):
            if is_downlink(frame):
                if self.own_frames.is_echo(frame):
                    self.echoes += 1
                else:
                    downlinks.take(frame)
                continue
            if not is_request(frame):
                continue
            self.requests += 1
            if self._requests_this_tick >= REQUESTS_PER_TICK:
                self.requests_dropped += 1
                continue
            self._requests_this_tick += 1
            self.engine.received(frame)
        downlinks.publish(now)

    @property
    def telemetry(self) -> tuple[Downlink, ...] | None:
        """The newest downlink of each Node-ID heard, sorted by Node-ID; None before any."""
        return self.downlinks.latest

    def tick(self, now: float, snapshot: NodeSnapshot) -> bytes:
        self._requests_this_tick = 0
        events = self._events(snapshot)
        out = self.engine.tick(events, self.latch.frames(snapshot))
        if out and not self.backpressure.room(len(out)):
            self.engine.wrote(0)  # nothing went: service frames stay owed, codes unused
            return b""
        self.own_frames.sent(out)
        return out

    def asleep(self, snapshot: NodeSnapshot) -> bool:
        """No node, no event it has not seen, no frame owed, no request waiting, an open
        line that takes bytes: its ticks would send nothing (docs/ICD.md "Timing and
        bandwidth": with no device there is no data frame to send)."""
        engine = self.engine
        return (
            not snapshot.nodes
            and snapshot.log.end == self._cursor
            and not self._announce_present
            and engine.owed_frames == 0
            and engine.pending_requests == 0
            and self.line.is_open
            and not self.line.stalled
        )

    def _events(self, snapshot: NodeSnapshot) -> tuple[ServiceEvent, ...]:
        log = snapshot.log
        fresh = log.since(self._cursor)
        self._cursor = log.end
        if fresh is None:
            self.log_gaps += 1
            fresh = ()
            if self.line.is_open:
                self.engine.line_opened()  # the receiver learns the whole picture again
                self._announce_present = True
        if not self._announce_present:
            return fresh
        self._announce_present = False
        self._lines_opened += 1
        if self._lines_opened > 1:
            fresh = ()  # what was logged for the dead line is superseded by what is present
        return (*fresh, *log.present)

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        delivered = self.engine.wrote(sent, unsure)
        self.data_frames += delivered.data_frames
        self.service_frames += delivered.service_frames
        return delivered

    def stats(self, now: float) -> dict[str, Any]:
        statuses = self.engine.statuses
        return {
            **super().stats(now),
            "data_frames": self.data_frames,
            "service_frames": self.service_frames,
            "round_robin_deferrals": self.engine.deferred_nodes,
            "handover_frames": statuses.handover_frames,
            "handovers_cut": statuses.handovers_cut,
            "low_battery_frames": statuses.low_battery_frames,
            "rx_skipped": self.decoder.bytes_skipped,
            "rx_crc_failures": self.decoder.crc_failures,
            "rx_requests": self.requests,
            "rx_requests_dropped": self.requests_dropped,
            "rx_downlink_frames": self.downlinks.frames,
            "rx_echo_frames": self.echoes,
            "event_log_gaps": self.log_gaps,
        }
