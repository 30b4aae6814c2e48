"""The serial line: pyserial's `serial_for_url`, reopened every second while it is gone.

Any pyserial URL works (`/dev/serial0`, `socket://host:port`, `spy:///dev/ttyUSB0`,
`loop://`). A missing or vanished port is logged once, retried every second, and reported
back through `take_opened()`; opening happens in a helper thread, so a slow open never
blocks a tick; writes never block a tick for longer than
`write_timeout_s`, and the OS transmit queue is never allowed to grow past `max_queued_bytes`.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from dataclasses import dataclass

import serial

log = logging.getLogger("usb2rc.serial")


@dataclass
class LinkStats:
    bytes_written: int = 0
    writes: int = 0
    writes_skipped_queue_full: int = 0
    write_timeouts: int = 0
    bytes_read: int = 0
    losses: int = 0
    opens: int = 0


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
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self.write_timeout_s = write_timeout_s
        self.max_queued_bytes = max_queued_bytes
        self.reopen_interval_s = reopen_interval_s
        self._opener: threading.Thread | None = None
        self._opened = False
        self._closing = False
        self.stats = LinkStats()
        self._port: serial.SerialBase | None = None
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

    def open_now(self) -> bool:
        """Open the port in this thread (at start). Never raises."""
        if self._port is not None:
            return True
        self._next_attempt = time.monotonic() + self.reopen_interval_s
        self._open()
        self._opened = False  # the first opening: the output starts with its startup frame
        return self._port is not None

    def try_open(self) -> bool:
        """Never blocks: if the port is closed and the retry interval has passed, open it in
        a helper thread (a USB-serial adapter or a TCP bridge can take a while to open) and
        return; the caller sees `is_open` once it is, and `take_opened()` once per opening."""
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

    def take_opened(self) -> bool:
        """True once after each successful opening: the caller starts the line afresh."""
        opened, self._opened = self._opened, False
        return opened

    def _open(self) -> None:
        try:
            port = serial.serial_for_url(
                self.url,
                baudrate=self.baudrate,
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
        self.stats.opens += 1
        if self._was_lost_logged:
            log.warning("serial port %s is back", self.url)
        self._was_lost_logged = False
        self.last_error = ""
        self._opened = True
        with self._lock:
            self._port = port

    def _lost(self, exc: BaseException) -> None:
        with self._lock:
            port, self._port = self._port, None
        if port is None:
            return
        self.stats.losses += 1
        self.last_error = f"serial port {self.url} lost: {exc}"
        log.error("%s; retrying every %.0f s", self.last_error, self.reopen_interval_s)
        self._was_lost_logged = True
        self._next_attempt = time.monotonic() + self.reopen_interval_s
        with contextlib.suppress(serial.SerialException, OSError):
            port.close()

    def _queued_bytes(self, port: serial.SerialBase) -> int:
        try:
            return int(port.out_waiting)
        except (AttributeError, NotImplementedError, serial.SerialException, OSError):
            return 0

    def write(self, data: bytes) -> bool:
        """Write one tick's bytes in one call. False when nothing went out (the port is
        closed, or its transmit queue is full); True when the bytes went (or may have gone)."""
        port = self._port
        if port is None:
            return False
        broken = self._broken
        if broken is not None and broken[0] is port:
            self._lost(broken[1])
            return False
        if self._queued_bytes(port) + len(data) > self.max_queued_bytes:
            self.stats.writes_skipped_queue_full += 1
            return False
        try:
            port.write(data)
        except serial.SerialTimeoutException:
            # Some or all of the bytes may be on the line (pyserial can even time out after
            # writing them all): count them as sent. Sending the same message codes again
            # would duplicate frames; a frame cut short is dropped by the receiver's CRC.
            self.stats.write_timeouts += 1
            return True
        except (serial.SerialException, OSError) as exc:
            self._lost(exc)
            return False
        self.stats.writes += 1
        self.stats.bytes_written += len(data)
        return True

    def read(self) -> bytes:
        """Whatever arrived (waits up to the port's 50 ms timeout); b'' when closed."""
        port = self._port
        if port is None or not self.readable:
            return b""
        try:
            waiting = port.in_waiting
            data = port.read(max(1, min(waiting, 4096)))
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
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()
