"""What a far end sends, on a link read on its own thread: read within a budget, handed to the
driver through a bounded queue. The driver passes the bytes to its session
(`session.received(data, now)`) on its own thread: a session is only ever touched by one.

The reader sleeps until bytes arrive: it polls the port's fd beside the link's doorbell,
which the link rings when its port changes (adopted, lost, closed) and the reader's stop
rings too. A far end that sends nothing costs no wake-up at all. A port whose handler has
no fd to poll (pyserial's `loop://`, `rfc2217://`) is read with the handler's own read
timeout instead.
"""

from __future__ import annotations

import logging
import queue
import select
import time
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar

from usb2rc.lines.link import BITS_PER_BYTE_ON_WIRE
from usb2rc.runtime.doorbell import Doorbell
from usb2rc.runtime.token_bucket import TokenBucket
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc.lines")

T = TypeVar("T")
RX_LINE_SHARE = 2.0  # a far end is read at up to twice what its baud rate carries
RX_BURST_S = 0.1  # ... after a burst of up to 0.1 s of the line (at least RX_BURST_MIN)
RX_BURST_MIN = 4096
RX_CHUNKS_QUEUED = 64  # reads waiting for the driver (at most RX_BURST_MIN each)


class RxBudget:
    """What a reader takes of a far end that sends faster than its line can: a token
    bucket of bytes at RX_LINE_SHARE × the baud rate's bytes per second. A real UART never
    exceeds it; a pty or `socket://` can send without limit, and decoding all of it would
    take the CPU from the driver. The excess is dropped, a whole read at a time, and
    counted."""

    def __init__(self, baudrate: int, now: float | None = None) -> None:
        self.bytes_per_s = RX_LINE_SHARE * baudrate / BITS_PER_BYTE_ON_WIRE
        self.burst = max(float(RX_BURST_MIN), self.bytes_per_s * RX_BURST_S)
        self.dropped_bytes = 0  # the reader thread writes it, `stats` reads it
        self._bucket = TokenBucket(
            self.bytes_per_s, self.burst, time.monotonic() if now is None else now
        )

    def admit(self, data: bytes, now: float) -> bytes:
        """`data`, read at `now`, whole while the budget holds it, else nothing (counted).

        Whole reads, not each read's start: a read is the far end's bytes in order, so
        what is taken decodes but for a frame cut at its two ends. The starts of many
        reads, joined, are bytes the far end never sent, and a fast reader's short reads
        leave starts shorter than one frame: a flood then let no request through at all,
        or some, depending on how the reader's and the sender's threads happened to run.
        A read longer than the burst is cut to the burst when the bucket is full."""
        tokens = self._bucket.level(now)
        size = len(data)
        if size > self.burst and tokens >= self.burst:
            self.dropped_bytes += size - int(self.burst)
            data, size = data[: int(self.burst)], int(self.burst)
        if size <= tokens:
            self._bucket.take(now, size)
            return data
        self.dropped_bytes += size
        return b""


class Handoff(Generic[T]):
    """A queue from a reader thread (the only writer) to the driver (the only reader) that
    holds at most `cap` items: one more is dropped and counted, so a far end never grows it
    without bound while the driver is busy."""

    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.dropped = 0  # the reader thread writes it, `stats` reads it
        self._queue: queue.SimpleQueue[T] = queue.SimpleQueue()
        # told after each put (the drivers' thread's wake-up, when it sleeps); set before
        # the reader thread starts
        self.on_put: Callable[[], None] | None = None

    def put(self, item: T) -> None:
        if self._queue.qsize() >= self.cap:  # only this thread adds: the check holds
            self.dropped += 1
            return
        self._queue.put(item)
        if self.on_put is not None:
            self.on_put()

    def take_all(self) -> list[T]:
        """What waits now (at most `cap` items: the driver's work is bounded)."""
        items: list[T] = []
        if self._queue.empty():  # the usual tick: no exception raised and caught
            return items
        for _ in range(self.cap):
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return items


RX_INVALID_FD_WAIT_S = 0.05  # an fd the OS calls invalid: a wait, not a spin, until the bell

_POLL_READY = select.POLLIN | select.POLLPRI | select.POLLERR | select.POLLHUP


class ReadableLink(Protocol):
    url: str
    baudrate: int
    received: Handoff[tuple[bytes, float]]
    doorbell: Doorbell  # rung when the port to read changes (adopted, lost, closed)

    @property
    def readable(self) -> bool: ...
    @property
    def read_fd(self) -> int | None: ...  # polled until `read()` returns at once; None: it waits
    def read(self) -> bytes: ...


class LinkReader(Worker):
    """Reads what the far end of a link sends and hands the bytes, with when they were read,
    to the link's `received` queue (the driver takes them). At most `RxBudget` of them: a far
    end that floods the line loses the excess here, counted."""

    def __init__(self, name: str, link: ReadableLink) -> None:
        super().__init__(name)
        self.link = link
        self.budget = RxBudget(link.baudrate)
        self._poller = select.poll()
        self._poller.register(link.doorbell.fileno(), select.POLLIN)
        self._polled_fd: int | None = None  # the port's fd registered with `_poller`

    def stop(self) -> None:
        super().stop()
        self.link.doorbell.ring()  # after the flag: the woken reader sees it

    def run(self) -> None:
        while not self.stopping:
            if not self._wait_for_bytes():
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
                self.link.received.put((admitted, now))

    def _wait_for_bytes(self) -> bool:
        """Asleep until the port has bytes to read (True), or the doorbell rang (False: the
        port changed, or the stop; the caller looks again). No port: the bell alone."""
        bell = self.link.doorbell
        readable = self.link.readable
        fd = self.link.read_fd if readable else None
        if readable and fd is None:
            return True  # no fd to poll: the handler's read waits (its read timeout)
        self._poll_port(fd)
        events = dict(self._poller.poll())
        if bell.fileno() in events:
            bell.clear()  # before the caller looks at the link: a later ring stays
            return False
        if fd is not None and events.get(fd, 0) & select.POLLNVAL:
            bell.wait(RX_INVALID_FD_WAIT_S)  # closed under us: the bell rings (or rang)
            return False
        return True

    def _poll_port(self, fd: int | None) -> None:
        """`_poller` watches `fd` beside the bell (None: the bell only)."""
        if fd == self._polled_fd:
            return
        if self._polled_fd is not None:
            self._poller.unregister(self._polled_fd)
        if fd is not None:
            self._poller.register(fd, _POLL_READY)
        self._polled_fd = fd

    def _say_dropping(self) -> None:
        """The first drop is logged; every dropped byte is counted (stats: rx bytes dropped)."""
        log.warning(
            "%s: %s sends faster than %d baud carries; the excess is dropped unread "
            "(counted in stats: rx bytes dropped)",
            self.name,
            self.link.url,
            self.link.baudrate,
        )
