"""The C2-16B line's state machine, its engine (of `protocols.c2_16b.session.C2Session`), sans-IO.

(About 550 lines on purpose: C2Engine's invariants — announce state, codes, owed
service frames, stalls and flushes — hold only together, and are tested together.)

A `C2Engine` is one C2-16B output's line protocol (h11's `Connection` is the model): it owns
the startup frame, the service frames owed, the message codes, the round-robin and who is
announced on the line, and moves the line's state (`lines.session.LineState`, shared with its
session). It takes events and returns the bytes to write; it has no thread, no port and no
clock, so every interleaving can be driven from a test:

    line_opened()                        a fresh line: the startup frame goes first
    line_lost()                          the port is gone: nothing is owed to a dead line
    tick(events, frames) -> bytes        one tick: the node table's events and snapshot
    wrote(sent, unsure=0)                how many bytes of the last output went out
    line_drained()                       after a stall, the line takes bytes again
    line_flushed()                       ... and what it held was dropped (a pty's
                                         buffer): the line starts over from the startup
    received(frame)                      a frame from the far end (`<`, `4` requests,
                                         answered in the next tick)

`C2Session` puts it on the one session interface (`usb2rc.lines.session`): it feeds it the
node snapshot's events and frames and the far end's decoded requests, and the generic driver
(`usb2rc.lines.driver`) moves the bytes. It speaks in the node table's `ServiceEvent` and
`NodeFrame`, which the codec (`protocols.c2_16b.codec`) knows nothing of.

Invariants, whatever the line does (docs/ICD.md, "Service frames" and "A stalled line"):
- the startup frame is the first thing on every (re)opened line;
- a node's `>` goes out only after its whole `1,6,5,7` went out on the current line (and no
  `2` of that node since);
- a node whose device left has its `2` out before the node's next frame of any kind;
- a node's message code advances by one per data frame that went out whole (a flush may
  drop frames: the receiver then sees a gap, never a code twice);
- a service frame cut short is sent again;
- after a flush the line starts over: the startup frame, a `2` for each node announced on the
  line whose device left since, the connect sequence of every device present;
- a node stays announced while the far end's request announces it again (only a `2` or
  a startup frame ends an announcement);
- a data frame's status is `!` unless the node is live and announced; then `&` while a
  handover asks for it, else `%` while its battery is low, else `>` (docs/ICD.md, "Status
  priority"). A `&` carries its destination in byte 4 and uses no message code.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Final

from usb2rc.lines.link import BITS_PER_BYTE_ON_WIRE
from usb2rc.lines.session import Delivered, LineState
from usb2rc.nodes.table import EventKind, NodeFrame, ServiceEvent
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.data_status import DataStatuses

log = logging.getLogger("usb2rc.session")


def frames_per_tick(baudrate: int, rate_hz: float, frame_len: int) -> int:
    """How many frames of frame_len bytes the line carries in one tick (at least 1)."""
    bytes_per_tick = baudrate / BITS_PER_BYTE_ON_WIRE / rate_hz
    return max(1, int(bytes_per_tick // frame_len))


def baud_needed(frames: int, rate_hz: float, frame_len: int) -> int:
    """The smallest standard baud rate that carries `frames` frames per tick."""
    needed = frames * frame_len * BITS_PER_BYTE_ON_WIRE * rate_hz
    for baud in (115200, 230400, 460800, 500000, 921600, 1000000, 1500000, 2000000):
        if baud >= needed:
            return baud
    return int(needed)


def device_string_text(product: str, manufacturer: str = "", limit: int = 12) -> str:
    """The product name for service frame `5`: without the maker's name in front.

    Kernel and hid-recorder names are "Manufacturer Product" ("Thrustmaster T.16000M"); the
    12 bytes the frame carries are better spent on the product. With no manufacturer known,
    the first word goes when the name does not fit.
    """
    name = product.strip()
    if manufacturer and name.lower().startswith(manufacturer.lower() + " "):
        return name[len(manufacturer) :].strip()
    _, _, rest = name.partition(" ")
    if not manufacturer and len(name) > limit and rest:
        return rest.strip()
    return name


@dataclass(frozen=True)
class C2Settings:
    rate_hz: float = 50.0
    baudrate: int = 115200
    line_feed: bool = True
    binary_status: bool = False
    version: str = "0.0.0"


@dataclass(frozen=True)
class _Owed:
    """One service frame owed to the line, and the event it comes from."""

    event: ServiceEvent
    service: c2_16b.Service
    frame: bytes

    @property
    def node_id(self) -> int:
        return self.event.node_id

    @property
    def ends_connect_sequence(self) -> bool:
        return self.service is c2_16b.Service.DEVICE_TYPE

    @property
    def is_disconnect(self) -> bool:
        return self.service is c2_16b.Service.DISCONNECTED


class _Slot:
    """One frame of the last output: where its 35 frame bytes end, and what it was (a plain
    class, made per frame: compiled, in C)."""

    def __init__(
        self,
        end: int,
        startup: bool = False,
        owed: _Owed | None = None,
        data_node: int | None = None,
        status: int = 0,
    ) -> None:
        self.end: Final = end  # offset of the frame's last byte + 1 (its LF does not count)
        self.startup: Final = startup
        self.owed: Final = owed
        self.data_node: Final = data_node
        # a data frame's status byte (`&`: byte 4 is its destination, not a code)
        self.status: Final = status


def _announced_after(announced: set[int], owed: Iterable[_Owed]) -> set[int]:
    """Who is announced once `owed` went out in order: a `7` closes a `1,6,5,7` (the queue
    sends each sequence whole and in order), a `2` opens the node's announcement again."""
    result = set(announced)
    for item in owed:
        if item.ends_connect_sequence:
            result.add(item.node_id)
        elif item.is_disconnect:
            result.discard(item.node_id)
    return result


class C2Engine:
    """The C2-16B line of one output. See the module docstring for the events. `line`: the
    line's state it moves (its session's; a new one when it runs alone, in a test)."""

    def __init__(
        self, settings: C2Settings, name: str = "c2-16b", line: LineState | None = None
    ) -> None:
        self.settings = settings
        self.name = name  # for log lines: the port
        self.frame_len = c2_16b.FRAME_LEN + (1 if settings.line_feed else 0)
        self.capacity = frames_per_tick(settings.baudrate, settings.rate_hz, self.frame_len)
        # built once here: a version that does not fit the frame fails at start, loudly
        self._startup_frame = c2_16b.startup(settings.version, **self._kw())
        self.line = LineState() if line is None else line
        self.deferred_nodes = 0
        self.statuses = DataStatuses(name)  # `!` `&` `%` `>`, and the handover presses
        self._startup_due = True
        self._owed: deque[_Owed] = deque()
        self._codes: dict[int, int] = {}
        # a node's frame body and its CRC, kept while its content stays the same
        self._data_frames = c2_16b.DataFrames(settings.line_feed)
        self._on_line: set[int] = set()  # nodes whose data frames this line has seen
        self._announced: set[int] = set()  # nodes whose whole 1,6,5,7 went out on this line
        self._present: dict[int, dict[str, ServiceEvent]] = {}  # node -> device -> CONNECTED
        # Kept across flushes, cleared with the line: a flush may drop any suffix of what
        # went out, so the receiver may still believe what it read before the first one.
        self._told: set[int] = set()  # nodes whose whole 1,6,5,7 went out on this line
        self._left_told: set[int] = set()  # ... and whose device left after that
        # the far end's requests since the last tick, coalesced: a `<`, and the `4`s by node
        self._asked_all = False
        self._polled: set[int] = set()
        self._last: list[_Slot] = []
        self._last_len = 0
        self._round_robin = 0
        self._warned_nodes = 0
        self._stop_owed: set[int] = set()  # stopping: nodes on this line without a `!` since

    # --- events from the line ------------------------------------------------------------

    def line_opened(self) -> None:
        """A fresh line (or one that came back): the startup frame first, then the caller
        feeds the connect events of every device present (`NodeTable` does)."""
        self._reset_line()
        self.line.opened()
        self._present.clear()  # rebuilt from the connect events that follow

    def line_lost(self) -> None:
        """The port is gone: nothing is owed to a dead line; the next one starts afresh."""
        self._reset_line()
        self.line.lost()

    def line_drained(self) -> None:
        """After a stall, the line takes bytes again: the next tick sends fresh frames (the
        owed service frames are still owed: none of them was lost)."""
        self.line.resumed()

    def line_flushed(self) -> None:
        """After a stall, the line takes bytes again and what the OS still held was dropped
        (`SerialLink.discard_stale`): any suffix of what went out may be lost, perhaps in
        the middle of a frame. So the line starts over: the startup frame; a `2` for every
        node announced on this line whose device left since (the receiver may have read its
        `>` and not its `2`); the service frames still owed that are not connect sequences
        (a `3`, a `2`); then the connect sequence of every device present, from its `1`.
        Message codes go on counting: the receiver sees a gap where frames were dropped.
        Nodes keep sending `!` while they are announced again (they are not new). A device
        that left since the last tick gets its `2` ahead of that announcement when its
        event comes (`_queue_disconnect`)."""
        if not self.line.is_open:
            return
        self.line.resumed()
        self._last, self._last_len = [], 0
        self._startup_due = True
        self._announced.clear()
        kept = [o for o in self._owed if o.event.kind is not EventKind.CONNECTED]
        gone = self._left_told - {o.node_id for o in kept if o.is_disconnect}
        self._owed = deque(kept)
        for node_id in sorted(gone):
            self._owed.extend(self._owed_frames(ServiceEvent(EventKind.DISCONNECTED, node_id)))
        self._announce(sorted(self._present))

    def _reset_line(self) -> None:
        self._startup_due = True
        self._owed.clear()
        self._on_line.clear()
        self._announced.clear()
        self._told.clear()
        self._left_told.clear()
        self._last, self._last_len = [], 0
        self.statuses.line_reset()

    def stopping(self) -> None:
        """usb2rc stops (SIGTERM, SIGINT): from now on every data frame is `!`, so a receiver
        sees failsafe at once instead of waiting for its own timeout (docs/ICD.md, "Stop").
        `stop_done` once every node whose frames this line has carried got one."""
        self.line.stop()
        self._stop_owed = set(self._on_line)

    @property
    def stop_done(self) -> bool:
        """Stopping, and nothing more to send: each node's `!` went out, or the line cannot
        take it (closed, or stalled: a stop never waits for a far end that does not read)."""
        return self.line.stop_done(not self._stop_owed)

    # --- events from the far end ---------------------------------------------------------

    def received(self, frame: c2_16b.Frame) -> bool:
        """A frame from the far end; True when it was a request (answered in the next ticks).

        `<` (any Node-ID): the connect sequence of every device present, in Node-ID order.
        `4` for node N: the connect sequence of each device present on N, else `2`.
        Requests are coalesced until the tick answers them (a `<`, and each polled node,
        once), and a sequence still owed is not queued twice: however often the far end
        asks, what is owed stays one answer per node."""
        if isinstance(frame, c2_16b.DataFrame) and frame.status == c2_16b.CONFIG_REQUEST:
            self._asked_all = True
            return True
        if isinstance(frame, c2_16b.ServiceFrame) and frame.service is c2_16b.Service.POLL:
            self._polled.add(frame.node_id)
            return True
        return False

    @property
    def pending_requests(self) -> int:
        """Requests waiting for the next tick, coalesced (at most one per Node-ID and a `<`)."""
        return len(self._polled) + self._asked_all

    def _clear_requests(self) -> None:
        self._asked_all = False
        self._polled.clear()

    def _answer_requests(self) -> None:
        """Answered in the tick, after its events: a device that left meanwhile is not
        announced again ahead of its `2`. One pass over what is owed, whatever was asked."""
        if not self._asked_all and not self._polled:
            return
        present = {node_id for node_id, devices in self._present.items() if devices}
        announce = present if self._asked_all else present & self._polled
        absent = self._polled - present
        self._clear_requests()
        owed = {o.event for o in self._owed}
        self._announce(sorted(announce), owed)
        for node_id in sorted(absent):
            self._queue_new(ServiceEvent(EventKind.DISCONNECTED, node_id), owed)

    def _announce(self, node_ids: Sequence[int], owed: set[ServiceEvent] | None = None) -> None:
        """Queue the connect sequence of every device present on `node_ids` that is not owed
        already (`owed`: the events owed now, when the caller has them)."""
        owed = {o.event for o in self._owed} if owed is None else owed
        for node_id in node_ids:
            for event in self._present.get(node_id, {}).values():
                self._queue_new(event, owed)

    def _queue_new(self, event: ServiceEvent, owed: set[ServiceEvent]) -> None:
        """`_queue_once` with the owed events at hand (kept up to date here)."""
        if self.line.is_open and event not in owed:
            self._owed.extend(self._owed_frames(event))
            owed.add(event)

    # --- ticks ---------------------------------------------------------------------------

    def tick(
        self,
        events: Sequence[ServiceEvent],
        frames: Sequence[NodeFrame],
        room_frames: int | None = None,
    ) -> bytes:
        """The bytes of one tick (b"" when there is nothing to send, no line, or a stall).
        `room_frames`: how many frames the line carries this tick (default: the baud rate's
        share of a tick). Call `wrote()` with what went out before the next tick."""
        self._track_presence(events)
        self.statuses.follow(frames)
        self._last, self._last_len = [], 0
        if not self.line.is_open:
            self._clear_requests()
            return b""  # nothing is queued for a dead line: it starts afresh when back
        for event in events:
            self._queue(event)
        self._answer_requests()
        if self.line.stalled:
            return b""  # the service state waits; the data frames would be stale by then
        room = self.capacity if room_frames is None else max(1, room_frames)
        return self._compose(frames, room)

    def _compose(self, frames: Sequence[NodeFrame], room: int) -> bytes:
        out: list[bytes] = []
        slots: list[_Slot] = []
        if self._startup_due:
            self._add(out, slots, self._startup_frame, startup=True)
        announced, held = self._service_frames(out, slots, len(frames), room)
        ready = [f for f in frames if f.node_id not in held] if held else list(frames)
        for frame in self._choose_nodes(ready, frames, room - len(out)):
            live = not frame.failsafe and frame.node_id in announced and not self.line.stopping
            code = self._codes.get(frame.node_id, 0)
            status, byte4 = self.statuses.choose(frame, live, code)
            data = self._data_frame(frame, status, byte4)
            self._add(out, slots, data, data_node=frame.node_id, status=status)
        self._last = slots
        self._last_len = sum(map(len, out))
        return b"".join(out)

    def _add(
        self,
        out: list[bytes],
        slots: list[_Slot],
        frame: bytes,
        startup: bool = False,
        owed: _Owed | None = None,
        data_node: int | None = None,
        status: int = 0,
    ) -> None:
        start = sum(map(len, out))
        out.append(frame)
        slots.append(_Slot(start + c2_16b.FRAME_LEN, startup, owed, data_node, status))

    def _service_frames(
        self, out: list[bytes], slots: list[_Slot], nodes: int, room: int
    ) -> tuple[set[int], set[int]]:
        """Add the owed service frames that fit; (the nodes announced once they are out, the
        nodes whose data frames wait)."""
        if not self._owed:  # the usual tick: nothing owed, nothing held
            return self._announced, set()
        taken = list(self._owed)[: max(0, self._service_room(nodes, room) - len(out))]
        for item in taken:
            self._add(out, slots, item.frame, owed=item)
        owed_after = list(self._owed)[len(taken) :]
        announcing = {o.node_id for o in owed_after if o.event.kind is EventKind.CONNECTED}
        leaving = {o.node_id for o in owed_after if o.is_disconnect}
        # A node announced on this line (its whole 1,6,5,7 out, no `2` and no startup frame
        # since) stays announced while it is announced again (a `<` or `4` answered, another
        # device on it): its data frames stay `>`, a request never costs a live node its
        # live frames (docs/ICD.md, "Sequences"). Any other node with a sequence owed is not.
        announced = _announced_after(self._announced, taken) - (announcing - self._announced)
        # a node new on this line waits for its connect sequence; a node whose `2` is still
        # owed waits for it (its next frame of any kind comes after the `2`)
        return announced, (announcing - self._on_line) | leaving

    def _service_room(self, nodes: int, room: int) -> int:
        """Service frames first, but never all the room while nodes wait for data frames:
        a far end that keeps asking must not starve the data (at least one slot for data
        when every node fits, at least one for service frames otherwise)."""
        if not self._owed and not self._startup_due:
            return 0
        return max(1, room - nodes)

    def _choose_nodes(
        self, ready: list[NodeFrame], frames: Sequence[NodeFrame], room: int
    ) -> list[NodeFrame]:
        """The nodes that get a data frame this tick: all of them when they fit, else a
        round-robin share (each tick starts where the previous one stopped)."""
        if len(ready) <= room:
            return ready
        if len(frames) > self.capacity:
            self._warn_bandwidth([f.node_id for f in frames])
        start = self._round_robin % len(ready)
        chosen = (ready[start:] + ready[:start])[: max(0, room)]
        self._round_robin = start + len(chosen)
        self.deferred_nodes += len(ready) - len(chosen)
        return sorted(chosen, key=lambda f: f.node_id)

    def _warn_bandwidth(self, node_ids: list[int]) -> None:
        nodes = len(node_ids)
        if nodes <= self._warned_nodes:
            return
        self._warned_nodes = nodes
        rate = self.settings.rate_hz
        log.warning(
            "%s: nodes %s need %d frames per %.0f ms tick but %d baud carries %d; sending "
            "nodes round-robin (each node every %.1f ticks). %d baud would carry them all.",
            self.name,
            ", ".join(map(str, node_ids)),
            nodes,
            1000.0 / rate,
            self.settings.baudrate,
            self.capacity,
            nodes / max(1, self.capacity),
            baud_needed(nodes, rate, self.frame_len),
        )

    # --- what went out -------------------------------------------------------------------

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        """`sent` bytes of the last output surely went out (a prefix); the `unsure` bytes
        after them may or may not have (a write that timed out in the middle).

        A frame is out when its 35 frame bytes are (its LF is not needed to decode it).
        A service frame that is not surely out stays owed and is sent again; a data frame
        that may be out uses its message code (a receiver never sees a code twice; with an
        exact count, which posix ports and sockets give, the codes it sees advance by one).
        Anything less than the whole output is a stall: no frames until `line_drained()`."""
        service = data = 0
        for slot in self._last:
            if slot.end <= sent:
                service += self._confirm(slot)
            if slot.data_node is not None and slot.end <= sent + unsure:
                node = slot.data_node
                if self.statuses.sent(node, slot.status):  # a `&` uses no message code
                    self._codes[node] = (self._codes.get(node, 0) + 1) & 0xFF
                self._on_line.add(node)
                self._stop_owed.discard(node)
                data += 1
        if unsure:
            self._restart_cut_sequence()
        stalled = sent < self._last_len and self.line.is_open
        if stalled:
            self.line.stall()
        self._last, self._last_len = [], 0
        return Delivered(service, data, stalled)

    def _restart_cut_sequence(self) -> None:
        """After an unsure write, a connect sequence whose rest is owed is sent again from
        its `1`: part of that rest may have gone, and a receiver must see the sequence
        whole and in order (`1,6,5,1,6,5,7`, never `1,6,5,6,5,7`)."""
        if not self._owed or self._owed[0].event.kind is not EventKind.CONNECTED:
            return
        head = self._owed[0]
        sequence = self._owed_frames(head.event)
        done = next(i for i, item in enumerate(sequence) if item.service is head.service)
        self._owed.extendleft(reversed(sequence[:done]))

    def _confirm(self, slot: _Slot) -> int:
        """A startup or service frame that went out whole: 1 (counted), else 0."""
        if slot.startup:
            self._startup_due = False
            return 1
        if slot.owed is None:
            return 0
        assert self._owed and self._owed[0] is slot.owed, "owed frames go out in order"
        self._owed.popleft()
        self._announced = _announced_after(self._announced, [slot.owed])
        if slot.owed.ends_connect_sequence:
            self._told.add(slot.owed.node_id)
        return 1

    # --- service events ------------------------------------------------------------------

    def _track_presence(self, events: Sequence[ServiceEvent]) -> None:
        """Which devices are present, from the events: for the far end's requests."""
        for event in events:
            key = event.info.key if event.info is not None else ""
            if event.kind is EventKind.CONNECTED:
                self._present.setdefault(event.node_id, {})[key] = event
            elif event.kind is EventKind.DISCONNECTED:
                self._present.get(event.node_id, {}).pop(key, None)

    def _queue(self, event: ServiceEvent) -> None:
        if event.kind is EventKind.CONNECTED:
            self._queue_once(event)  # that connect sequence is on its way: once is enough
        elif event.kind is EventKind.DISCONNECTED:
            self._queue_disconnect(event)
        else:
            self._owed.extend(self._owed_frames(event))

    def _queue_disconnect(self, event: ServiceEvent) -> None:
        """The `2` goes before any other frame of its node: a connect sequence of that node
        still owed (a `<` answered just before the device left) is taken out, and queued
        again after the `2`, from its `1`, if its device is still present."""
        node_id = event.node_id
        if node_id in self._told:
            self._left_told.add(node_id)  # owed a `2` after any flush from now on
        ahead = [
            o for o in self._owed if o.node_id == node_id and o.event.kind is EventKind.CONNECTED
        ]
        self._owed = deque(o for o in self._owed if o not in ahead)
        self._owed.extend(self._owed_frames(event))
        present = self._present.get(node_id, {}).values()
        for connected in dict.fromkeys(o.event for o in ahead):
            if connected in present:
                self._queue_once(connected)

    def _queue_once(self, event: ServiceEvent) -> None:
        self._queue_new(event, {o.event for o in self._owed})

    def _owed_frames(self, event: ServiceEvent) -> list[_Owed]:
        kw, node = self._kw(), event.node_id
        Service = c2_16b.Service
        if event.kind is EventKind.DISCONNECTED:
            return [_Owed(event, Service.DISCONNECTED, c2_16b.disconnected(node, **kw))]
        if event.kind is EventKind.ERROR:
            frame = c2_16b.device_error(node, event.error_code, **kw)
            return [_Owed(event, Service.ERROR, frame)]
        info = event.info
        assert info is not None
        text = device_string_text(info.product, info.manufacturer)
        return [
            _Owed(event, Service.CONNECTED, c2_16b.connected(node, **kw)),
            _Owed(event, Service.VID_PID, c2_16b.vid_pid(node, info.vid, info.pid, **kw)),
            _Owed(event, Service.DEVICE_STRING, c2_16b.device_string(node, text, **kw)),
            _Owed(event, Service.DEVICE_TYPE, c2_16b.device_type(node, event.device_type, **kw)),
        ]

    def _data_frame(self, frame: NodeFrame, status: int, byte4: int) -> bytes:
        return self._data_frames.encode(
            status, frame.node_id, byte4, frame.axes, frame.group1, frame.group2
        )

    def _kw(self) -> dict[str, bool]:
        return {
            "binary_status": self.settings.binary_status,
            "line_feed": self.settings.line_feed,
        }

    @property
    def owed_frames(self) -> int:
        return len(self._owed)
