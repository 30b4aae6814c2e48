"""The serial line: pyserial's `serial_for_url`, reopened every second while it is gone.

Any pyserial URL works (`/dev/serial0`, `socket://host:port`, `spy:///dev/ttyUSB0`,
`loop://`). A missing or vanished port is logged once and retried every second; opening
happens in a helper thread, so a slow open never blocks a tick.

Two threads use a link: the output's writer thread and its RX thread. Only the writer thread
writes, closes and *adopts* a port: the opener publishes a new port, and the writer learns
of it from `line_event()` (OPENED) before it writes anything on it, so the output session
always hears of a new line before its first byte goes out.

A write never blocks a tick and says how many bytes went out (`Written`):
- posix ports (serial ports, ptys): one non-blocking `os.write` on the port's fd;
- `socket://`: one non-blocking `send` on its socket (whose send buffer is kept small);
- other URLs (`loop://`, `rfc2217://`, ...): `port.write` in pieces that fit the write
  timeout; a piece that times out may or may not have gone (`Written.unsure`).
Where the OS reports its transmit queue (serial ports, `loop://`), a write that would push
it past `max_queued_bytes` is skipped (0 bytes); where it does not (ptys, sockets), a write
the OS does not take whole says the far end stopped reading. Either way the writer waits
for `drained()` before it writes again.

Dropping stale bytes: this module only says what the OS lets it drop, the output thread
(`scheduler._LineThread`) decides when. `discard_stale()` drops what the OS holds for the
far end (`tcflush(TCOFLUSH)`, as pyserial's `reset_output_buffer()`) on any posix port: a
serial port's transmit queue, a pty's kernel queue. On a pty that is not all of it: the far
end's own line discipline keeps the first 4095 bytes it did not read, which only the far
end can drop (tests/test_stall_journeys.py::test_what_a_pty_flush_drops). `hides_queue`
says the OS does not tell what waits (a pty): there a write the far end has not taken one
tick later is stale, and only a flush before the next write keeps it off the line.
"""

from __future__ import annotations

import contextlib
import enum
import logging
import os
import queue
import select
import socket
import termios
import threading
import time
from dataclasses import dataclass
from typing import Any

import serial
import serial.serialposix

log = logging.getLogger("usb2rc.serial")

PTY_SLAVE_MAJORS = range(136, 144)  # Linux UNIX98 pty slaves: TIOCOUTQ always reads 0
SOCKET_SEND_BUFFER = 4096  # bytes: what a stalled TCP bridge can hold back from us


@dataclass
class LinkStats:
    bytes_written: int = 0
    writes: int = 0
    writes_skipped_queue_full: int = 0
    write_timeouts: int = 0
    short_writes: int = 0  # the OS took less than the whole write (the far end stalls)
    bytes_read: int = 0
    losses: int = 0
    opens: int = 0
    flushes: int = 0  # the OS queue dropped when a stall began or drained (posix ports)


@dataclass(frozen=True)
class Written:
    """What one write put out: `sent` bytes surely (a prefix), then `unsure` bytes that may
    or may not have gone; `lost`: the write failed and the port is closed."""

    sent: int
    unsure: int = 0
    lost: bool = False


class LineEvent(enum.Enum):
    OPENED = "opened"  # the writer adopted a new port: a fresh line
    LOST = "lost"  # the port failed and is closed


def _out_waiting(port: Any) -> int:
    """pyserial's transmit queue count; ports that cannot say raise (SerialBase lacks it)."""
    return int(port.out_waiting)


def _in_waiting(port: Any) -> int:
    """Bytes received and not read yet (SerialBase lacks the attribute; its ports have it)."""
    return int(port.in_waiting)


def _describe_open_error(url: str, exc: Exception) -> str:
    text = str(exc)
    if "Permission denied" in text or "Errno 13" in text:
        return (
            f"serial port {url}: permission denied. Add the user to the 'dialout' group "
            "(sudo usermod -aG dialout $USER, then log in again) or run as the usb2rc service."
        )
    if "No such file" in text or "Errno 2" in text or "could not open port" in text:
        return (
            f"serial port {url} is not there ({text}). Check the cable / adapter, the path "
            "(ls /dev/serial* /dev/ttyUSB* /dev/ttyACM*) or give another one with --port."
        )
    return f"serial port {url}: {text}"


def _posix_fd(port: serial.SerialBase) -> int | None:
    """The fd to write on directly: a plain posix port (not a `spy://` wrapper, whose own
    write logs what goes out)."""
    if not isinstance(port, serial.serialposix.Serial):
        return None
    if type(port).write is not serial.serialposix.Serial.write:
        return None
    fd = getattr(port, "fd", None)
    return fd if isinstance(fd, int) else None


def _socket_of(port: serial.SerialBase) -> socket.socket | None:
    sock = getattr(port, "_socket", None)  # pyserial's socket:// keeps it non-blocking
    return sock if isinstance(sock, socket.socket) else None


def _is_pty(fd: int) -> bool:
    try:
        return os.major(os.fstat(fd).st_rdev) in PTY_SLAVE_MAJORS
    except OSError:
        return False


class SerialLink:
    """One serial output line, shared by the output's writer thread and its RX thread."""

    def __init__(
        self,
        url: str,
        baudrate: int = 115200,
        *,
        write_timeout_s: float = 0.005,
        max_queued_bytes: int = 4096,
        reopen_interval_s: float = 1.0,
        parity: str = serial.PARITY_NONE,
        stopbits: float = serial.STOPBITS_ONE,
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self.parity = parity  # SBUS: even parity, two stop bits (8E2)
        self.stopbits = stopbits
        self.write_timeout_s = write_timeout_s
        self.max_queued_bytes = max_queued_bytes
        self.reopen_interval_s = reopen_interval_s
        self._opener: threading.Thread | None = None
        self._closing = False
        self.stats = LinkStats()
        self._port: serial.SerialBase | None = None  # published by the opener
        self._adopted: serial.SerialBase | None = None  # the writer's port (writer thread)
        self._queue_known = False  # the adopted port reports its transmit queue
        # A read failure seen by the RX thread: (port, error). Only the writer thread closes
        # the port, so a write never races a close (nor an fd number reused meanwhile).
        self._broken: tuple[serial.SerialBase, BaseException] | None = None
        self._lock = threading.Lock()  # guards _port replacement, not I/O
        self._next_attempt = 0.0
        self._was_lost_logged = False
        self.last_error = ""

    @property
    def is_open(self) -> bool:
        return self._port is not None

    @property
    def readable(self) -> bool:
        port, broken = self._port, self._broken
        return port is not None and (broken is None or broken[0] is not port)

    # --- opening (any thread) ------------------------------------------------------------

    def open_now(self) -> bool:
        """Open the port in this thread (at start). Never raises. The writer still adopts it
        through `line_event()`, so its first tick starts the line with the startup frame."""
        if self._port is not None:
            return True
        self._next_attempt = time.monotonic() + self.reopen_interval_s
        self._open()
        return self._port is not None

    def try_open(self) -> bool:
        """Never blocks: if the port is closed and the retry interval has passed, open it in
        a helper thread (a USB-serial adapter or a TCP bridge can take a while to open) and
        return; the writer adopts it with `line_event()` once it is open."""
        if self._port is not None:
            return True
        now = time.monotonic()
        opener = self._opener
        if now < self._next_attempt or (opener is not None and opener.is_alive()):
            return False
        self._next_attempt = now + self.reopen_interval_s
        self._opener = threading.Thread(target=self._open, name=f"open {self.url}")
        self._opener.start()
        return False

    def _open(self) -> None:
        try:
            port = serial.serial_for_url(
                self.url,
                baudrate=self.baudrate,
                parity=self.parity,
                stopbits=self.stopbits,
                timeout=0.05,
                write_timeout=self.write_timeout_s,
                exclusive=True,
            )
        except Exception as exc:  # whatever a URL handler raises: logged, retried
            self.last_error = _describe_open_error(self.url, exc)
            if not self._was_lost_logged:
                log.error("%s; retrying every %.0f s", self.last_error, self.reopen_interval_s)
                self._was_lost_logged = True
            return
        if self._closing:
            port.close()
            return
        self._limit_socket_buffer(port)
        self.stats.opens += 1
        if self._was_lost_logged:
            log.warning("serial port %s is back", self.url)
        self._was_lost_logged = False
        self.last_error = ""
        with self._lock:
            self._port = port  # one step: the writer adopts it whole, or not yet

    def _limit_socket_buffer(self, port: serial.SerialBase) -> None:
        """A TCP bridge that stops reading holds back what the send buffer holds: keep it
        small, so what comes out after a stall is not seconds old. And send each tick at
        once: Nagle's algorithm would hold a small write back until the bridge acknowledges
        the last one (up to its delayed-ACK time, 40 ms on Linux: several ticks)."""
        sock = _socket_of(port)
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SEND_BUFFER)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    # --- the writer thread ---------------------------------------------------------------

    def line_event(self) -> LineEvent | None:
        """Writer thread, once a tick: OPENED when a new port is there (from now on writes
        go to it), LOST when the RX thread found the adopted port broken; else None."""
        adopted, broken = self._adopted, self._broken
        if adopted is not None and broken is not None and broken[0] is adopted:
            self._lost(broken[1])
            return LineEvent.LOST
        port = self._port
        if port is None or port is adopted:
            return None
        self._adopted = port
        self._queue_known = self._reports_queue(port)
        return LineEvent.OPENED

    def write(self, data: bytes) -> Written:
        """Write one tick's bytes on the adopted port, without blocking the tick."""
        port = self._adopted
        if port is None or not data:
            return Written(0)
        queued = self._queued_bytes(port)
        if queued is not None and queued + len(data) > self.max_queued_bytes:
            self.stats.writes_skipped_queue_full += 1
            return Written(0)
        result = self._put(port, data)
        if result.lost:
            return result
        self.stats.writes += 1
        self.stats.bytes_written += result.sent
        if result.sent < len(data):
            self.stats.short_writes += 1
        return result

    def drained(self) -> bool:
        """After a stall: may the writer write again? With a reported transmit queue, once it
        holds at most half of `max_queued_bytes`; otherwise once the OS takes bytes again
        (the port's fd or socket is writable)."""
        port = self._adopted
        if port is None:
            return False
        queued = self._queued_bytes(port)
        if queued is not None:
            return queued <= self.max_queued_bytes // 2
        handle: int | socket.socket | None = _posix_fd(port)
        if handle is None:
            handle = _socket_of(port)
        if handle is None:
            return True  # nothing to ask: try again
        try:
            return bool(select.select([], [handle], [], 0)[1])
        except (OSError, ValueError):
            return True  # the next write finds out what is wrong

    def discard_stale(self) -> bool:
        """A stall began, or the stalled line drained: drop what the OS still holds for the
        far end; True if it could (the caller must then assume any suffix of what it wrote
        was lost). A posix port can: a serial port's transmit queue (at most two ticks), a
        pty's kernel queue (about 16 KB, frames as old as the stall). Sockets and other URLs
        cannot (False: the caller must assume all of it arrives). Counted in `flushes`."""
        if not self._flush():
            return False
        self.stats.flushes += 1
        return True

    @property
    def hides_queue(self) -> bool:
        """The adopted port is a posix fd whose OS does not say what waits in it (a pty)."""
        port = self._adopted
        return port is not None and not self._queue_known and _posix_fd(port) is not None

    def discard_unread(self) -> bool:
        """Before a tick's write where the OS hides its queue (`hides_queue`, a pty): drop
        what the far end has not taken since the last tick. A far end that reads has the
        kernel hand it the bytes at once, so what is still there is a tick old: it waits
        behind a far end that stopped reading. The OS does not say whether anything was
        there, so this is not counted as a flush. True if it flushed."""
        return self.hides_queue and self._flush()

    def _flush(self) -> bool:
        port = self._adopted
        fd = None if port is None else _posix_fd(port)
        if fd is None:
            return False
        try:
            termios.tcflush(fd, termios.TCOFLUSH)
        except (OSError, termios.error) as exc:
            log.debug("serial port %s: could not drop the stale bytes: %s", self.url, exc)
            return False
        return True

    def wait_drained(self, timeout_s: float) -> bool:
        """`drained()`, but where the OS can say when the fd or socket takes bytes again,
        wait up to timeout_s for it (writer thread, between ticks): a far end reads a pty's
        whole buffer in well under a tick, so a drain seen only at the next tick comes after
        the stale bytes were read."""
        port = self._adopted
        if port is None or self._queue_known:
            return self.drained()
        handle: int | socket.socket | None = _posix_fd(port)
        if handle is None:
            handle = _socket_of(port)
        if handle is None:
            return self.drained()
        try:
            return bool(select.select([], [handle], [], max(0.0, timeout_s))[1])
        except (OSError, ValueError):
            return True  # the next write finds out what is wrong

    def _put(self, port: serial.SerialBase, data: bytes) -> Written:
        """One write; a failure closes the port (`lost`), after what went out before it."""
        fd, sock = _posix_fd(port), _socket_of(port)
        try:
            if fd is not None:
                return Written(os.write(fd, data))  # a failing write(2) writes nothing
            if sock is not None:
                return Written(sock.send(data))
        except BlockingIOError:
            return Written(0)
        except OSError as exc:
            self._lost(exc)
            return Written(0, lost=True)
        return self._put_in_pieces(port, data)

    def _put_in_pieces(self, port: serial.SerialBase, data: bytes) -> Written:
        """`port.write` in pieces the write timeout allows at the baud rate (pyserial's
        `loop://` refuses a longer write outright); a piece that times out is unsure."""
        piece = max(1, int(self.baudrate / 10 * self.write_timeout_s))
        sent = 0
        while sent < len(data):
            chunk = data[sent : sent + piece]
            try:
                port.write(chunk)
            except (serial.SerialTimeoutException, queue.Full):
                self.stats.write_timeouts += 1
                return Written(sent, len(chunk))
            except (serial.SerialException, OSError) as exc:
                self._lost(exc)
                return Written(sent, len(chunk), lost=True)
            sent += len(chunk)
        return Written(sent)

    def _reports_queue(self, port: serial.SerialBase) -> bool:
        fd = _posix_fd(port)
        if fd is not None and _is_pty(fd):
            return False  # a pty's TIOCOUTQ reads 0 whatever waits in it
        if _socket_of(port) is not None:
            return False
        try:
            _out_waiting(port)
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            return False
        return True

    def _queued_bytes(self, port: serial.SerialBase) -> int | None:
        """Bytes in the OS transmit queue, or None where the OS does not tell."""
        if not self._queue_known:
            return None
        try:
            return _out_waiting(port)
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            return None

    def _lost(self, exc: BaseException) -> None:
        with self._lock:
            port, self._port = self._port, None
            self._adopted = None
        if port is None:
            return
        self.stats.losses += 1
        self.last_error = f"serial port {self.url} lost: {exc}"
        log.error("%s; retrying every %.0f s", self.last_error, self.reopen_interval_s)
        self._was_lost_logged = True
        self._next_attempt = time.monotonic() + self.reopen_interval_s
        with contextlib.suppress(serial.SerialException, OSError):
            port.close()

    # --- the RX thread -------------------------------------------------------------------

    def read(self) -> bytes:
        """Whatever arrived (waits up to the port's 50 ms timeout); b'' when closed."""
        port = self._port
        if port is None or not self.readable:
            return b""
        try:
            data: bytes = port.read(max(1, min(_in_waiting(port), 4096)))
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            # TypeError/AttributeError: pyserial's posix read on a port closed under it.
            self._broken = (port, exc)  # the writer closes it and reopens
            return b""
        self.stats.bytes_read += len(data)
        return data

    def close(self) -> None:
        self._closing = True
        opener = self._opener
        if opener is not None and opener is not threading.current_thread():
            opener.join(self.reopen_interval_s)
        with self._lock:
            port, self._port = self._port, None
            self._adopted = None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()
