"""The scheduler: one thread per output, ticking against absolute monotonic deadlines.

A C2-16B tick writes, in one `write()`, the pending service frames and then one data frame
per node (round-robin when the baud rate cannot carry them all). A SUMD tick writes one
frame. A late tick is counted, never caught up with a burst. An RX thread per C2-16B output
answers the far end's `<` and `4` requests.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from usb2rc.protocol import c2_16b, sumd
from usb2rc.state import EventKind, NodeFrame, NodeTable, ServiceEvent
from usb2rc.transport import SerialLink

log = logging.getLogger("usb2rc.scheduler")

BITS_PER_BYTE_ON_WIRE = 10  # 8N1: start + 8 data + stop


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


@dataclass
class OutputStats:
    ticks: int = 0
    late_ticks: int = 0
    missed_ticks: int = 0
    writes: int = 0
    data_frames: int = 0
    service_frames: int = 0
    deferred_nodes: int = 0
    tick_errors: int = 0
    periods_s: deque[float] = field(default_factory=lambda: deque(maxlen=3000))

    def period_p99_error_ms(self, nominal_s: float) -> float:
        if not self.periods_s:
            return 0.0
        errors = sorted(abs(p - nominal_s) for p in self.periods_s)
        return errors[min(len(errors) - 1, int(len(errors) * 0.99))] * 1000.0


class TickThread(threading.Thread):
    """Calls `tick()` every 1/rate_hz s on absolute monotonic deadlines until stopped."""

    def __init__(
        self,
        name: str,
        rate_hz: float,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name=name)
        self.period_s = 1.0 / rate_hz
        self.stats = OutputStats()
        self.on_tick = on_tick  # after every tick, on this thread (the watchdog hook)
        self.on_first_write = on_first_write  # once, after the first successful write
        self.last_tick_monotonic = 0.0
        self.next_deadline = 0.0  # when the next tick is due (monotonic): readers pace on it
        self._stop_event = threading.Event()
        self._last_write = 0.0
        self._logged_errors: set[str] = set()

    def stop(self) -> None:
        self._stop_event.set()

    def run(self) -> None:
        deadline = time.monotonic()
        while not self._stop_event.is_set():
            self.next_deadline = deadline
            delay = deadline - time.monotonic()
            if delay > 0 and self._stop_event.wait(delay):
                break
            started = time.monotonic()
            if started - deadline > self.period_s / 2:
                self.stats.late_ticks += 1
            self.next_deadline = deadline + self.period_s  # readers sample for the next one
            if self._safe_tick():
                self.stats.ticks += 1
                self.last_tick_monotonic = time.monotonic()
                self._safe_call(self.on_tick)
            deadline += self.period_s
            behind = time.monotonic() - deadline
            if behind >= 0:  # a whole tick lost: skip it, never burst to catch up
                missed = int(behind // self.period_s) + 1
                self.stats.missed_ticks += missed
                deadline += missed * self.period_s
        self.finish()

    def _safe_tick(self) -> bool:
        """One tick; a bug in it is logged (once per kind) and counted, never kills the
        thread. A failed tick does not count as alive, so a scheduler that keeps failing
        starves the watchdog and systemd restarts it."""
        try:
            self.tick()
        except Exception as exc:
            self.stats.tick_errors += 1
            frame = traceback.extract_tb(exc.__traceback__)[-1]
            kind = f"{type(exc).__name__} at {frame.filename}:{frame.lineno}"
            if kind not in self._logged_errors:
                self._logged_errors.add(kind)
                log.exception("%s: tick failed (%s: %s); going on", self.name, kind, exc)
            return False
        return True

    def _safe_call(self, hook: Callable[[], object] | None) -> None:
        if hook is None:
            return
        try:
            hook()
        except Exception:
            log.exception("%s: hook %r failed", self.name, hook)

    def tick(self) -> None:
        raise NotImplementedError

    def finish(self) -> None:
        """Called once in the thread after the last tick."""

    def note_write(self) -> None:
        now = time.monotonic()
        if self._last_write:
            self.stats.periods_s.append(now - self._last_write)
        self._last_write = now
        self.stats.writes += 1
        if self.on_first_write:
            callback, self.on_first_write = self.on_first_write, None
            self._safe_call(callback)


@dataclass(frozen=True)
class _Pending:
    node_id: int
    event: ServiceEvent
    frame: bytes


@dataclass(frozen=True)
class C2Settings:
    rate_hz: float = 50.0
    baudrate: int = 115200
    line_feed: bool = True
    binary_status: bool = False
    version: str = "0.0.0"


class C2Output(TickThread):
    """SERaero C2-16B: startup, service frames, one data frame per node per tick."""

    def __init__(
        self,
        name: str,
        link: SerialLink,
        table: NodeTable,
        settings: C2Settings,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name, settings.rate_hz, on_tick, on_first_write)
        self.link = link
        self.table = table
        self.settings = settings
        self.subscriber = table.subscribe()
        self.frame_len = c2_16b.FRAME_LEN + (1 if settings.line_feed else 0)
        self.capacity = frames_per_tick(settings.baudrate, settings.rate_hz, self.frame_len)
        self._codes: dict[int, int] = {}
        self._on_line: set[int] = set()  # nodes whose data frames this line has seen
        self._pending: deque[_Pending] = deque()  # service frames owed, in order
        self._round_robin = 0
        self._warned_nodes = 0
        self._startup_due = True
        # built once here: a version that does not fit the frame fails at start, loudly
        self._startup_frame = c2_16b.startup(settings.version, **self._kw())

    def _line_opened(self) -> None:
        """A fresh line (or one that came back): the startup frame, then who is here."""
        self._startup_due = True
        self._pending.clear()
        self._on_line.clear()
        self.table.collect(self.subscriber)  # what was queued is superseded by:
        self.table.request_connect_sequences(self.subscriber)

    def _kw(self) -> dict[str, bool]:
        return {
            "binary_status": self.settings.binary_status,
            "line_feed": self.settings.line_feed,
        }

    def service_frames(self, event: ServiceEvent) -> list[bytes]:
        kw, node = self._kw(), event.node_id
        if event.kind is EventKind.DISCONNECTED:
            return [c2_16b.disconnected(node, **kw)]
        if event.kind is EventKind.ERROR:
            return [c2_16b.device_error(node, event.error_code, **kw)]
        info = event.info
        assert info is not None
        return [
            c2_16b.connected(node, **kw),
            c2_16b.vid_pid(node, info.vid, info.pid, **kw),
            c2_16b.device_string(node, device_string_text(info.product, info.manufacturer), **kw),
            c2_16b.device_type(node, event.device_type or "", **kw),
        ]

    def data_frame(self, frame: NodeFrame, code: int) -> bytes:
        status = c2_16b.FAILSAFE if frame.failsafe else c2_16b.LIVE
        return c2_16b.encode_data(
            status,
            frame.node_id,
            code,
            frame.axes,
            frame.group1,
            frame.group2,
            line_feed=self.settings.line_feed,
        )

    def _announcing(self) -> set[int]:
        """Nodes whose connect sequence is still queued (not yet on the line)."""
        return {p.node_id for p in self._pending if p.event.kind is EventKind.CONNECTED}

    def _choose_nodes(self, frames: Sequence[NodeFrame], room: int) -> list[NodeFrame]:
        """The nodes that get a data frame this tick: all of them when they fit, else a
        round-robin share. A node new on this line waits for its connect sequence; a node
        already on it keeps its frames coming (as `!`, see tick) while it is re-announced."""
        held = self._announcing() - self._on_line
        ready = [f for f in frames if f.node_id not in held]
        if len(ready) <= room:
            return ready
        if len(frames) > self.capacity:
            self._warn_bandwidth([f.node_id for f in frames])
        start = self._round_robin % len(ready)
        chosen = (ready[start:] + ready[:start])[:room]
        self._round_robin = start + room
        self.stats.deferred_nodes += len(ready) - len(chosen)
        return sorted(chosen, key=lambda f: f.node_id)

    def _warn_bandwidth(self, node_ids: list[int]) -> None:
        nodes = len(node_ids)
        if nodes <= self._warned_nodes:
            return
        self._warned_nodes = nodes
        log.warning(
            "%s: nodes %s need %d frames per %.0f ms tick but %d baud carries %d; sending "
            "nodes round-robin (each node every %.1f ticks). %d baud would carry them all.",
            self.link.url,
            ", ".join(map(str, node_ids)),
            nodes,
            self.period_s * 1000,
            self.settings.baudrate,
            self.capacity,
            nodes / max(1, self.capacity),
            baud_needed(nodes, self.settings.rate_hz, self.frame_len),
        )

    def _queue(self, events: Sequence[ServiceEvent]) -> None:
        queued = {p.event for p in self._pending}
        for event in events:
            if event.kind is EventKind.CONNECTED and event in queued:
                continue  # that connect sequence is still on its way: once is enough
            queued.add(event)
            self._pending.extend(
                _Pending(event.node_id, event, f) for f in self.service_frames(event)
            )

    def _service_room(self, nodes: int) -> int:
        """Service frames first, but never all the room while nodes wait for data frames:
        a far end that keeps asking must not starve the data (at least one slot for data
        when every node fits, at least one for service frames otherwise)."""
        if not self._pending and not self._startup_due:
            return 0
        return max(1, self.capacity - nodes)

    def tick(self) -> None:
        if not self.link.is_open:
            self.link.try_open()
        if self.link.take_opened():
            self._line_opened()
        events, frames = self.table.collect(self.subscriber)
        if not self.link.is_open:
            self._pending.clear()  # the line is gone: the startup + connect sequence follow
            return
        self._queue(events)
        service_room = self._service_room(len(frames))
        out: list[bytes] = []
        if self._startup_due:
            out.append(self._startup_frame)
        taken = list(itertools.islice(self._pending, max(0, service_room - len(out))))
        out.extend(p.frame for p in taken)
        service_count = len(out)
        for _ in taken:  # a node whose service frames are still queued waits for them
            self._pending.popleft()
        chosen = self._choose_nodes(frames, self.capacity - service_count)
        announcing = self._announcing()  # never `>` ahead of the node's connect sequence
        chosen = [replace(f, failsafe=True) if f.node_id in announcing else f for f in chosen]
        codes = [self._codes.get(f.node_id, 0) for f in chosen]
        out.extend(self.data_frame(f, code) for f, code in zip(chosen, codes, strict=True))
        if not out:
            return
        if self.link.write(b"".join(out)):
            self._startup_due = False
            for f, code in zip(chosen, codes, strict=True):
                self._codes[f.node_id] = (code + 1) & 0xFF
            self._on_line.update(f.node_id for f in chosen)
            self.stats.service_frames += service_count
            self.stats.data_frames += len(chosen)
            self.note_write()
        else:  # nothing went out: the service frames are owed still, the codes not used
            self._pending.extendleft(reversed(taken))

    def finish(self) -> None:
        self.link.close()


ChannelValue = Callable[[dict[int, NodeFrame]], tuple[int, bool]]


class SumdOutput(TickThread):
    """HoTT SUMD: one frame of the configured channels per tick (100 Hz)."""

    def __init__(
        self,
        name: str,
        link: SerialLink,
        table: NodeTable,
        channels: Sequence[ChannelValue],
        rate_hz: float = 100.0,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name, rate_hz, on_tick, on_first_write)
        self.link = link
        self.table = table
        self.channels = list(channels)
        self.frames_sent = 0

    def tick(self) -> None:
        if not self.link.is_open and not self.link.try_open():
            return
        self.link.take_opened()
        nodes = {f.node_id: f for f in self.table.frames()}
        values: list[int] = []
        failsafe = False
        for channel in self.channels:
            value, channel_failsafe = channel(nodes)
            values.append(value)
            failsafe = failsafe or channel_failsafe
        if self.link.write(sumd.encode_sumd(values, failsafe=failsafe)):
            self.frames_sent += 1
            self.note_write()

    def finish(self) -> None:
        self.link.close()


class RxThread(threading.Thread):
    """Reads what the far end sends on a C2-16B line and answers `<` and `4` requests."""

    def __init__(self, name: str, link: SerialLink, table: NodeTable, subscriber: int) -> None:
        super().__init__(name=name)
        self.link = link
        self.table = table
        self.subscriber = subscriber
        self.decoder = c2_16b.Decoder()
        self.requests = 0
        self._stop_event = threading.Event()

    def stop(self) -> None:
        self._stop_event.set()

    def run(self) -> None:
        while not self._stop_event.is_set():
            if not self.link.readable:
                self._stop_event.wait(0.1)
                continue
            data = self.link.read()
            if data:
                for frame in self.decoder.feed(data):
                    self._answer(frame)

    def _answer(self, frame: c2_16b.DataFrame | c2_16b.ServiceFrame) -> None:
        if isinstance(frame, c2_16b.DataFrame) and frame.status == c2_16b.CONFIG_REQUEST:
            self.requests += 1
            self.table.request_connect_sequences(self.subscriber)
        elif isinstance(frame, c2_16b.ServiceFrame) and frame.service == c2_16b.Service.POLL:
            self.requests += 1
            self.table.request_connect_sequences(self.subscriber, frame.node_id)
