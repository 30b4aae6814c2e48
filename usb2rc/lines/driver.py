"""The line drivers: every output's session pumped over its link, all on one thread
(python-can's `Notifier`).

Once a tick, on absolute monotonic deadlines, an output's `LineDriver`
- follows the link: a new port (`session.line_opened()`) before anything is written on it, a
  lost one (`line_lost()`); what the far end sent (`session.received(data, now)`: a serial
  link's reader thread queued it, a UDP link is polled here);
- reports the link's state to the session and carries out what it asks (`Ask.FLUSH`: drop
  what the link holds, then `flush_done`; `Ask.DROP_UNREAD`);
- asks the session for the tick's bytes (`tick(now, snapshot)`), writes them in one
  non-blocking write and tells the session what went (`wrote(sent, unsure)`).
It knows no protocol: what to send, when to stall, when to flush, when the next tick is due
(`session.next_due`) are the session's. A late tick is counted, never caught up with a burst.

One thread drives every output (`DriverThread`). A tick wakes on its deadline, reads the
records and writes its bytes as soon as they are made. Beside others, a session that makes
its ticks ahead (`session.makes_ahead()`: a sending CRSF output, whose module corrects the
frames' phase to the microsecond) makes its bytes `Lead.s` before its deadline (what its
ticks took together, recently) and writes them on it, as a transmitter's mixer runs ahead
of its frame timer; the lead costs every frame's records that much age, and the thread a
second wake-up, which no other output pays. Ticks due together are made together, from one
snapshot: those whose far end times their frames (`session.on_deadline`: C2-16B, CRSF)
first, each written as soon as it is made, so C2-16B's write beside others moves with the
step and its own bytes only, as the only output's does. Threads of their own would queue
for the one interpreter, and C2-16B's write would move with the others' work.

One clock: a driver's ticks fall on the multiples of its period from the grid's epoch on the
monotonic clock (`aligned`, `nodes.step.GRID_EPOCH_S`: 3/4 of a kernel tick, off the kernel's
own), whenever it starts. Outputs whose periods are multiples of one another (the defaults:
20, 10, 4 ms) tick together, on the 4 ms grid of the node step (`nodes.step.BASE_PERIOD_S`),
so the ticks due together share one step. A CRSF output that follows its module's timing
leaves the grid: the module sets its phase (`session.next_due`), to the microsecond.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from usb2rc.lines.link import LineEvent, Link, Written
from usb2rc.lines.session import Ask, LineSession
from usb2rc.nodes.step import aligned
from usb2rc.nodes.table import NodeSnapshot
from usb2rc.runtime.load import CpuMark, MissedTickLog
from usb2rc.runtime.samples import SampleRing
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc.lines")

PERIODS_KEPT = 3000
FINAL_TICKS_S = 0.25  # at most this long for the failsafe frames when usb2rc stops
STALL_LOG_QUIET_S = 10.0  # a line that stalls again and again is logged once in this long
LEAD_FIRST_S = 0.0005  # how long before its deadline a tick starts, until it has measured itself
LEAD_MARGIN_S = 0.0002  # over the tick's recent cost (its p95): a wake-up is often 0.1 ms late
LEAD_MAX_SHARE = 0.25  # never more than a quarter period: the records' age
LEAD_WINDOW = 50  # ticks measured between two updates of the lead
SAME_TICK_S = 0.0005  # starts this close are begun as one batch (< half of 1 kHz)
# While every output is asleep (nothing to send until the nodes change or a far end speaks)
# the thread sleeps until woken, and ticks at least this often anyway: a port lost meanwhile
# is noticed, and the watchdog (`Daemon.all_outputs_ticking`, 1 s) sees it alive.
DOZE_SAFETY_S = 0.5
SAME_DEADLINE_S = 1e-6  # deadlines this close are one (each driver adds its own periods)


class Lead:
    """How long before its deadline a tick starts, so that its bytes are ready on time:
    the p95 of what the last LEAD_WINDOW ticks took from their planned start to their bytes
    and those of the ticks due with them (the wake-up's lateness included), plus
    LEAD_MARGIN_S, at most a quarter period. It follows the machine (a Pi, a VM) and the
    load (devices, outputs), and a single tick held up by the host moves it by nothing. The
    drivers' thread owns it."""

    def __init__(self, period_s: float) -> None:
        self.s = min(LEAD_FIRST_S, period_s * LEAD_MAX_SHARE)
        self._costs: list[float] = []

    def took(self, cost_s: float, period_s: float) -> None:
        """A tick's bytes were ready `cost_s` after its planned start."""
        costs = self._costs
        costs.append(cost_s)
        if len(costs) < LEAD_WINDOW:
            return
        costs.sort()
        p95 = costs[int(len(costs) * 0.95)]
        self.s = min(period_s * LEAD_MAX_SHARE, p95 + LEAD_MARGIN_S)
        costs.clear()


@dataclass
class OutputStats:
    """Counters of one output. The driver writes them; `stats_lines` reads them from
    another thread, so the samples are only read through `periods()` and the others (a
    copy under a lock)."""

    ticks: int = 0
    late_ticks: int = 0
    missed_ticks: int = 0
    writes: int = 0
    tick_errors: int = 0
    stalls: int = 0
    periods_s: SampleRing = field(default_factory=lambda: SampleRing(PERIODS_KEPT))
    # how long each tick took, wake-up to written (a wait for the deadline left out): what
    # a tick costs, whatever the wake-up's jitter (other threads' work, a status client,
    # shows here)
    ticks_s: SampleRing = field(default_factory=lambda: SampleRing(PERIODS_KEPT))
    # each written frame's input age: from the read of the newest report it carries (of a
    # live device) to its write (docs/ICD.md, "Input age")
    input_ages_s: SampleRing = field(default_factory=lambda: SampleRing(PERIODS_KEPT))
    _periods_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add_period(self, period_s: float) -> None:
        with self._periods_lock:
            self.periods_s.append(period_s)

    def add_tick(self, took_s: float) -> None:
        with self._periods_lock:
            self.ticks_s.append(took_s)

    def add_input_age(self, age_s: float) -> None:
        with self._periods_lock:
            self.input_ages_s.append(age_s)

    def input_age_ms(self) -> dict[str, float] | None:
        """p50, p99 and max of the input age of the frames kept, in ms; None: no frame
        carried a live device's report yet."""
        with self._periods_lock:
            ages = sorted(self.input_ages_s.values())
        if not ages:
            return None
        p50, p99 = (ages[min(len(ages) - 1, int(len(ages) * share))] for share in (0.5, 0.99))
        return {"p50": p50 * 1000.0, "p99": p99 * 1000.0, "max": ages[-1] * 1000.0}

    def periods(self) -> list[float]:
        with self._periods_lock:
            return self.periods_s.values()

    def tick_durations(self) -> list[float]:
        with self._periods_lock:
            return self.ticks_s.values()

    def new_periods(self) -> list[float]:
        """The write periods noted since the last call (a bench's window)."""
        with self._periods_lock:
            return self.periods_s.take_new()

    def new_tick_durations(self) -> list[float]:
        """The tick durations noted since the last call."""
        with self._periods_lock:
            return self.ticks_s.take_new()

    def period_p99_error_ms(self, nominal_s: float) -> float:
        return _p99_ms([abs(p - nominal_s) for p in self.periods()])

    def tick_p99_ms(self) -> float:
        return _p99_ms(self.tick_durations())


def _p99_ms(values_s: list[float]) -> float:
    if not values_s:
        return 0.0
    values_s.sort()
    return values_s[min(len(values_s) - 1, int(len(values_s) * 0.99))] * 1000.0


class LineDriver:
    """One output's driver: `session` over `link`, ticked on the grid by the drivers' thread
    (`DriverThread`), whose loop calls `begin` at each tick's start, `write` on its deadline
    and `finish` after the writes due with it.

    `snapshot`: the node table's latest step of the nodes asked for (`NodeTable.step_if_due`,
    asked for those its session reads, or those of every output due with it); `on_tick`
    after every tick (the watchdog hook), `on_first_write` once, after the first write
    that went out.
    `alone`: the daemon's only output. It has no lead (`lead` is None) and writes as soon
    as its bytes are made, as does one whose session does not make its ticks ahead
    (`leads`, decided at each `plan`); beside others, one that does makes them `lead.s`
    ahead and writes them on its deadline. A tick due on the same deadline as one that
    leads is made with it (`DriverThread`) and written on the deadline too.
    Every field is written by the drivers' thread only; `period_s` and `stats` are read by
    others."""

    def __init__(
        self,
        name: str,
        link: Link,
        session: LineSession,
        snapshot: Callable[[frozenset[int] | None], NodeSnapshot],
        period_s: float,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
        alone: bool = False,
    ) -> None:
        self.name = name
        self.link = link
        self.session = session
        self.snapshot = snapshot
        # the period now (a CRSF module may change it: `plan`)
        self.period_s = period_s
        # the only output has no lead: it reads the records on its deadline; beside others,
        # one whose session makes its ticks ahead (`makes_ahead`, asked at each `plan`) starts
        # this lead before the deadline, and so does one whose far end times its frames
        # (`on_deadline`) while another's does (`beside_ahead`: the thread wakes twice a
        # tick then anyway, and a batch started on another's lead could outgrow it)
        self.lead = None if alone else Lead(period_s)
        self.leads = False  # the tick planned starts its lead ahead
        self.beside_ahead = False  # another output's session makes its ticks ahead (the thread's)
        self.stats = OutputStats()
        # a missed tick is said in the log (rate limited), with usb2rc's CPU share
        self._missed_log = MissedTickLog(f"{name} ({link.url})", CpuMark.now())
        self.on_tick = on_tick
        self.on_first_write = on_first_write
        # told when what the far end said changed the session's telemetry (feedback's ring);
        # set before the thread starts
        self.on_telemetry: Callable[[], None] | None = None
        # whoever queues the far end's bytes wakes the drivers' thread (`DriverThread.wake`),
        # so this output may sleep while its session is asleep; set before the thread starts
        self.can_doze = False
        self.asleep = False  # its last tick found its session asleep (and it can doze)
        # its session's line stalled, as this driver's last call (start, write, wait on the
        # link, tick) left it: the only calls that change it; the loop asks at every wake-up
        self.stalled = False
        self.last_tick_monotonic = 0.0
        self._last_write = 0.0
        # bytes went out on this port since its queue was last dropped (`Ask.DROP_UNREAD`): a
        # port nothing was written to since holds nothing of ours to drop (a silent CRSF
        # line asks at every tick)
        self._unread_maybe = True
        self._input_at: float | None = None  # newest report of the tick's snapshot (read at)
        # the tick in progress (this thread only): due, started, made, held for the write
        self._deadline = 0.0
        self._start = 0.0
        self._cost_s = 0.0
        self._ok = True
        self._was_stalled = False
        self._held: bytes | None = None
        # when this driver has something to do next: its write if it holds bytes (`begin`
        # to `write`), else its next start; an attribute, as the loop asks at every wake-up
        self.next_moment = 0.0
        self._logged_errors: set[str] = set()
        self._stalled_since = 0.0
        self._stall_logged_at = -STALL_LOG_QUIET_S
        self._stalls_not_logged = 0

    # --- the loop ----------------------------------------------------------------------------

    def plan(self, deadline: float, period_s: float) -> None:
        """The next tick is due at `deadline`, `period_s` before the one after it (the
        session's: a CRSF module may change it); it starts its lead before it."""
        self._deadline = deadline
        lead, session = self.lead, self.session
        self.leads = lead is not None and (
            session.makes_ahead() or (session.on_deadline and self.beside_ahead)
        )
        self._start = deadline - (lead.s if lead is not None and self.leads else 0.0)
        self.period_s = period_s
        self.next_moment = self._start

    @property
    def deadline(self) -> float:
        """When the next tick, or the one in progress, writes."""
        return self._deadline

    @property
    def start(self) -> float:
        """When the next tick, or the one in progress, was planned to start."""
        return self._start

    @property
    def holding(self) -> bool:
        """Between a tick's start and its write: its bytes are made."""
        return self._held is not None

    def begin(self, snapshot: NodeSnapshot, step_s: float = 0.0) -> None:
        """A tick's start: the link followed, the bytes made from `snapshot` and held for
        the write (an empty tick holds b''). A failure is counted and logged; the tick then
        writes nothing and does not count as alive. `step_s`: what getting the snapshot
        took, counted in this tick's cost (`OutputStats.ticks_s`) as when each output
        stepped the table itself."""
        started = time.monotonic()
        if started - self._start > self.period_s / 2:
            self.stats.late_ticks += 1
        self._input_at = snapshot.newest_report_at
        self._ok = True
        self._was_stalled = self.session.stalled
        try:
            self._held = self._make(snapshot)
        except Exception as exc:
            self._failed(exc)
            self._held = b""
        self.next_moment = self._deadline
        self.asleep = self.can_doze and self._ok and self.session.asleep(snapshot)
        self.stalled = self.session.stalled
        self._cost_s = step_s + time.monotonic() - started

    def write(self) -> None:
        """The tick's write, on its moment (`finish` does the rest: the writes due together
        go out one right after another)."""
        data, self._held = self._held or b"", None
        self.next_moment = self._start
        sent_at = time.monotonic()
        if self._ok:
            try:
                self._write(data, self._was_stalled)
            except Exception as exc:
                self._failed(exc)
        self.stalled = self.session.stalled
        self._cost_s += time.monotonic() - sent_at

    def finish(self) -> None:
        """After the write: the tick counted, then the next one planned (a whole tick lost
        is skipped, never caught up with a burst)."""
        if self._ok:
            self.stats.ticks += 1
            self.last_tick_monotonic = time.monotonic()
            self.stats.add_tick(self._cost_s)
            self._safe_call(self.on_tick)
        now = time.monotonic()
        deadline = self.session.next_due(self._deadline, now)
        period = self.session.period(now)
        behind = time.monotonic() - deadline
        if behind >= 0:
            missed = int(behind // period) + 1
            self.stats.missed_ticks += missed
            self._missed_log.note(missed, self.stats.missed_ticks)
            deadline += missed * period
        elif self._missed_log.unsaid:  # misses since its last line: said once it is due
            self._missed_log.note(0, self.stats.missed_ticks)
        self.plan(deadline, period)

    def _failed(self, exc: Exception) -> None:
        """A bug in a tick is logged (once per kind) and counted, never kills the thread. A
        failed tick does not count as alive, so a driver that keeps failing starves the
        watchdog and systemd restarts it."""
        self._ok = False
        self.stats.tick_errors += 1
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        kind = f"{type(exc).__name__} at {frame.filename}:{frame.lineno}"
        if kind not in self._logged_errors:
            self._logged_errors.add(kind)
            log.exception("%s: tick failed (%s: %s); going on", self.name, kind, exc)

    def wait_while_stalled(self, timeout_s: float) -> None:
        """While the line is stalled, wait on the link itself (up to `timeout_s`) and tell
        the session the moment it takes bytes: the far end reads what a pty holds in well
        under a tick, and the stale part must be dropped before it does."""
        if self.session.stalled and self.link.wait_writable(timeout_s):
            self._follow_backpressure()
        self.stalled = self.session.stalled

    def final_tick(self) -> None:
        """One tick at once while usb2rc stops; a failure is logged and counted."""
        try:
            self.tick()
        except Exception as exc:
            self._failed(exc)

    def _safe_call(self, hook: Callable[[], object] | None) -> None:
        if hook is None:
            return
        try:
            hook()
        except Exception:
            log.exception("%s: hook %r failed", self.name, hook)

    # --- one tick ----------------------------------------------------------------------------

    def tick(self) -> None:
        """One tick at once: the link followed, the bytes made and written (the final
        ticks, and a test's own pace)."""
        was_stalled = self.session.stalled
        self._input_at = None  # the latest step's, unknown here: no age counted
        try:
            self._write(self._make(None), was_stalled)
        finally:
            self.stalled = self.session.stalled

    def _make(self, snapshot: NodeSnapshot | None) -> bytes:
        """The link followed, the backpressure reported, the session's bytes for now from
        `snapshot` (None: the latest step, read after the link was followed)."""
        self._follow_link()
        self._follow_backpressure()
        return self.session.tick(
            time.monotonic(), self.snapshot(self.session.reads) if snapshot is None else snapshot
        )

    def _write(self, data: bytes, was_stalled: bool) -> None:
        written = self._send(data)
        if self.session.stalled and not was_stalled:
            self._stall_began(written, len(data))

    def _follow_link(self) -> None:
        """The line's events, in this thread only: a new port is adopted (and the session
        told) before anything is written on it; what the far end sent goes to the session."""
        link, session = self.link, self.session
        if not link.is_open:
            link.try_open()
        event = link.line_event()
        if event is not None:
            if event is LineEvent.OPENED:
                self._unread_maybe = True  # a port new to this driver: what it holds is unknown
                session.line_opened()
            else:
                session.line_lost()
        told = session.telemetry
        for data, at in link.take_received():
            session.received(data, at)
        if session.telemetry is not told and self.on_telemetry is not None:
            self.on_telemetry()

    def _follow_backpressure(self) -> None:
        """Tell the session what the link holds; carry out what it asks."""
        session = self.session
        was_stalled = session.stalled
        ask = session.link_state(self.link.state(probe_writable=was_stalled))
        if ask is Ask.DROP_UNREAD:
            if self._unread_maybe:
                self._unread_maybe = not self.link.flush(counted=False)
        elif ask is Ask.FLUSH:
            flushed = self.link.flush()
            session.flush_done(flushed)
            if was_stalled and not session.stalled:
                self._say_resumed(flushed)
        elif was_stalled and not session.stalled:
            self._say_resumed(False)

    def _send(self, data: bytes) -> Written:
        """Write the session's bytes and tell it what went out."""
        if not data:
            return Written(0)
        written: Written = self.link.write(data)
        self.session.wrote(written.sent, written.unsure)
        if written.lost:  # what went out before the failure counts; the line is gone
            self.session.line_lost()
        if written.sent or written.unsure:
            self._unread_maybe = True
            self._note_write()
        return written

    def _note_write(self) -> None:
        now = time.monotonic()
        if self._last_write:
            self.stats.add_period(now - self._last_write)
        self._last_write = now
        self.stats.writes += 1
        if self._input_at is not None:
            self.stats.add_input_age(now - self._input_at)
        if self.on_first_write:
            callback, self.on_first_write = self.on_first_write, None
            self._safe_call(callback)

    # --- stalls (the session decides; the driver logs what happened) --------------------------

    def _stall_began(self, written: Written, size: int) -> None:
        """The session stalled the line (a write cut short, or a full queue the link
        reports)."""
        self.stats.stalls += 1
        self._stalled_since = time.monotonic()
        before = self.link.stats.flushes
        self._follow_backpressure()  # a serial port: its queue is dropped at once
        flushed = self.link.stats.flushes > before
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

    def _say_resumed(self, flushed: bool) -> None:
        self._log_stall(
            logging.INFO,
            "%s: %s takes bytes again after %.1f s; %s",
            self.name,
            self.link.url,
            time.monotonic() - self._stalled_since,
            "dropped the stale bytes it held, restarted the line"
            if flushed
            else "resumed with fresh frames",
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

    # --- stop ---------------------------------------------------------------------------------

    @property
    def stopped(self) -> bool:
        """Its failsafe went out, or the line cannot take it: no final tick is owed."""
        return not self.session.line_open or self.session.stop_done

    def protocol_stats(self) -> dict[str, Any]:
        """The session's record and the link's counters (labels: `usb2rc.runtime.stats_text`)."""
        return {**self.session.stats(time.monotonic()), **self.link.counters()}


def _due_with(drivers: list[LineDriver], due: list[float]) -> list[LineDriver]:
    """The drivers (in their order) whose deadline is within SAME_DEADLINE_S of one of
    `due`. Usually every deadline in `due` is one: then a range, with no loop over `due`."""
    low, high = min(due), max(due)
    if high - low <= SAME_DEADLINE_S:  # within both ends' reach: within one's
        low, high = low - SAME_DEADLINE_S, high + SAME_DEADLINE_S
        return [d for d in drivers if low <= d._deadline <= high]
    return [d for d in drivers if any(abs(d._deadline - at) <= SAME_DEADLINE_S for at in due)]


def nodes_read_by(drivers: Sequence[LineDriver]) -> frozenset[int] | None:
    """The nodes these drivers' sessions read (None: every node, if one reads any)."""
    nodes: frozenset[int] = frozenset()
    for driver in drivers:
        reads = driver.session.reads
        if reads is None:
            return None
        nodes |= reads
    return nodes


class DriverThread(Worker):
    """The drivers' thread: every output's ticks, on one thread, in one loop (as
    python-can's `Notifier` serves every bus). A tick starts on its deadline, or its lead
    before it (`LineDriver.leads`), makes its bytes (`begin`) and writes them on the
    deadline (`write`, then `finish`). Ticks due together, the default outputs' every 20
    ms, start together from one snapshot, so the readers are pulled once for all of them,
    and are made and written in order: those whose far end times their frames
    (`session.on_deadline`: C2-16B, CRSF) first, then the others, each group in config
    order. Each is written as soon as it is made once its deadline has come, so C2-16B's
    write beside others waits for the step and its own bytes only, as when it is the only
    output; each tick is counted after all of them went out. Ticks due together start on
    the earliest of their starts: the lead of any of them (which learns what its ticks took
    with those due together), or their deadline when none leads; then all of them are
    held for the deadline."""

    def __init__(self, name: str, drivers: Sequence[LineDriver]) -> None:
        super().__init__(name)
        # the ticks due together are made and written in this order (sorted is stable)
        self.drivers = sorted(drivers, key=lambda driver: not driver.session.on_deadline)
        self._bell = threading.Event()  # wake(): the nodes changed or a far end spoke
        self.dozes = 0  # times every output was asleep and the thread slept until woken
        self._ahead: list[bool] = []  # which drivers' sessions made their ticks ahead, last

    def wake(self) -> None:
        """Something an asleep output may have to answer: a device came or went, the far
        end sent bytes. Any thread; costs nothing while the outputs tick."""
        self._bell.set()

    def stop(self) -> None:
        super().stop()
        self._bell.set()

    def run(self) -> None:
        """Until stopped: the next moment's writes, else its starts; then the final ticks
        and the links closed. A write comes before a start due with it: its moment is the
        one that matters."""
        drivers = self.drivers
        if not drivers:
            return
        now = time.monotonic()
        for driver in drivers:
            driver.plan(aligned(now, driver.period_s), driver.period_s)
        # the flag itself, not `stopping` and `sleep`: Worker's are Python calls, and the loop
        # asks twice a tick
        stop_flag = self._stopping
        while not stop_flag.is_set():
            if all([d.asleep and d._held is None for d in drivers]):
                self._doze()
                continue
            moment = min([driver.next_moment for driver in drivers])
            delay = moment - time.monotonic()
            if delay > 0 and self._wait(delay):
                break
            now = time.monotonic()
            due = [d for d in drivers if d.next_moment <= now and d.holding]
            for driver in due:
                driver.write()
            for driver in due:
                driver.finish()
            if not due:
                self._begin(now)
        self._final_ticks()
        for driver in drivers:
            driver.link.close()

    def _begin(self, now: float) -> None:
        """The ticks that start now, those within SAME_TICK_S after (one batch), and those
        due on the same deadline as any of them (due together: they start with the one that
        leads most), made in order from one snapshot: outputs due together send one
        step's values, and a record a reader publishes meanwhile does not step the table
        again. A tick whose deadline has come is written as soon as it is made; all are
        counted after the batch. Each that started on its own lead teaches it what the
        whole batch took."""
        waiting = [driver for driver in self.drivers if driver._held is None]
        horizon = now + SAME_TICK_S
        starting = [driver for driver in waiting if driver.next_moment <= horizon]
        if not starting:
            return
        batch = _due_with(waiting, [driver._deadline for driver in starting])
        stepping = time.monotonic()
        # the daemon's drivers all read its one node table: the nodes the batch reads
        snapshot = batch[0].snapshot(nodes_read_by(batch))
        step_s = time.monotonic() - stepping
        written: list[LineDriver] = []
        for driver in batch:
            driver.begin(snapshot, step_s)
            now = time.monotonic()
            if driver.next_moment <= now:  # its deadline has come
                # with those made before it and held whose deadline came too (a lead that
                # fell short), in order
                for made in batch:
                    if made.holding and made.next_moment <= now:
                        made.write()
                        written.append(made)
                    if made is driver:
                        break
        ready = time.monotonic()
        self._note_ahead()
        for driver in written:
            driver.finish()
        for driver in starting:
            if driver.lead is not None and driver.leads:
                driver.lead.took(ready - driver.start, driver.period_s)

    def _note_ahead(self) -> None:
        """Tell each driver whether another's session makes its ticks ahead now (for its
        next `plan`)."""
        drivers = self.drivers
        ahead = [d.lead is not None and d.session.makes_ahead() for d in drivers]
        if ahead == self._ahead:
            return
        self._ahead, count = ahead, sum(ahead)
        for driver, its_own in zip(drivers, ahead, strict=True):
            driver.beside_ahead = count > (1 if its_own else 0)

    def _doze(self) -> None:
        """Every output is asleep: sleep until woken (or DOZE_SAFETY_S), then tick again on
        each one's grid. A wake-up that came since the last tick returns at once: it is
        cleared only here, after the sleep, before the ticks that answer it."""
        self.dozes += 1
        self._bell.wait(DOZE_SAFETY_S)
        self._bell.clear()
        now = time.monotonic()
        for driver in self.drivers:
            driver.asleep = False
            driver.plan(aligned(now, driver.period_s), driver.period_s)

    def _wait(self, delay_s: float) -> bool:
        """Asleep until the next moment (awake would hold the GIL from the readers); True
        when stopped. A stalled line is waited on itself: the first for the whole wait,
        any other looked at when it ends (and at every tick)."""
        end = time.monotonic() + delay_s
        for driver in self.drivers:
            if driver.stalled:
                driver.wait_while_stalled(max(0.0, end - time.monotonic()))
        return self._stopping.wait(max(0.0, end - time.monotonic()))

    def _final_ticks(self) -> None:
        """usb2rc stops: each protocol's failsafe before its port closes (docs/ICD.md,
        "Stop"). Each output ticks on at its own rate until its session says its failsafe
        went out, or its line cannot take it, for at most FINAL_TICKS_S in all: a stalled
        line never holds the stop."""
        for driver in self.drivers:
            driver.session.stopping()
        start = time.monotonic()
        end = start + FINAL_TICKS_S
        next_at = {driver.name: start for driver in self.drivers}
        owed = [driver for driver in self.drivers if not driver.stopped]
        while owed:
            now = time.monotonic()
            for driver in owed:
                if next_at[driver.name] <= now:
                    driver.final_tick()
                    next_at[driver.name] = now + driver.period_s
            owed = [d for d in owed if not d.stopped and next_at[d.name] <= end]
            if owed:  # `sleep()` returns at once now: the worker is stopping
                time.sleep(max(0.0, min(next_at[d.name] for d in owed) - time.monotonic()))
        for driver in self.drivers:
            if not driver.stopped:
                log.warning("%s: stopped before every node's failsafe frame went out", driver.name)
