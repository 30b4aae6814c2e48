"""The scheduler: one thread per output, ticking against absolute monotonic deadlines.

Each output thread is a thin loop around its line session (`usb2rc.session`): once a tick it
follows the link (`line_event()`: a new port, a lost one; `drained()` after a stall, then
`discard_stale()`: the session is told `line_flushed()` or `line_drained()`), takes
the node table's events and snapshot, asks the session for the tick's bytes, writes them in
one `write()` and tells the session how many went out. A late tick is counted, never caught
up with a burst (MAVLink writes each message of a tick on its own: one datagram each on
UDP). An RX thread per C2-16B output decodes what the far end sends and hands the
frames to the output thread, whose session answers `<` and `4` requests.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from usb2rc.nodes.table import NodeTable
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.channels import OutputChannels
from usb2rc.rc_sessions import CrsfSession
from usb2rc.runtime.worker import Worker
from usb2rc.session import (  # noqa: F401 - re-exported: their home used to be here
    BITS_PER_BYTE_ON_WIRE,
    C2Session,
    C2Settings,
    Delivered,
    FrameLineSession,
    SumdSession,
    baud_needed,
    device_string_text,
    frames_per_tick,
)
from usb2rc.transport import LineEvent, SerialLink, Written
from usb2rc.transport_udp import UdpLink

if TYPE_CHECKING:  # pymavlink's dialect is loaded only with a MAVLink output
    from usb2rc.outputs.mavlink import MavlinkChannels, MavlinkSession

log = logging.getLogger("usb2rc.scheduler")

T = TypeVar("T")
PERIODS_KEPT = 3000
FINAL_TICKS_S = 0.25  # at most this long for the failsafe frames when usb2rc stops


def queue_cap(tick_bytes: int) -> int:
    """At most two ticks of frames wait in an OS transmit queue that reports its size:
    what comes out after a stall is never older than that (docs/ICD.md)."""
    return 2 * tick_bytes


@dataclass
class OutputStats:
    """Counters of one output. The output thread writes them; `stats_lines` reads them from
    another thread, so the periods are only read through `periods()` (a copy under a lock:
    iterating the deque while the writer appends would raise)."""

    ticks: int = 0
    late_ticks: int = 0
    missed_ticks: int = 0
    writes: int = 0
    data_frames: int = 0
    service_frames: int = 0
    deferred_nodes: int = 0
    handover_frames: int = 0  # `&`, `%` and the `&` a failsafe cut (docs/ICD.md, "Handover")
    handovers_cut: int = 0
    low_battery_frames: int = 0
    tick_errors: int = 0
    stalls: int = 0
    periods_s: deque[float] = field(default_factory=lambda: deque(maxlen=PERIODS_KEPT))
    _periods_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add_period(self, period_s: float) -> None:
        with self._periods_lock:
            self.periods_s.append(period_s)

    def periods(self) -> list[float]:
        with self._periods_lock:
            return list(self.periods_s)

    def period_p99_error_ms(self, nominal_s: float) -> float:
        periods = self.periods()
        if not periods:
            return 0.0
        errors = sorted(abs(p - nominal_s) for p in periods)
        return errors[min(len(errors) - 1, int(len(errors) * 0.99))] * 1000.0


@dataclass(frozen=True)
class Pace:
    """When an output's next tick is due (monotonic) and its period now: one value, so a
    reader thread pacing on it (`Daemon._reader_pause`) never pairs one tick's deadline
    with another's period. Only the output's own thread replaces it, whole."""

    deadline: float
    period_s: float


class TickThread(Worker):
    """Calls `tick()` every 1/rate_hz s on absolute monotonic deadlines until stopped.

    `pace` is written by this thread only (one assignment of an immutable `Pace`); other
    threads read it whole."""

    def __init__(
        self,
        name: str,
        rate_hz: float,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name)
        self.pace = Pace(0.0, 1.0 / rate_hz)  # deadline 0: not ticking yet
        self.stats = OutputStats()
        self.on_tick = on_tick  # after every tick, on this thread (the watchdog hook)
        self.on_first_write = on_first_write  # once, after the first successful write
        self.last_tick_monotonic = 0.0
        self._last_write = 0.0
        self._logged_errors: set[str] = set()

    def run(self) -> None:
        deadline = time.monotonic()
        while not self.stopping:
            self._set_pace(deadline, self.period_s)
            delay = deadline - time.monotonic()
            if delay > 0 and self.wait(delay):
                break
            started = time.monotonic()
            if started - deadline > self.period_s / 2:
                self.stats.late_ticks += 1
            self._set_pace(deadline + self.period_s, self.period_s)  # readers sample for it
            if self._safe_tick():
                self.stats.ticks += 1
                self.last_tick_monotonic = time.monotonic()
                self._safe_call(self.on_tick)
            deadline = self.next_due(deadline)
            behind = time.monotonic() - deadline
            if behind >= 0:  # a whole tick lost: skip it, never burst to catch up
                missed = int(behind // self.period_s) + 1
                self.stats.missed_ticks += missed
                deadline += missed * self.period_s
        self.final_ticks()
        self.finish()

    @property
    def period_s(self) -> float:
        """The period now (a CRSF module may change it; `pace` has it with its deadline)."""
        return self.pace.period_s

    def _set_pace(self, deadline: float, period_s: float) -> None:
        """This thread only: publish the next deadline with the period, in one step."""
        self.pace = Pace(deadline, period_s)

    def wait(self, delay_s: float) -> bool:
        """Between ticks: wait delay_s, or less if stopped (then True)."""
        return self.sleep(delay_s)

    def next_due(self, due: float) -> float:
        """When the tick after the one due at `due` is due (an output whose session sets
        its own pace, CRSF, overrides this)."""
        return due + self.period_s

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

    def final_ticks(self) -> None:
        """Called once in the thread when it is stopped, before `finish()`."""

    def finish(self) -> None:
        """Called once in the thread after the last tick."""

    def protocol_stats(self) -> dict[str, Any]:
        """What only this protocol counts, for the stats record (`Daemon.stats_record`; the
        labels of its keys are in `usb2rc.runtime.stats_text`)."""
        return {}

    def note_write(self) -> None:
        now = time.monotonic()
        if self._last_write:
            self.stats.add_period(now - self._last_write)
        self._last_write = now
        self.stats.writes += 1
        if self.on_first_write:
            callback, self.on_first_write = self.on_first_write, None
            self._safe_call(callback)


STALL_LOG_QUIET_S = 10.0  # a line that stalls again and again is logged once in this long


class _LineThread(TickThread):
    """An output thread: follows its link and feeds the session what the line did.

    The one place that decides what happens to stale bytes (docs/ICD.md, "A stalled line"):
    - a stall on a port whose transmit queue the OS reports (a serial port) drops that
      queue at once (`SerialLink.discard_stale`) and the session starts over
      (`line_flushed`): what was queued is as old as the stall, and the empty queue takes
      fresh frames at once;
    - on a pty, whose queue the OS hides, a channel output (`drops_unread_each_tick`) drops
      what the far end has not taken before each tick's write (`discard_unread`), so the
      kernel never holds a frame older than a tick; a C2-16B output cannot (its session
      must know what went out), so it waits for the full queue to drain and drops the rest
      then (`resume_line`);
    - a socket cannot be flushed: the session waits for the drain and goes on.
    """

    drops_unread_each_tick = True  # a frame lost to the flush is replaced by the next one

    def __init__(
        self,
        name: str,
        link: SerialLink | UdpLink,
        session: C2Session | FrameLineSession | MavlinkSession,
        rate_hz: float,
        on_tick: Callable[[], None] | None,
        on_first_write: Callable[[], None] | None,
    ) -> None:
        super().__init__(name, rate_hz, on_tick, on_first_write)
        self.link = link
        self.session = session
        self._stalled_since = 0.0
        self._stall_logged_at = -STALL_LOG_QUIET_S
        self._stalls_not_logged = 0

    def follow_link(self) -> None:
        """The line's events, in this thread only: a new port is adopted (and the session
        told) before anything is written on it; a stalled line is resumed once drained;
        on a pty, what the far end left unread since the last tick is dropped."""
        if not self.link.is_open:
            self.link.try_open()
        event = self.link.line_event()
        if event is LineEvent.OPENED:
            self.line_opened()
        elif event is LineEvent.LOST:
            self.session.line_lost()
        if self.session.stalled and self.link.drained():
            self.resume_line()
        if self.drops_unread_each_tick and isinstance(self.link, SerialLink):
            self.link.discard_unread()

    def resume_line(self) -> None:
        """The far end reads again. What the OS still holds is as old as the stall: the
        link drops it where it can (a pty), and the session then starts the line over;
        elsewhere nothing was lost and the session goes on where it stopped."""
        flushed = self.link.discard_stale()
        if flushed:
            self.session.line_flushed()
        else:
            self.session.line_drained()
        self._log_stall(
            logging.INFO,
            "%s: %s takes bytes again after %.1f s; %s",
            self.name,
            self.link.url,
            time.monotonic() - self._stalled_since,
            "dropped the stale bytes it held, restarted the line with the startup frame"
            if flushed
            else "resumed with fresh frames",
        )

    def stall_began(self, written: Written, size: int) -> None:
        """The far end takes no more bytes. Where the OS reports the queue (a serial port)
        it is dropped now: it holds frames as old as the stall, and once empty it takes
        fresh frames, so the line starts over at once. Elsewhere the session waits for the
        drain (on a pty the full queue is the only sign the far end reads again)."""
        self._stalled_since = time.monotonic()
        link = self.link
        flushed = isinstance(link, SerialLink) and not link.hides_queue and link.discard_stale()
        if flushed:
            self.session.line_flushed()
        self._log_stall(
            logging.WARNING,
            "%s: %s stalled: the far end takes no more bytes (%d of %d went out); %s",
            self.name,
            self.link.url,
            written.sent,
            size,
            "dropped what its queue held, starting over"
            if flushed
            else "no frames are added until it drains",
        )

    def _log_stall(self, level: int, text: str, *args: object) -> None:
        """A line that stalls again and again (a serial far end that never reads, whose
        queue is dropped at each stall) is logged once in STALL_LOG_QUIET_S; the stats
        count every stall and flush."""
        now = time.monotonic()
        if level == logging.WARNING:
            if now - self._stall_logged_at < STALL_LOG_QUIET_S:
                self._stalls_not_logged += 1
                return
            if self._stalls_not_logged:
                text += f" ({self._stalls_not_logged} more stalls since the last such line)"
            self._stall_logged_at, self._stalls_not_logged = now, 0
        elif self._stalls_not_logged:
            level = logging.DEBUG  # the resume of a stall that was not logged either
        log.log(level, text, *args)

    def wait(self, delay_s: float) -> bool:
        """Between ticks. While the line is stalled, wait on the port itself and resume
        the moment it drains: the far end reads what a pty holds in well under a tick, and
        the stale part must be dropped before it does."""
        end = time.monotonic() + delay_s
        if self.session.stalled and self.link.wait_drained(delay_s):
            self.resume_line()
        return self.sleep(max(0.0, end - time.monotonic()))

    def line_opened(self) -> None:
        self.session.line_opened()

    def send(self, data: bytes) -> Delivered | None:
        """Write the session's bytes and tell it what went out."""
        if not data:
            return None
        written: Written = self.link.write(data)
        delivered = self.session.wrote(written.sent, written.unsure)
        if written.lost:  # what went out before the failure counts; the line is gone
            self.session.line_lost()
        elif delivered.stalled:
            self.stall_began(written, len(data))
        self.stats.stalls = self.session.stalls
        if written.sent or written.unsure:
            self.note_write()
        return delivered

    def final_ticks(self) -> None:
        """usb2rc stops: failsafe frames before the port closes (docs/ICD.md, "Stop"). The
        session marks every frame failsafe; ticks go on at the tick rate until each node's
        `!` (SUMD: one 0x81 frame) went out, or the line cannot take it, and for at most
        FINAL_TICKS_S: a stalled line never holds the stop."""
        self.session.stopping()
        end = time.monotonic() + FINAL_TICKS_S
        while self.session.line_open and not self.session.stop_done:
            self._safe_tick()
            if self.session.stop_done or time.monotonic() + self.period_s > end:
                break
            time.sleep(self.period_s)  # `sleep()` returns at once now: the worker is stopping
        if self.session.line_open and not self.session.stop_done:
            log.warning("%s: stopped before every node's failsafe frame went out", self.name)

    def finish(self) -> None:
        self.link.close()


class C2Output(_LineThread):
    """SERaero C2-16B: startup, service frames, one data frame per node per tick."""

    # The session must know what went out (service frames, message codes); a flush on a
    # pty, where the OS cannot say whether it dropped anything, would leave it guessing.
    drops_unread_each_tick = False

    def __init__(
        self,
        name: str,
        link: SerialLink,
        table: NodeTable,
        settings: C2Settings,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        session = C2Session(settings, name=link.url)
        super().__init__(name, link, session, settings.rate_hz, on_tick, on_first_write)
        self.c2 = session
        self.table = table
        self.settings = settings
        self.subscriber = table.subscribe()
        self.frame_len = session.frame_len
        self.capacity = session.capacity
        # frames the far end sent (RX thread -> this thread): the session answers them
        self.received: queue.SimpleQueue[c2_16b.Frame] = queue.SimpleQueue()
        self._lines_opened = 0

    def line_opened(self) -> None:
        """A fresh line: the startup frame, then the connect sequence of every device.

        On the first line what the table queued since the start goes out too (an unusable
        device's `3`, say); a connect sequence still queued is not asked twice. On a line
        that came back, what was queued for the dead line is superseded."""
        self.c2.line_opened()
        if self._lines_opened:
            self.table.collect(self.subscriber)
        self.table.request_connect_sequences(self.subscriber)
        self._lines_opened += 1

    def tick(self) -> None:
        self.follow_link()
        events, frames = self.table.collect(self.subscriber)
        self._take_received()
        delivered = self.send(self.c2.tick(events, frames))
        self.stats.deferred_nodes = self.c2.deferred_nodes
        statuses = self.c2.statuses
        self.stats.handover_frames = statuses.handover_frames
        self.stats.handovers_cut = statuses.handovers_cut
        self.stats.low_battery_frames = statuses.low_battery_frames
        if delivered is not None:
            self.stats.service_frames += delivered.service_frames
            self.stats.data_frames += delivered.data_frames

    def _take_received(self) -> None:
        if self.received.empty():  # the usual tick: no exception raised and caught
            return
        while True:
            try:
                frame = self.received.get_nowait()
            except queue.Empty:
                return
            self.c2.received(frame)


class ChannelOutput(_LineThread):
    """A channel output (SUMD, CRSF, SBUS): one frame of the configured channels per tick;
    the values are the output's channels' (`usb2rc.protocols.channels.OutputChannels`), the
    frame the session's."""

    def __init__(
        self,
        name: str,
        link: SerialLink,
        table: NodeTable,
        channels: OutputChannels,
        session: FrameLineSession,
        rate_hz: float,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name, link, session, rate_hz, on_tick, on_first_write)
        self.frame_session = session
        self.table = table
        self.channels = channels
        self.subscriber = table.subscribe(events=False)  # its own latch of button taps

    def tick(self) -> None:
        self.follow_link()
        if not self.frame_session.line_open or self.frame_session.stalled:
            return
        values, failsafe = self.channels.evaluate(self.table.frames(self.subscriber))
        self.send(self.frame_session.tick(values, failsafe))


class SumdOutput(ChannelOutput):
    """HoTT SUMD: one frame of the configured channels per tick (100 Hz)."""

    def __init__(
        self,
        name: str,
        link: SerialLink,
        table: NodeTable,
        channels: OutputChannels,
        rate_hz: float = 100.0,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        self.sumd = SumdSession()
        super().__init__(name, link, table, channels, self.sumd, rate_hz, on_tick, on_first_write)


class CrsfOutput(ChannelOutput):
    """CRSF to a transmitter module: RC frames at the module's pace when it gives one; what
    the module sends back comes from the RX thread (`received`, a queue) into the session."""

    def __init__(
        self,
        name: str,
        link: SerialLink,
        table: NodeTable,
        channels: OutputChannels,
        session: CrsfSession,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        rate_hz = 1.0 / session.configured_interval_s
        super().__init__(name, link, table, channels, session, rate_hz, on_tick, on_first_write)
        self.crsf = session
        # bytes the module sent, with when they were read (RX thread -> this thread): at
        # most RX_CHUNKS_QUEUED reads, each within the RX thread's `RxBudget`, so what a
        # tick decodes is bounded however fast the far end sends
        self.received: Handoff[tuple[bytes, float]] = Handoff(RX_CHUNKS_QUEUED)

    def tick(self) -> None:
        for data, at in self.received.take_all():
            self.crsf.received(data, at)
        super().tick()

    def next_due(self, due: float) -> float:
        """The session says when: the module's interval and phase while it sends timing
        corrections, the configured rate otherwise."""
        now = time.monotonic()
        period_s = self.crsf.interval_s(now)
        following = self.crsf.next_send(due, now)
        self._set_pace(self.pace.deadline, period_s)
        return following

    def protocol_stats(self) -> dict[str, Any]:
        """The module's link quality, timing and what was withheld: the figures for
        scripts, and `module`, the line a person reads."""
        session, decoder = self.crsf, self.crsf.decoder
        module_link = session.link  # one read: one report's figures
        link = None if module_link is None else module_link.stats
        return {
            "module": session.link_text(time.monotonic()),
            "link_quality_up": None if link is None else link.uplink_link_quality,
            "link_quality_down": None if link is None else link.downlink_link_quality,
            "frames_withheld": session.withheld,
            "module_rx_frames": decoder.frames,
            "module_rx_crc_failures": decoder.crc_failures,
            "module_rx_skipped": decoder.bytes_skipped,
            "module_rx_reads_dropped": self.received.dropped,
            "timing_corrections": session.timing_frames,
            "timing_corrections_ignored": session.timing_ignored,
        }


class MavlinkOutput(_LineThread):
    """MAVLink: a heartbeat a second and the control message each tick, one write (one
    datagram on UDP) per message; the session decides what a failsafe sends
    (`usb2rc.outputs.mavlink`). What the far end sent reaches the session here, once a
    tick: on UDP read from the socket (non-blocking; udpin locks to the vehicle that called),
    on a serial line from the RX thread (`received`, a queue, as CRSF's)."""

    def __init__(
        self,
        name: str,
        link: SerialLink | UdpLink,
        table: NodeTable,
        channels: MavlinkChannels,
        session: MavlinkSession,
        rate_hz: float = 50.0,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name, link, session, rate_hz, on_tick, on_first_write)
        self.mav = session
        self.table = table
        self.channels = channels
        self.subscriber = table.subscribe(events=False)  # its own latch of button taps
        self._first_in_tick = True
        # bytes a serial far end sent, with when they were read (RX thread -> this thread)
        self.received: queue.SimpleQueue[tuple[bytes, float]] = queue.SimpleQueue()

    def tick(self) -> None:
        self.follow_link()
        if isinstance(self.link, UdpLink):
            self.mav.received(self.link.take_received())
        while True:
            try:
                data, _at = self.received.get_nowait()
            except queue.Empty:
                break
            self.mav.received(data)
        if not self.mav.line_open or self.mav.stalled:
            return
        values = self.channels.evaluate(self.table.frames(self.subscriber))
        self._first_in_tick = True
        for message in self.mav.tick(time.monotonic(), values, time.time()):
            self.send(message)
            if self.mav.stalled or not self.mav.line_open:
                break

    def note_write(self) -> None:
        """Periods are from tick to tick: a heartbeat and the control message go out in
        one tick, a few µs apart, which is not a period."""
        if self._first_in_tick:
            self._first_in_tick = False
            super().note_write()
        else:
            self.stats.writes += 1

    def protocol_stats(self) -> dict[str, Any]:
        from usb2rc.outputs.mavlink import stats_record  # pymavlink: with a MAVLink output

        record = stats_record(self.mav)
        if isinstance(self.link, UdpLink):
            record.update(self.link.counters())
        return record


RX_LINE_SHARE = 2.0  # a far end is read at up to twice what its baud rate carries
RX_BURST_S = 0.1  # ... after a burst of up to 0.1 s of the line (at least RX_BURST_MIN)
RX_BURST_MIN = 4096
RX_CHUNKS_QUEUED = 64  # reads waiting for the output thread (at most RX_BURST_MIN each)
RX_FRAMES_QUEUED = 512  # C2-16B requests waiting for the output thread (2 per Node-ID)


class RxBudget:
    """What an RX thread takes of a far end that sends faster than its line can: a token
    bucket of bytes at RX_LINE_SHARE × the baud rate's bytes per second. A real UART never
    exceeds it; a pty or `socket://` can send without limit, and decoding all of it would
    take the CPU from the output thread. The excess is dropped, unread, and counted."""

    def __init__(self, baudrate: int) -> None:
        self.bytes_per_s = RX_LINE_SHARE * baudrate / BITS_PER_BYTE_ON_WIRE
        self.burst = max(float(RX_BURST_MIN), self.bytes_per_s * RX_BURST_S)
        self.dropped_bytes = 0  # the RX thread writes it, `stats` reads it
        self._tokens = self.burst
        self._at = time.monotonic()

    def admit(self, data: bytes, now: float) -> bytes:
        """The part of `data`, read at `now`, within the budget (its start: the decoder
        resynchronises on the next frame)."""
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.bytes_per_s)
        self._at = now
        taken = min(len(data), int(self._tokens))
        self._tokens -= taken
        self.dropped_bytes += len(data) - taken
        return data[:taken]


class Handoff(Generic[T]):
    """A queue from an RX thread (the only writer) to an output thread (the only reader)
    that holds at most `cap` items: one more is dropped and counted, so a far end never
    grows it without bound while the output thread is busy."""

    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.dropped = 0  # the RX thread writes it, `stats` reads it
        self._queue: queue.SimpleQueue[T] = queue.SimpleQueue()

    def put(self, item: T) -> None:
        if self._queue.qsize() >= self.cap:  # only this thread adds: the check holds
            self.dropped += 1
            return
        self._queue.put(item)

    def take_all(self) -> list[T]:
        """What waits now (at most `cap` items: the output thread's work is bounded)."""
        items: list[T] = []
        if self._queue.empty():  # the usual tick: no exception raised and caught
            return items
        for _ in range(self.cap):
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return items


class ReplyRx(Worker):
    """Reads what the far end of an output sends (a CRSF module's telemetry) and hands the
    bytes, with when they were read, to `on_bytes` (the output thread's queue). At most
    `RxBudget` of them: a far end that floods the line loses the excess here, counted."""

    def __init__(
        self, name: str, link: SerialLink, on_bytes: Callable[[tuple[bytes, float]], None]
    ) -> None:
        super().__init__(name)
        self.link = link
        self.on_bytes = on_bytes
        self.budget = RxBudget(link.baudrate)

    def run(self) -> None:
        while not self.stopping:
            if not self.link.readable:
                self.sleep(0.1)
                continue
            data = self.link.read()
            if not data:
                continue
            now = time.monotonic()
            dropped_before = self.budget.dropped_bytes
            admitted = self.budget.admit(data, now)
            if self.budget.dropped_bytes and not dropped_before:
                self._say_dropping()
            if admitted:
                self.on_bytes((admitted, now))

    def _say_dropping(self) -> None:
        """The first drop is logged; every dropped byte is counted (stats: rx bytes dropped)."""
        log.warning(
            "%s: %s sends faster than %d baud carries; the excess is dropped unread "
            "(counted in stats: rx bytes dropped)",
            self.name,
            self.link.url,
            self.link.baudrate,
        )


class RxThread(ReplyRx):
    """Reads what the far end sends on a C2-16B line and puts each request in `received`
    (the output thread's queue: its session answers `<` and `4` requests). A request past
    RX_FRAMES_QUEUED waiting is dropped and counted (`requests_dropped`): the session answers
    a node at most once a tick anyway."""

    def __init__(
        self,
        name: str,
        link: SerialLink,
        received: queue.SimpleQueue[c2_16b.Frame],
    ) -> None:
        super().__init__(name, link, self._decode)
        self.received = received
        self.decoder = c2_16b.Decoder()
        self.requests = 0
        self.requests_dropped = 0

    def _decode(self, received: tuple[bytes, float]) -> None:
        for frame in self.decoder.feed(received[0]):
            self._hand_over(frame)

    def _hand_over(self, frame: c2_16b.Frame) -> None:
        if not is_request(frame):
            return
        self.requests += 1
        if self.received.qsize() >= RX_FRAMES_QUEUED:  # only this thread adds to it
            self.requests_dropped += 1
            return
        self.received.put(frame)


def is_request(frame: c2_16b.Frame) -> bool:
    """A `<` config request or a `4` poll request: what the far end may ask.

    Byte 4 does not matter (docs/ICD.md, "UART receive"): a `<`'s is the far end's message
    code, a `4`'s a service code, which the ICD leaves TBD; a poll that carries one is still
    a poll, and answering it costs at most one connect sequence (never queued twice)."""
    if isinstance(frame, c2_16b.DataFrame):
        return frame.status == c2_16b.CONFIG_REQUEST
    return frame.service is c2_16b.Service.POLL
