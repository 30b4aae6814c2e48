"""The serial line: pyserial's `serial_for_url`, reopened every second while it is gone.

Any pyserial URL works (`/dev/serial0`, `socket://host:port`, `spy:///dev/ttyUSB0`,
`loop://`). A missing or vanished port is logged once and retried every second; opening
happens in a helper thread, so a slow open never blocks a tick.

Two threads use a link: the output's driver thread (the writer) and its reader thread
(`lines.rx.LinkReader`, which hands what it reads to the driver through `received`). Only
the writer writes, closes and *adopts* a port: the opener offers a new port, and the writer
learns of it from `line_event()` (OPENED) before it writes anything on it, so the output
session always hears of a new line before its first byte goes out. Each field has one
writer (`SerialLink`'s docstring); a close waits for a read in progress.

The reader sleeps in `poll` on the port's fd (`read_fd`) until bytes arrive; the writer
rings the link's `doorbell` whenever the port to read changes (adopted; un-adopted, before
it is closed), so the reader never polls a port that is gone for long, nor waits for one
with a timeout.

A write never blocks a tick and says how many bytes went out (`Written`):
- posix ports (serial ports, ptys) and `socket://` (whose send buffer is kept small): one
  non-blocking `os.write` on the port's `fileno()` (`plain_fd`);
- other URLs (`loop://`, `rfc2217://`, ...): `port.write` in pieces that fit the write
  timeout; a piece that times out may or may not have gone (`Written.unsure`).
`state()` reports what the OS holds (`lines.session.LinkState`): the transmit queue where the
OS counts it (serial ports, `loop://`), whether the port can drop it, whether it hides it (a
pty), whether the fd takes bytes. The session decides what to add and when to drop
(`lines.session.Backpressure`); this module only carries it out.

Dropping stale bytes: `flush()` drops what the OS holds for the far end
(`tcflush(TCOFLUSH)`, as pyserial's `reset_output_buffer()`) on any posix port: a serial
port's transmit queue, a pty's kernel queue. On a pty that is not all of it: the far end's
own line discipline keeps the first 4095 bytes it did not read, which only the far end can
drop (tests/test_stall_journeys.py::test_what_a_pty_flush_drops).
"""

from __future__ import annotations

import contextlib
import enum
import errno
import logging
import os
import queue
import select
import socket
import stat
import termios
import threading
import time
from dataclasses import dataclass
from typing import Any

import serial
from serial.urlhandler import protocol_socket

from usb2rc.lines.link import LineEvent, LinkStats, Written
from usb2rc.lines.port_holders import holders_text
from usb2rc.lines.rx import RX_CHUNKS_QUEUED, Handoff
from usb2rc.lines.session import LinkState
from usb2rc.runtime.doorbell import Doorbell

log = logging.getLogger("usb2rc.serial")

SOCKET_SEND_BUFFER = 4096  # bytes: what a stalled TCP bridge can hold back from us
PTY_SLAVE_DIR = "/dev/pts/"  # where Linux names UNIX98 pty slaves (os.ttyname)
PROC_DEVICES = "/proc/devices"  # the kernel's character majors, by driver name
PTY_SLAVE_DRIVERS = ("pts", "ttyp")  # UNIX98 and legacy BSD pty slaves
# While another process holds the port, who it is is looked up (all of /proc) this often:
# once a retry would cost a few ms of Python every second, beside the outputs' ticks.
HOLDERS_RESCAN_S = 30.0


@dataclass(frozen=True)
class _Opened:
    """What one open attempt gave the writer: a port, or why there is none. The opener
    thread only opens; logging, counting and adopting are the writer's."""

    port: serial.SerialBase | None
    error: str = ""


class FdKind(enum.Enum):
    """What a port writes on directly (see `plain_fd`), learnt once at adoption."""

    TTY = "tty"  # a serial port: its OS reports the transmit queue
    PTY = "pty"  # a pty slave: TIOCOUTQ reads 0 whatever waits in it
    SOCKET = "socket"  # socket://: no queue to ask, nothing to flush


@dataclass(frozen=True)
class _Handle:
    """The adopted port and how the writer writes on it (writer thread only)."""

    port: serial.SerialBase
    fd: int | None  # None: through `port.write` (spy://, loop://, rfc2217://)
    kind: FdKind | None
    queue_known: bool  # `port.out_waiting` says what waits (a serial port, loop://)
    read_fd: int | None  # the reader polls it (`read_fd()`); None: it reads with a timeout


# --- what pyserial has no public API for: one function each, held to the real handlers by
# tests/test_pyserial_contract.py ---------------------------------------------------------

# Handlers whose `read` takes the bytes from their fd as they are (pyserial's posix port and
# the `spy://` one built on it, `socket://`): when the fd is readable, a read of what waits
# returns at once, so the reader polls the fd. Others (`loop://`'s queue, `rfc2217://`'s
# own reader thread) are read with their read timeout.
FD_READS = (serial.Serial, protocol_socket.Serial)


def read_fd(port: serial.SerialBase) -> int | None:
    """The fd whose readability says `port.read` returns at once, or None."""
    if not isinstance(port, FD_READS):
        return None
    try:
        fd = port.fileno()
    except (OSError, ValueError, AttributeError):  # io.UnsupportedOperation; closed
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


# Handlers whose `write` puts the bytes on their fd unchanged. pyserial has no public "write
# what the OS takes now and say how much" (its `write` with a write timeout loops until all
# went or raises, the count unknown), so usb2rc writes on the fd itself where that is the
# same bytes: the posix port and socket://. A handler that changes or watches what goes out
# (spy:// logs it, rfc2217:// escapes 0xFF) overrides `write` and is written through it.
PLAIN_WRITES = (serial.Serial.write, protocol_socket.Serial.write)


def plain_fd(port: serial.SerialBase) -> int | None:
    """The fd to write `port`'s bytes on directly, or None: through `port.write`."""
    if getattr(type(port), "write", None) not in PLAIN_WRITES:
        return None
    try:
        fd = port.fileno()  # public on both: the port's fd, the socket's
    except (OSError, ValueError, AttributeError):  # io.UnsupportedOperation; closed
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def fd_kind(fd: int) -> FdKind | None:
    """What the fd is, from the OS: a socket, a pty slave or another tty."""
    try:
        mode = os.fstat(fd).st_mode
    except OSError:
        return None
    if stat.S_ISSOCK(mode):
        return FdKind.SOCKET
    if not stat.S_ISCHR(mode) or not os.isatty(fd):
        return None
    return FdKind.PTY if is_pty(fd) else FdKind.TTY


def is_pty(fd: int) -> bool:
    """A pty slave: named under /dev/pts/, or its major is a pty driver's in /proc/devices
    (a pty from another devpts mount has no name here). No hard-coded majors."""
    with contextlib.suppress(OSError):
        if os.ttyname(fd).startswith(PTY_SLAVE_DIR):
            return True
    try:
        return os.major(os.fstat(fd).st_rdev) in pty_slave_majors()
    except OSError:
        return False


def pty_slave_majors(devices: str = PROC_DEVICES) -> frozenset[int]:
    """The character majors the kernel gives pty slave drivers (empty if unreadable)."""
    majors: set[int] = set()
    with contextlib.suppress(OSError), open(devices, encoding="ascii", errors="replace") as f:
        for line in f:
            if line.strip() == "Block devices:":
                break
            number, _, name = line.strip().partition(" ")
            if number.isdigit() and name in PTY_SLAVE_DRIVERS:
                majors.add(int(number))
    return frozenset(majors)


def _out_waiting(port: Any) -> int:
    """pyserial's transmit queue count; ports that cannot say raise (SerialBase lacks it)."""
    return int(port.out_waiting)


def _in_waiting(port: Any) -> int:
    """Bytes received and not read yet (SerialBase lacks the attribute; its ports have it)."""
    return int(port.in_waiting)


def _describe_open_error(url: str, exc: Exception) -> str:
    """What failed and what to do, as the log line's first part (it goes on with
    "; retrying every 1 s", so no full stop at the end)."""
    text = str(exc)
    if "Permission denied" in text or "Errno 13" in text:
        return (
            f"serial port {url}: permission denied. Add the user to the 'dialout' group "
            "(sudo usermod -aG dialout $USER, then log in again) or run as the usb2rc service"
        )
    if "No such file" in text or "Errno 2" in text or "could not open port" in text:
        return (
            f"serial port {url} is not there ({text}). Check the cable / adapter, the path "
            "(ls /dev/serial* /dev/ttyUSB* /dev/ttyACM*) or give another one with --port"
        )
    return f"serial port {url}: {text}"


def is_held(exc: Exception) -> bool:
    """The open failed because another process has the port: its exclusive lock (flock:
    EAGAIN, pyserial's "Could not exclusively lock port") or the port's own (TIOCEXCL: EBUSY)."""
    number = getattr(exc, "errno", None)
    return number in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY) or (
        "exclusively lock" in str(exc)
    )


def device_path(url: str) -> str:
    """The device a port URL opens: the path itself, or the one under `spy://`."""
    scheme, sep, rest = url.partition("://")
    return rest.partition("?")[0] if sep and scheme.lower() == "spy" else url


class SerialLink:
    """One serial output line, shared by the output's writer thread and its RX thread.

    Who writes what (docs/DESIGN.md, "Threads and what each owns"):
    - the opener thread only opens a port and offers the result (`_offer`, under `_lock`);
    - the writer (driver) thread owns everything else: it takes the offer, adopts the port
      (`_handle`, `_adopted`), writes, logs, counts (`stats`, `last_error`) and closes;
    - the reader thread reads the adopted port, puts what it read in `received` and reports
      a failed read (`_broken`, its only fields besides `stats.bytes_read`); the writer acts
      on it at its next tick.
    A port is closed only under `_port_lock`, which a read holds: a read never runs on a
    closed port. A read on a polled fd returns at once; one through a handler's read
    timeout (50 ms) may delay a close that long. The writer rings `doorbell` after the port
    to read changed and before a port it gave up is closed.
    """

    def __init__(
        self,
        url: str,
        baudrate: int = 115200,
        *,
        write_timeout_s: float = 0.005,
        reopen_interval_s: float = 1.0,
        parity: str = serial.PARITY_NONE,
        stopbits: float = serial.STOPBITS_ONE,
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self.parity = parity  # SBUS: even parity, two stop bits (8E2)
        self.stopbits = stopbits
        self.write_timeout_s = write_timeout_s
        self.reopen_interval_s = reopen_interval_s
        self.stats = LinkStats()
        self.last_error = ""  # writer thread
        # what the reader thread read, with when (reader -> writer, bounded)
        self.received: Handoff[tuple[bytes, float]] = Handoff(RX_CHUNKS_QUEUED)
        self.doorbell = Doorbell()  # wakes the reader: the port to read changed
        self._closing = False  # close() only
        self._lock = threading.Lock()  # guards the offer slot, not I/O
        self._offer: _Opened | None = None  # opener -> writer
        self._held_by: tuple[float, str] | None = None  # opener: who holds the port, when seen
        self._opener: threading.Thread | None = None  # writer thread
        self._handle: _Handle | None = None  # the adopted port (writer thread)
        self._port_lock = threading.Lock()  # a read holds it; a close takes it
        # A read failure seen by the RX thread: (port, error). Only the writer thread closes
        # the port, so a write never races a close (nor an fd number reused meanwhile).
        self._broken: tuple[serial.SerialBase, BaseException] | None = None
        self._next_attempt = 0.0  # writer thread
        self._down_logged = False  # writer thread: the port's absence was logged

    @property
    def _adopted(self) -> serial.SerialBase | None:
        handle = self._handle
        return None if handle is None else handle.port

    @property
    def is_open(self) -> bool:
        """A port is adopted, or opened and waiting for the writer (any thread)."""
        offer = self._offer
        return self._handle is not None or (offer is not None and offer.port is not None)

    @property
    def readable(self) -> bool:
        port, broken = self._adopted, self._broken
        return port is not None and (broken is None or broken[0] is not port)

    @property
    def read_fd(self) -> int | None:
        """The adopted port's fd for the reader to poll; None: no port, or `read()` waits
        with the handler's read timeout."""
        handle = self._handle
        return None if handle is None else handle.read_fd

    # --- opening ---------------------------------------------------------------------------

    def open_now(self) -> bool:
        """Open the port in this thread (at start, before the writer runs). Never raises.
        The writer still adopts it through `line_event()`, so its first tick starts the
        line with the startup frame."""
        if self.is_open:
            return True
        self._next_attempt = time.monotonic() + self.reopen_interval_s
        self._open()
        self._note_failed_open()
        return self.is_open

    def try_open(self) -> bool:
        """Writer thread. Never blocks: if the port is closed and the retry interval has
        passed, open it in a helper thread (a USB-serial adapter or a TCP bridge can take a
        while to open) and return; the writer adopts it with `line_event()` once open."""
        if self.is_open:
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
        """The opener: open, and offer the port (or the error) to the writer; nothing else."""
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
            opened = _Opened(None, self._open_error(exc))
        else:
            if self._closing:
                port.close()
                return
            opened = _Opened(port)
        with self._lock:
            self._offer = opened  # one step: the writer takes it whole, or not yet

    def _open_error(self, exc: Exception) -> str:
        """The opener's description of a failed open; a held port names who holds it
        (looked up at most every HOLDERS_RESCAN_S)."""
        if not is_held(exc):
            return _describe_open_error(self.url, exc)
        now = time.monotonic()
        if self._held_by is None or now - self._held_by[0] >= HOLDERS_RESCAN_S:
            self._held_by = (now, holders_text(device_path(self.url)))
        number = getattr(exc, "errno", None)
        reason = f"[Errno {number}] {os.strerror(number)}" if number else str(exc)
        return (
            f"serial port {self.url} is in use by another process (it cannot be locked: "
            f"{reason}): {self._held_by[1]}"
        )

    def _take_offer(self) -> _Opened | None:
        with self._lock:
            offer, self._offer = self._offer, None
        return offer

    def _note_failed_open(self) -> None:
        """A failed open is logged once, until a port is adopted again."""
        offer = self._offer
        if offer is None or offer.port is not None:
            return
        self._take_offer()
        self.last_error = offer.error
        if not self._down_logged:
            log.error("%s; retrying every %.0f s", self.last_error, self.reopen_interval_s)
            self._down_logged = True

    def _adopt(self, port: serial.SerialBase) -> None:
        fd = plain_fd(port)
        kind = None if fd is None else fd_kind(fd)
        if kind is FdKind.SOCKET and fd is not None:
            _limit_socket_buffer(fd)
        self._handle = _Handle(port, fd, kind, _reports_queue(port, kind), read_fd(port))
        self.doorbell.ring()  # a reader waiting for a port polls this one now
        self.stats.opens += 1
        if self._down_logged:
            log.warning("serial port %s is back", self.url)
        self._down_logged = False
        self.last_error = ""

    # --- the writer thread ---------------------------------------------------------------

    def line_event(self) -> LineEvent | None:
        """Writer thread, once a tick: OPENED when a new port is there (from now on writes
        go to it), LOST when the RX thread found the adopted port broken; else None."""
        adopted, broken = self._adopted, self._broken
        if adopted is not None and broken is not None and broken[0] is adopted:
            self._lost(broken[1])
            return LineEvent.LOST
        self._note_failed_open()
        if self._offer is None:
            return None
        offer = self._take_offer()
        if offer is None or offer.port is None:
            return None
        if adopted is not None:  # a port already adopted (never: try_open waits for a loss)
            self._handle = None
            self.doorbell.ring()
            self._close(adopted)
        self._adopt(offer.port)
        return LineEvent.OPENED

    def write(self, data: bytes) -> Written:
        """Write one tick's bytes on the adopted port, without blocking the tick."""
        handle = self._handle
        if handle is None or not data:
            return Written(0)
        result = self._put(handle, data)
        if result.lost:
            return result
        self.stats.writes += 1
        self.stats.bytes_written += result.sent
        if result.sent < len(data):
            self.stats.short_writes += 1
        return result

    def state(self, probe_writable: bool) -> LinkState:
        """What the OS holds for the far end now; `probe_writable`: ask the fd whether it
        takes bytes (a stalled line's question: one system call, not made every tick)."""
        handle = self._handle
        if handle is None:
            return LinkState(writable=False)
        queued = self._queued_bytes(handle)
        flushable = handle.fd is not None and handle.kind in (FdKind.TTY, FdKind.PTY)
        writable = True
        if probe_writable and queued is None and handle.fd is not None:
            writable = _writable(handle.fd, 0.0)
        return LinkState(queued, flushable, handle.kind is FdKind.PTY, writable)

    def flush(self, counted: bool = True) -> bool:
        """Drop what the OS holds for the far end; True if it could (the caller must then
        assume any suffix of what it wrote was lost). A posix port can: a serial port's
        transmit queue, a pty's kernel queue (about 16 KB). Sockets and other URLs cannot.
        `counted`: a stale queue dropped (`flushes`); not the unread bytes a channel output
        drops on a pty before each tick (the OS does not say whether any were there)."""
        handle = self._handle
        if handle is None or handle.fd is None or handle.kind not in (FdKind.TTY, FdKind.PTY):
            return False
        try:
            termios.tcflush(handle.fd, termios.TCOFLUSH)  # as pyserial's reset_output_buffer
        except (OSError, termios.error) as exc:
            log.debug("serial port %s: could not drop the stale bytes: %s", self.url, exc)
            return False
        if counted:
            self.stats.flushes += 1
        return True

    def wait_writable(self, timeout_s: float) -> bool:
        """Between ticks of a stalled line: wait up to timeout_s for the fd to take bytes
        again, where the OS can say (a pty, a socket; a far end reads a pty's whole buffer
        in well under a tick). False at once where it cannot."""
        handle = self._handle
        if handle is None or handle.queue_known or handle.fd is None:
            return False
        return _writable(handle.fd, max(0.0, timeout_s))

    def take_received(self) -> list[tuple[bytes, float]]:
        """What the reader thread read since the last call (driver thread)."""
        return self.received.take_all()

    def counters(self) -> dict[str, int | str]:
        """The link's own counters for the stats record."""
        return {"rx_bytes": self.stats.bytes_read, "module_rx_reads_dropped": self.received.dropped}

    def _put(self, handle: _Handle, data: bytes) -> Written:
        """One write; a failure closes the port (`lost`), after what went out before it."""
        if handle.fd is None:
            return self._put_in_pieces(handle.port, data)
        try:
            return Written(os.write(handle.fd, data))  # non-blocking; a failure writes nothing
        except BlockingIOError:
            return Written(0)
        except OSError as exc:
            self._lost(exc)
            return Written(0, lost=True)

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

    def _queued_bytes(self, handle: _Handle) -> int | None:
        """Bytes in the OS transmit queue, or None where the OS does not tell."""
        if not handle.queue_known:
            return None
        try:
            return _out_waiting(handle.port)
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            return None

    def _lost(self, exc: BaseException) -> None:
        handle, self._handle = self._handle, None
        if handle is None:
            return
        self.stats.losses += 1
        self.last_error = f"serial port {self.url} lost: {exc}"
        log.error("%s; retrying every %.0f s", self.last_error, self.reopen_interval_s)
        self._down_logged = True
        self._next_attempt = time.monotonic() + self.reopen_interval_s
        self.doorbell.ring()  # the reader lets go of the fd before it is closed
        self._close(handle.port)

    def _close(self, port: serial.SerialBase) -> None:
        """Close a port no thread reads any more: the RX thread reads only the adopted
        port, and only while it holds `_port_lock` (it may still poll the fd: it was rung)."""
        with self._port_lock, contextlib.suppress(serial.SerialException, OSError):
            port.close()

    # --- the RX thread -------------------------------------------------------------------

    def read(self) -> bytes:
        """Whatever arrived (at once when `read_fd` polled readable, else waits up to the
        port's 50 ms timeout); b'' when closed. A failed read is reported to the writer
        (`_broken`), which closes the port."""
        with self._port_lock:
            port = self._adopted  # the writer un-adopts before it closes: this one is open
            if port is None or not self.readable:
                return b""
            try:
                data: bytes = port.read(max(1, min(_in_waiting(port), 4096)))
            except (serial.SerialException, OSError) as exc:
                self._broken = (port, exc)
                return b""
        self.stats.bytes_read += len(data)
        return data

    def close(self) -> None:
        """At stop, by the writer thread (or after it was joined)."""
        self._closing = True
        opener = self._opener
        if opener is not None and opener is not threading.current_thread():
            opener.join(self.reopen_interval_s)
        handle, self._handle = self._handle, None
        offer = self._take_offer()
        self.doorbell.ring()
        if handle is not None:
            self._close(handle.port)
        if offer is not None and offer.port is not None:
            self._close(offer.port)


def _writable(fd: int, timeout_s: float) -> bool:
    try:
        return bool(select.select([], [fd], [], timeout_s)[1])
    except (OSError, ValueError):
        return True  # the next write finds out what is wrong


def _reports_queue(port: serial.SerialBase, kind: FdKind | None) -> bool:
    """Whether `out_waiting` says what waits: not on a pty (TIOCOUTQ reads 0 whatever waits
    in it) nor a socket; elsewhere if the handler has it (SerialBase lacks it)."""
    if kind in (FdKind.PTY, FdKind.SOCKET):
        return False
    try:
        _out_waiting(port)
    except (AttributeError, NotImplementedError, serial.SerialException, OSError):
        return False
    return True


def _limit_socket_buffer(fd: int) -> None:
    """A TCP bridge that stops reading holds back what the send buffer holds: keep it
    small, so what comes out after a stall is not seconds old. And send each tick at
    once: Nagle's algorithm would hold a small write back until the bridge acknowledges
    the last one (up to its delayed-ACK time, 40 ms on Linux: several ticks). pyserial
    gives the socket only as `fileno()`: the options are set through a duplicate of it
    (the same socket; the duplicate is closed at once)."""
    with contextlib.suppress(OSError), socket.socket(fileno=os.dup(fd)) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SEND_BUFFER)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
