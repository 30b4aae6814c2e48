"""The one driver: a thread that pumps any line session over any link (python-can's `Notifier`).

Once a tick, on absolute monotonic deadlines, the driver
- follows the link: a new port (`session.line_opened()`) before anything is written on it, a
  lost one (`line_lost()`); what the far end sent (`session.received(data, now)`: a serial
  link's reader thread queued it, a UDP link is polled here);
- reports the link's state to the session and carries out what it asks (`Ask.FLUSH`: drop
  what the link holds, then `flush_done`; `Ask.DROP_UNREAD`);
- asks the session for the tick's bytes (`tick(now, snapshot)`), writes them in one
  non-blocking write and tells the session what went (`wrote(sent, unsure)`).
It knows no protocol: what to send, when to stall, when to flush, when the next tick is due
(`session.next_due`) are the session's. A late tick is counted, never caught up with a burst.

The daemon's only output (`alone`) wakes on its deadline, reads the records and writes its
bytes as soon as they are made: nothing else ticks then. Outputs due together queue for
one interpreter, so the write of the one that comes last would move with the others' work
(C2-16B's p99 period error 0.9-1.1 ms beside four more outputs): each of several makes its
bytes `Lead.s` before its deadline (its own recent cost) and writes them on it, as a
transmitter's mixer runs ahead of its frame timer. The lead costs every frame's records
that much age (0.3-0.45 ms on the latency), which the only output has no reason to pay
(bench/README.md, "Issue 21: the grid half a kernel tick off the kernel's"). Outputs due
together still woke together for their writes, and the writes queued: each of several
writes `write_offset` after its deadline, WRITE_SPACING_S per output listed before it, so
that the first listed writes on the grid with no write before it, and each other alone
(bench/README.md, "Issue 21: outputs due together write apart"). Their starts, where the
records are read, stay together: the readers wake once for all of them.

One clock: a driver's ticks fall on the multiples of its period from the grid's epoch on the
monotonic clock (`aligned`, `nodes.step.GRID_EPOCH_S`: half a kernel tick, off the kernel's
own), whenever it starts. Outputs whose periods are multiples of
one another (the defaults: 20, 10, 4 ms) tick together, on the 4 ms grid of the node step
(`nodes.step.BASE_PERIOD_S`), so a reader that paces on them (`Daemon._next_tick`, through
`earliest`) wakes once for all of them. A CRSF output that follows its module's timing
leaves the grid: the module sets its phase (`session.next_due`), to the microsecond.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from usb2rc.lines.link import LineEvent, Link, Written
from usb2rc.lines.session import Ask, LineSession
from usb2rc.nodes.step import GRID_EPOCH_S, kernel_tick_s
from usb2rc.nodes.table import NodeSnapshot
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc.lines")

PERIODS_KEPT = 3000
FINAL_TICKS_S = 0.25  # at most this long for the failsafe frames when usb2rc stops
STALL_LOG_QUIET_S = 10.0  # a line that stalls again and again is logged once in this long
LEAD_FIRST_S = 0.0005  # how long before its deadline a tick starts, until it has measured itself
LEAD_MARGIN_S = 0.0002  # over the tick's recent cost (its p95): a wake-up is often 0.1 ms late
LEAD_MAX_SHARE = 0.25  # never more than a quarter period: the records' age
LEAD_WINDOW = 50  # ticks measured between two updates of the lead
SAME_TICK_S = 0.0005  # starts this close are one tick for the readers (< half of 1 kHz)
WRITE_SPACING_S = 0.0005  # outputs due together write this far apart, in config order


def write_offset(index: int, count: int) -> float:
    """How long after its deadline output `index` of `count` writes: WRITE_SPACING_S per
    output listed before it, so that outputs due together never write together (their
    writes queued behind one another, each moved by the others' work: C2-16B, due with four
    outputs, wrote 0.14-0.15 ms after its deadline at p50 and 0.42-0.56 ms at p99, written
    first 0.11 and 0.34-0.35 ms). All of them stay within half a kernel tick of the grid
    (`nodes.step.GRID_EPOCH_S`): closer together on a 1000 Hz kernel. The only output
    writes on its deadline."""
    tick_s = kernel_tick_s()
    spacing = min(WRITE_SPACING_S, tick_s / 2 / count) if tick_s else WRITE_SPACING_S
    return index * spacing


def aligned(now: float, period_s: float) -> float:
    """The first multiple of `period_s` from the grid's epoch at or after `now` (monotonic
    clock, `nodes.step.GRID_EPOCH_S`: half a kernel tick, off the kernel's own ticks)."""
    return GRID_EPOCH_S + math.ceil((now - GRID_EPOCH_S) / period_s - 1e-9) * period_s


@dataclass(frozen=True)
class Pace:
    """When a driver's next tick starts (monotonic: its deadline less its lead, if it has
    one: when it reads the records) and its period now: one value, so a reader pacing on it
    never pairs one tick's start with another's period. Only the driver's own thread
    replaces it, whole."""

    deadline: float
    period_s: float


def earliest(paces: Iterable[Pace], now: float) -> Pace | None:
    """The next tick of any output after `now` (None: no output ticks): what a reader wakes
    for. Its `period_s` is the gap from it to the tick after it, of whichever output: two
    outputs due together (C2-16B's 20 ms and SUMD's 10 ms), or a slower one due sooner
    than the faster one's next, must not send a reader to sleep past a tick (it would miss
    a release, and a tap would show in two frames). Outputs due together start apart, each
    its own lead before the deadline: starts within SAME_TICK_S of the first are one tick
    for the readers (one wake-up, not one per output). A driver between its start and its
    write still shows the start it has passed: its records are read, so its next start
    counts (that past start had made a reader poll through the wait, a drain per report)."""
    ticking = [pace for pace in paces if pace.deadline]
    if not ticking:
        return None
    due = min(_start_after(pace, now) for pace in ticking)
    after = min(_start_after(pace, due + SAME_TICK_S) for pace in ticking)
    return Pace(due, after - due)


def _start_after(pace: Pace, moment: float) -> float:
    """The first start of `pace`'s output after `moment`."""
    if pace.deadline > moment:
        return pace.deadline
    return (
        pace.deadline + (math.floor((moment - pace.deadline) / pace.period_s) + 1) * pace.period_s
    )


class Lead:
    """How long before its deadline a tick starts, so that its bytes are ready on time:
    the p95 of what the last LEAD_WINDOW ticks took from their planned start to their bytes
    (the wake-up's lateness included), plus LEAD_MARGIN_S, at most a quarter period. It
    follows the machine (a Pi, a VM) and the load (devices, outputs), and a single tick held
    up by the host moves it by nothing. One driver thread owns it."""

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
    another thread, so the periods are only read through `periods()` (a copy under a lock:
    iterating the deque while the writer appends would raise)."""

    ticks: int = 0
    late_ticks: int = 0
    missed_ticks: int = 0
    writes: int = 0
    tick_errors: int = 0
    stalls: int = 0
    periods_s: deque[float] = field(default_factory=lambda: deque(maxlen=PERIODS_KEPT))
    # how long each tick took, wake-up to written (a wait for the deadline left out): what
    # a tick costs, whatever the wake-up's jitter (other threads' work, a status client,
    # shows here)
    ticks_s: deque[float] = field(default_factory=lambda: deque(maxlen=PERIODS_KEPT))
    _periods_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add_period(self, period_s: float) -> None:
        with self._periods_lock:
            self.periods_s.append(period_s)

    def add_tick(self, took_s: float) -> None:
        with self._periods_lock:
            self.ticks_s.append(took_s)

    def periods(self) -> list[float]:
        with self._periods_lock:
            return list(self.periods_s)

    def tick_durations(self) -> list[float]:
        with self._periods_lock:
            return list(self.ticks_s)

    def period_p99_error_ms(self, nominal_s: float) -> float:
        return _p99_ms([abs(p - nominal_s) for p in self.periods()])

    def tick_p99_ms(self) -> float:
        return _p99_ms(self.tick_durations())


def _p99_ms(values_s: list[float]) -> float:
    if not values_s:
        return 0.0
    values_s.sort()
    return values_s[min(len(values_s) - 1, int(len(values_s) * 0.99))] * 1000.0


class Driver(Worker):
    """One output: `session` over `link`, ticked on the grid until stopped.

    `snapshot`: the node table's latest step (`NodeTable.step_if_due`); `on_tick` after every
    tick (the watchdog hook), `on_first_write` once, after the first write that went out.
    `alone`: the daemon's only output, which has no lead (`lead` is None) and writes as soon
    as its bytes are made; one of several makes them `lead.s` ahead and writes
    `write_offset_s` after the deadline (`write_offset`). Every field is written by this
    thread only; `pace` and `stats` are read by others."""

    def __init__(
        self,
        name: str,
        link: Link,
        session: LineSession,
        snapshot: Callable[[], NodeSnapshot],
        period_s: float,
        on_tick: Callable[[], None] | None = None,
        on_first_write: Callable[[], None] | None = None,
        alone: bool = False,
        write_offset_s: float = 0.0,
    ) -> None:
        super().__init__(name)
        self.link = link
        self.session = session
        self.snapshot = snapshot
        self.pace = Pace(0.0, period_s)  # deadline 0: not ticking yet
        # the daemon's only output has no lead: it reads the records on its deadline
        self.lead = None if alone else Lead(period_s)
        self.write_offset_s = 0.0 if alone else write_offset_s
        self.stats = OutputStats()
        self.on_tick = on_tick
        self.on_first_write = on_first_write
        self.last_tick_monotonic = 0.0
        self._last_write = 0.0
        self._waited_s = 0.0  # this tick's wait for its deadline, bytes ready
        self._logged_errors: set[str] = set()
        self._stalled_since = 0.0
        self._stall_logged_at = -STALL_LOG_QUIET_S
        self._stalls_not_logged = 0

    @property
    def period_s(self) -> float:
        """The period now (a CRSF module may change it; `pace` has it with its deadline)."""
        return self.pace.period_s

    # --- the loop ----------------------------------------------------------------------------

    def run(self) -> None:
        deadline = aligned(time.monotonic(), self.period_s)
        while not self.stopping:
            start = deadline - (self.lead.s if self.lead else 0.0)
            self.pace = Pace(start, self.period_s)
            delay = start - time.monotonic()
            if delay > 0 and self._wait(delay):
                break
            started = time.monotonic()
            if started - start > self.period_s / 2:
                self.stats.late_ticks += 1
            if self._safe_tick(deadline, start):
                self.stats.ticks += 1
                self.last_tick_monotonic = time.monotonic()
                self.stats.add_tick(self.last_tick_monotonic - started - self._waited_s)
                self._safe_call(self.on_tick)
            now = time.monotonic()
            following = self.session.next_due(deadline, now)
            period = self.session.period(now)
            deadline = following
            behind = time.monotonic() - deadline
            if behind >= 0:  # a whole tick lost: skip it, never burst to catch up
                missed = int(behind // period) + 1
                self.stats.missed_ticks += missed
                deadline += missed * period
            self.pace = Pace(deadline, period)  # readers sample for it
        self._final_ticks()
        self.link.close()

    def _wait(self, delay_s: float) -> bool:
        """Between ticks; True when stopped. While the line is stalled, wait on the link
        itself and tell the session the moment it takes bytes: the far end reads what a
        pty holds in well under a tick, and the stale part must be dropped before it does."""
        end = time.monotonic() + delay_s
        if self.session.stalled and self.link.wait_writable(delay_s):
            self._follow_backpressure()
        return self.sleep(max(0.0, end - time.monotonic()))

    def _safe_tick(self, deadline: float | None = None, start: float = 0.0) -> bool:
        """One tick; a bug in it is logged (once per kind) and counted, never kills the
        thread. A failed tick does not count as alive, so a driver that keeps failing
        starves the watchdog and systemd restarts it."""
        try:
            self.tick(deadline, start)
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

    # --- one tick ----------------------------------------------------------------------------

    def tick(self, deadline: float | None = None, start: float = 0.0) -> None:
        """One tick: the link followed, the bytes made, then written at `deadline` (None:
        at once, as the final ticks are; at once too without a lead: its start was the
        deadline). `start`: when it was planned to begin."""
        self._follow_link()
        self._follow_backpressure()
        was_stalled = self.session.stalled
        data = self.session.tick(time.monotonic(), self.snapshot())
        self._waited_s = 0.0
        if deadline is not None and self.lead is not None:
            self._until(self.lead, deadline, start, bool(data))
        written = self._send(data)
        if self.session.stalled and not was_stalled:
            self._stall_began(written, len(data))

    def _until(self, lead: Lead, deadline: float, start: float, writing: bool) -> None:
        """The bytes are ready: the lead learns what that took; they wait for the deadline
        and this output's write offset (asleep: a wait awake would hold the GIL from the
        other outputs' ticks). A stop during the wait still writes them (the final ticks
        follow)."""
        ready = time.monotonic()
        lead.took(ready - start, self.period_s)
        write_at = deadline + self.write_offset_s
        if writing and write_at > ready:
            self.sleep(write_at - ready)
            # a stop ends the wait early: only what was waited is left out of the tick's time
            self._waited_s = min(write_at, time.monotonic()) - ready

    def _follow_link(self) -> None:
        """The line's events, in this thread only: a new port is adopted (and the session
        told) before anything is written on it; what the far end sent goes to the session."""
        link, session = self.link, self.session
        if not link.is_open:
            link.try_open()
        event = link.line_event()
        if event is not None:
            if event is LineEvent.OPENED:
                session.line_opened()
            else:
                session.line_lost()
        for data, at in link.take_received():
            session.received(data, at)

    def _follow_backpressure(self) -> None:
        """Tell the session what the link holds; carry out what it asks."""
        session = self.session
        was_stalled = session.stalled
        ask = session.link_state(self.link.state(probe_writable=was_stalled))
        if ask is Ask.DROP_UNREAD:
            self.link.flush(counted=False)
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
            self._note_write()
        return written

    def _note_write(self) -> None:
        now = time.monotonic()
        if self._last_write:
            self.stats.add_period(now - self._last_write)
        self._last_write = now
        self.stats.writes += 1
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

    def _final_ticks(self) -> None:
        """usb2rc stops: the protocol's failsafe before the port closes (docs/ICD.md,
        "Stop"). Ticks go on at the tick rate until the session says its failsafe went
        out, or the line cannot take it, and for at most FINAL_TICKS_S: a stalled line
        never holds the stop."""
        session = self.session
        session.stopping()
        end = time.monotonic() + FINAL_TICKS_S
        while session.line_open and not session.stop_done:
            self._safe_tick()
            if session.stop_done or time.monotonic() + self.period_s > end:
                break
            time.sleep(self.period_s)  # `sleep()` returns at once now: the worker is stopping
        if session.line_open and not session.stop_done:
            log.warning("%s: stopped before every node's failsafe frame went out", self.name)

    def protocol_stats(self) -> dict[str, Any]:
        """The session's record and the link's counters (labels: `usb2rc.runtime.stats_text`)."""
        return {**self.session.stats(time.monotonic()), **self.link.counters()}
