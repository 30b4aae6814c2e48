"""Doorbell: a file descriptor that a thread blocked in `select`/`poll` wakes on, rung from
any thread.

A thread that waits for a file descriptor (a serial port's bytes, a udev monitor's
uevents, an inotify watch's events) cannot wait on a lock at the same time, and a timeout
that looks at a flag now and then wakes it for nothing many times a second. So whoever
changes what such a thread waits for (a stop, a port adopted or closed, a device to scan
again) rings its doorbell: one byte written to a pipe the thread polls beside its own fd.

Its pipe is closed when the doorbell is collected, never explicitly: a thread still
polling it (one a join gave up on) never polls an fd number that was closed and reused.
"""

from __future__ import annotations

import contextlib
import os
import select
import weakref

DRAIN_BYTES = 65536  # a pipe's whole buffer on Linux: one read empties it


def _close_pipe(read_fd: int, write_fd: int) -> None:
    for fd in (read_fd, write_fd):
        with contextlib.suppress(OSError):
            os.close(fd)


class Doorbell:
    """`ring()` from any thread; a waiter polls `fileno()` with its own fds, and `clear()`s
    the bell after it woke, before it looks at what changed (a ring after the clear
    stays, so no change is missed)."""

    def __init__(self) -> None:
        self._read_fd, self._write_fd = os.pipe()  # both close-on-exec (PEP 446)
        os.set_blocking(self._read_fd, False)
        os.set_blocking(self._write_fd, False)  # a full pipe is rung already
        weakref.finalize(self, _close_pipe, self._read_fd, self._write_fd)

    def fileno(self) -> int:
        return self._read_fd

    def ring(self) -> None:
        with contextlib.suppress(BlockingIOError):
            os.write(self._write_fd, b"\x01")

    def clear(self) -> None:
        with contextlib.suppress(BlockingIOError):
            os.read(self._read_fd, DRAIN_BYTES)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Until the bell rings (True), or `timeout_s` passed (None: no timeout). It stays
        rung: `clear()` it."""
        poller = select.poll()
        poller.register(self._read_fd, select.POLLIN)
        return bool(poller.poll(None if timeout_s is None else max(0, timeout_s) * 1000))
