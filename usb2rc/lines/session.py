"""The one line-session interface every output protocol implements, sans-IO (h11's
`Connection`), and what the sessions share.

A line session is everything one output knows about its line, and nothing about threads,
ports or clocks (time is passed in). The driver (one generic loop, whatever the protocol)
only moves events and bytes:

    line_opened() / line_lost()           the link adopted a new port / lost it
    link_state(state) -> Ask              what the link reports now (bytes it holds, or
                                          unknown; whether it can drop them; whether it
                                          takes bytes): the session decides the
                                          back-pressure and asks the driver to act on it
    flush_done(flushed)                   the driver carried out Ask.FLUSH (True: the link
                                          dropped what it held)
    received(data, now)                   bytes from the far end (each session owns its
                                          stream decoder)
    tick(now, snapshot) -> bytes          one tick: the session evaluates its own channels
                                          from the node snapshot (its own tap latch, its own
                                          event cursor: reading the snapshot changes nothing)
    wrote(sent, unsure)                   how much of the tick's bytes went out
    stopping() / stop_done                usb2rc stops: the protocol's failsafe, then done
    next_due(due, now)                    when the tick after the one due at `due` is due
    period(now)                           the period now (a CRSF module may set it)
    stats(now) -> dict                    what only this protocol counts (stats record)
    telemetry                             what the far end said last, one immutable value
                                          (`usb2rc.feedback.model.Telemetry`; None: nothing)

The line's state is one `LineState` per session (h11's `_state.py`): closed, open, stalled or
flushing, and whether usb2rc is stopping; only its events change it, and the session and its
protocol's engine read the same one.

Back-pressure is decided here, by `Backpressure`, once for every protocol (docs/ICD.md,
"A stalled line"): no tick adds bytes while the line is stalled; a serial port's queue is
dropped when a stall begins; a channel output on a pty drops what the far end left unread
before each tick; a C2-16B output on a pty waits for the drain, then drops the rest; a socket
or UDP is never flushed.

What the far end says back (`telemetry`: C2-16B's downlink frames, a CRSF module's link
statistics and sensors, the MAVLink vehicle's state) is one immutable value that `received`
replaces whole on the driver's thread: the feedback worker reads it from its own thread
without a lock, and never sees one report's figures with another's.

Each protocol has one session class, in its package (`usb2rc.protocols.<name>.session`): a
channel output's (one frame of its channels a tick) is a `ChannelSession`, which says what
its frame is; C2-16B's and MAVLink's are `EngineSession`s around the protocol's own state
machine, its engine (`C2Engine`, `MavlinkEngine`).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from typing import Any, Final, Generic, Protocol, TypeVar

from usb2rc.feedback.model import Telemetry
from usb2rc.nodes.step import LIVENESS_PERIOD_S, NodeFrame, TapLatch, aligned
from usb2rc.nodes.table import NodeSnapshot

QUEUE_TICKS = 2  # at most this many ticks of bytes wait in a queue the link reports
# A channel output whose protocol's failsafe is silence (CRSF, iBus) has nothing to send
# while a channel's node is in failsafe: it ticks on this grid then (the node clock's, where
# the default outputs' ticks fall: their step is shared), not at its own rate, which it
# takes again from the first tick that sends (docs/ICD.md, "CRSF failsafe").
SILENT_TICK_PERIOD_S = LIVENESS_PERIOD_S


class Line(enum.Enum):
    """Where a line is."""

    CLOSED = "closed"  # no port: nothing is sent, nothing is owed
    OPEN = "open"  # ticks add bytes
    STALLED = "stalled"  # a write went out short, or the queue the link reports is full
    FLUSHING = "flushing"  # stalled, and the driver is asked to drop what the link holds


class LineState:
    """One line's state, in one place: where the line is (`now`) and whether usb2rc is
    stopping. Only these events change it; a session and its protocol's engine read it.

        event            from                to
        opened()         any                 OPEN
        lost()           any                 CLOSED
        stall()          OPEN                STALLED
        flushing()       STALLED             FLUSHING
        resumed()        STALLED, FLUSHING   OPEN      (drained, or what it held dropped)
        flush_failed()   FLUSHING            STALLED
        stop()           any                 the same, stopping from now on

    An event from a state the table does not list leaves it as it is: a closed line does not
    stall, an open one has nothing to resume."""

    def __init__(self) -> None:
        self.now = Line.CLOSED
        self.stopping = False

    @property
    def is_open(self) -> bool:
        return self.now is not Line.CLOSED

    @property
    def stalled(self) -> bool:
        """No tick adds bytes: stalled, or flushing."""
        return self.now is Line.STALLED or self.now is Line.FLUSHING

    def opened(self) -> None:
        self.now = Line.OPEN

    def lost(self) -> None:
        self.now = Line.CLOSED

    def stall(self) -> None:
        if self.now is Line.OPEN:
            self.now = Line.STALLED

    def flushing(self) -> None:
        if self.now is Line.STALLED:
            self.now = Line.FLUSHING

    def resumed(self) -> None:
        if self.stalled:
            self.now = Line.OPEN

    def flush_failed(self) -> None:
        if self.now is Line.FLUSHING:
            self.now = Line.STALLED

    def stop(self) -> None:
        self.stopping = True

    def stop_done(self, failsafe_out: bool) -> bool:
        """Stopping, and the protocol's failsafe went out (`failsafe_out`), or the line
        cannot take it: closed, or stalled (a stop never waits for a far end that does not
        read)."""
        return self.stopping and (failsafe_out or self.now is Line.CLOSED or self.stalled)


class LinkState:
    """What a link reports, as the driver read it just now (the link only reports). A plain
    class, made at every tick: compiled, in C (a NamedTuple's `__new__` is Python code)."""

    def __init__(
        self,
        queued: int | None = None,
        flushable: bool = False,
        hides_queue: bool = False,
        writable: bool = True,
    ) -> None:
        self.queued: Final = queued  # bytes it holds for the far end; None: it does not say
        self.flushable: Final = flushable  # it can drop what it holds (a serial port, a pty)
        # it holds bytes it cannot count (a pty): droppable only
        self.hides_queue: Final = hides_queue
        # it takes bytes now (after a stall: the far end reads again)
        self.writable: Final = writable

    def __repr__(self) -> str:
        return (
            f"LinkState(queued={self.queued}, flushable={self.flushable}, "
            f"hides_queue={self.hides_queue}, writable={self.writable})"
        )


class Ask(enum.Enum):
    """What a session asks of the driver after a `link_state`."""

    NOTHING = "nothing"
    FLUSH = "flush"  # drop what the link holds, then `flush_done(flushed)`
    DROP_UNREAD = "drop unread"  # drop what the far end has not read; no event follows


class Backpressure:
    """The stall policy of one line, decided in one place for every protocol.

    `tick_bytes`: the most one tick adds (a queue the link reports may hold QUEUE_TICKS of
    them); `drops_unread_each_tick`: a frame lost to a flush is replaced by the next one (a
    channel output), so on a pty what the far end left unread is dropped before each tick;
    a session whose frames carry state (C2-16B) waits for the drain instead."""

    def __init__(self, tick_bytes: int, drops_unread_each_tick: bool = True) -> None:
        self.cap = QUEUE_TICKS * max(1, tick_bytes)
        self.drops_unread_each_tick = drops_unread_each_tick
        self.held_queue_full = 0  # ticks that added nothing: the reported queue was full
        self.state = LinkState()

    def ask(self, stalled: bool, line_open: bool, state: LinkState) -> Ask:
        """The driver's next act on the link, given the session's own stall state."""
        self.state = state
        if not line_open:
            return Ask.NOTHING
        if stalled:
            if state.flushable and not state.hides_queue:
                return Ask.FLUSH  # a serial port: its queue is as old as the stall
            if self.drained(state):
                return Ask.FLUSH if state.flushable else Ask.NOTHING
            return Ask.NOTHING
        if state.hides_queue and self.drops_unread_each_tick:
            return Ask.DROP_UNREAD
        return Ask.NOTHING

    def drained(self, state: LinkState) -> bool:
        """A stalled line may take bytes again: its queue is back to half the cap, or (a
        queue it does not report) the OS takes bytes again."""
        if state.queued is not None:
            return state.queued <= self.cap // 2
        return state.writable

    def room(self, size: int) -> bool:
        """Whether `size` more bytes keep the reported queue within the cap (a tick that
        would pass it adds nothing: the line stalls, counted in `held_queue_full`)."""
        queued = self.state.queued
        if queued is None or queued + size <= self.cap:
            return True
        self.held_queue_full += 1
        return False


class Delivered:
    """What `wrote()` found went out: frames counted once, as the stats want them (a plain
    class, made at every write: compiled, in C)."""

    def __init__(
        self, service_frames: int = 0, data_frames: int = 0, stalled: bool = False
    ) -> None:
        self.service_frames: Final = service_frames
        self.data_frames: Final = data_frames
        self.stalled: Final = stalled

    def __repr__(self) -> str:
        return (
            f"Delivered(service_frames={self.service_frames}, "
            f"data_frames={self.data_frames}, stalled={self.stalled})"
        )


class LineSession(Protocol):
    """What the driver knows of any output's session (see the module docstring)."""

    name: str
    reads: frozenset[int] | None
    on_deadline: bool

    def makes_ahead(self) -> bool: ...
    @property
    def line_open(self) -> bool: ...
    @property
    def stalled(self) -> bool: ...
    def line_opened(self) -> None: ...
    def line_lost(self) -> None: ...
    def link_state(self, state: LinkState) -> Ask: ...
    def flush_done(self, flushed: bool) -> None: ...
    def received(self, data: bytes, now: float) -> None: ...
    def tick(self, now: float, snapshot: NodeSnapshot) -> bytes: ...
    def asleep(self, snapshot: NodeSnapshot) -> bool: ...
    def wrote(self, sent: int, unsure: int = 0) -> Delivered: ...
    def stopping(self) -> None: ...
    @property
    def stop_done(self) -> bool: ...
    def next_due(self, due: float, now: float) -> float: ...
    def period(self, now: float) -> float: ...
    def stats(self, now: float) -> dict[str, Any]: ...
    @property
    def telemetry(self) -> Telemetry: ...


class SessionBase:
    """What every session shares: its line's state (`line`), the back-pressure decision,
    the period, the tap latch. The line's events move the state; a session whose protocol
    has an engine hands them to it (`EngineSession`).

    `on_deadline`: the far end times this protocol's frames (C2-16B's period, a CRSF
    module's packet timing), so among the ticks due together its are made and written
    first, before the others' work can move them. Other protocols' receivers take a frame
    whenever it comes (SUMD, SBUS, iBus, MAVLink). `makes_ahead()`: its next tick's bytes
    are made a lead before the deadline, beside other outputs, and written on it
    (`lines.driver.Lead`): only where a far end times frames to a fraction of a
    millisecond, and only while it sends."""

    on_deadline = False

    def __init__(
        self, name: str, line: LineState, backpressure: Backpressure, period_s: float
    ) -> None:
        self.name = name
        self.line = line
        self.backpressure = backpressure
        self.period_s = period_s
        self.latch = TapLatch()  # this output's taps: advanced by its own ticks only
        # the Node-IDs its ticks read (None: every node): the driver steps those before a
        # tick (`NodeTable.step_if_due`)
        self.reads: frozenset[int] | None = None

    @property
    def line_open(self) -> bool:
        return self.line.is_open

    @property
    def stalled(self) -> bool:
        return self.line.stalled

    def line_opened(self) -> None:
        self.line.opened()

    def line_lost(self) -> None:
        self.line.lost()

    def line_drained(self) -> None:
        """After a stall, the line takes bytes again."""
        self.line.resumed()

    def line_flushed(self) -> None:
        """After a stall, the line takes bytes again and what the link held was dropped."""
        self.line.resumed()

    def stopping(self) -> None:
        self.line.stop()

    def link_state(self, state: LinkState) -> Ask:
        ask = self.backpressure.ask(self.stalled, self.line_open, state)
        if ask is Ask.FLUSH:
            self.line.flushing()
        elif ask is Ask.NOTHING and self.stalled and self.backpressure.drained(state):
            self.line_drained()  # nothing to drop (a socket, loop://): go on
        return ask

    def flush_done(self, flushed: bool) -> None:
        """After Ask.FLUSH: what the link held is gone (start over), or it could not."""
        if flushed:
            self.line_flushed()
        elif self.backpressure.drained(self.backpressure.state):
            self.line_drained()
        else:
            self.line.flush_failed()

    def can_add(self, size: int) -> bool:
        """Whether a tick may add `size` bytes: an open line, not stalled, with room in the
        queue the link reports; a full queue stalls the line (as a write cut short would)."""
        if not self.line_open or self.stalled:
            return False
        if self.backpressure.room(size):
            return True
        self.line.stall()
        return False

    def received(self, data: bytes, now: float) -> None:
        """A protocol whose far end says nothing it needs ignores what it sends."""

    def asleep(self, snapshot: NodeSnapshot) -> bool:
        """Whether, after a tick from `snapshot`, its ticks would send nothing until the
        nodes change or the far end speaks (the driver then sleeps until one of them
        happens: an idle daemon wakes for nothing). A protocol that sends on a clock of its
        own (failsafe frames, heartbeats) never is."""
        return False

    def next_due(self, due: float, now: float) -> float:
        return due + self.period_s

    def makes_ahead(self) -> bool:
        """Whether its next tick, beside other outputs, is made a lead before its deadline
        (see the class docstring); after a tick, for the next one."""
        return False

    def period(self, now: float) -> float:
        return self.period_s

    def stats(self, now: float) -> dict[str, Any]:
        return {"queue_full_ticks": self.backpressure.held_queue_full}

    @property
    def telemetry(self) -> Telemetry:
        """What the far end said last, replaced whole by `received` (see the module
        docstring); None for a protocol whose far end tells usb2rc nothing it shows (SUMD,
        SBUS, iBus)."""
        return None


class ChannelValues(Protocol):
    """An output's channels: wire values and failsafe from the node frames; `node_ids`:
    the nodes they read (None: any)."""

    node_ids: frozenset[int] | None

    def evaluate(self, frames: Iterable[NodeFrame]) -> tuple[list[int], bool]: ...


class ChannelSession(SessionBase):
    """A channel output's session: one frame of its channels a tick while the line is
    open and not stalled, the values from the snapshot through its own tap latch; the
    protocol says what the frame is (`encode`).

    Such a protocol has no service state, so a stall only stops the frames (the values would
    be stale); a frame cut short fails the receiver's check and is not sent again."""

    def __init__(
        self, name: str, channels: ChannelValues, frame_length: int, period_s: float
    ) -> None:
        super().__init__(name, LineState(), Backpressure(frame_length), period_s)
        self.channels = channels
        self.reads = channels.node_ids
        self.frame_length = frame_length
        self._last_len = 0
        self._stop_sent = False
        # the last tick sent nothing because a channel is in failsafe (the protocol's
        # failsafe is silence): the next one is due on SILENT_TICK_PERIOD_S's grid
        self._silent = False
        # the last frame made, and the wire values and failsafe flag it was made of: a
        # protocol's frame is a function of those alone, so equal ones (nodes in failsafe,
        # sticks at rest) send the same bytes without encoding them again
        self._encoded: tuple[list[int], bool, bytes] | None = None

    def encode(self, values: Sequence[int], failsafe: bool) -> bytes:
        """The protocol's frame of the channels' wire values (b"": nothing this tick)."""
        raise NotImplementedError

    @property
    def stop_done(self) -> bool:
        """Stopping, and a failsafe frame went out whole (or the line cannot take one):
        every frame from the stop on is the protocol's failsafe frame (SUMD 0x81, SBUS the
        failsafe and frame-lost flags; none where the failsafe is silence, as CRSF's)."""
        return self.line.stop_done(self._stop_sent)

    def tick(self, now: float, snapshot: NodeSnapshot) -> bytes:
        # no frame on a closed or stalled line: the channels are not read, so the taps
        # since the last frame stay latched for the next one
        if not self.can_add(self.frame_length):
            return b""
        values, failsafe = self.channels.evaluate(self.latch.frames(snapshot, self.reads))
        return self.frame(values, failsafe)

    def frame(self, values: Sequence[int], failsafe: bool) -> bytes:
        """This tick's frame of these wire values: b"" on a closed or stalled line, the
        failsafe frame while stopping."""
        self._last_len = 0
        self._silent = False
        line = self.line
        if not line.is_open or line.stalled:
            return b""
        frame = self._encoded_frame(values, failsafe or line.stopping)
        if not frame:
            if line.stopping:
                self._stop_sent = True  # its failsafe is silence: nothing more to send
            else:
                self._silent = failsafe
        self._last_len = len(frame)
        return frame

    def _encoded_frame(self, values: Sequence[int], failsafe: bool) -> bytes:
        """`encode`, or the last frame it made when the values and the flag are the same.
        Nothing sent (b"") is never reused: the protocol counts each tick it withholds."""
        last = self._encoded
        if last is not None and last[1] == failsafe and last[0] == values:
            return last[2]
        frame = self.encode(values, failsafe)
        self._encoded = (list(values), failsafe, frame) if frame else None
        return frame

    def next_due(self, due: float, now: float) -> float:
        """The protocol's next frame (`frame_due`); while its failsafe is silence and it
        keeps it, the first tick of SILENT_TICK_PERIOD_S's grid from then."""
        frame_due = self.frame_due(due, now)
        return aligned(frame_due, SILENT_TICK_PERIOD_S) if self._silent else frame_due

    def frame_due(self, due: float, now: float) -> float:
        """When the frame after the one due at `due` is due: every session's next tick (a
        protocol with a pace of its own says otherwise)."""
        return super().next_due(due, now)

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        whole = self._last_len > 0 and sent >= self._last_len
        self._stop_sent = self._stop_sent or (whole and self.line.stopping)
        stalled = self.line.is_open and sent < self._last_len
        if stalled:
            self.line.stall()
        self._last_len = 0
        return Delivered(0, 1 if whole else 0, stalled)


class Engine(Protocol):
    """A protocol's own line state machine (C2-16B's, MAVLink's), as `EngineSession`
    drives it: on each line event it moves the line's state and reacts."""

    line: LineState

    def line_opened(self) -> None: ...
    def line_lost(self) -> None: ...
    def line_drained(self) -> None: ...
    def line_flushed(self) -> None: ...
    def stopping(self) -> None: ...
    @property
    def stop_done(self) -> bool: ...
    def wrote(self, sent: int, unsure: int = 0) -> Delivered: ...


E = TypeVar("E", bound=Engine)


class EngineSession(SessionBase, Generic[E]):
    """A session around its protocol's engine (C2-16B, MAVLink): the line's events go to
    the engine, which moves the line's state (the same `line`) and reacts to them (C2-16B
    starts a flushed line over from its startup frame)."""

    def __init__(self, name: str, engine: E, backpressure: Backpressure, period_s: float):
        super().__init__(name, engine.line, backpressure, period_s)
        self.engine = engine

    def line_opened(self) -> None:
        self.engine.line_opened()

    def line_lost(self) -> None:
        self.engine.line_lost()

    def line_drained(self) -> None:
        self.engine.line_drained()

    def line_flushed(self) -> None:
        self.engine.line_flushed()

    def stopping(self) -> None:
        self.engine.stopping()

    @property
    def stop_done(self) -> bool:
        return self.engine.stop_done

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        return self.engine.wrote(sent, unsure)
