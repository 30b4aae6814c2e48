"""sd_notify(3) without a library: readiness, status and watchdog pings to systemd.

`Notifier.from_env()` reads `$NOTIFY_SOCKET` (a path, or `@name` for the abstract namespace)
and `$WATCHDOG_USEC` / `$WATCHDOG_PID`. Outside systemd every method is a no-op returning
False, so callers never need an `if`.

The socket is NON-BLOCKING on purpose: the watchdog is fed from the output threads, and a
blocking datagram socket would stall a tick (and then the whole RC stream) as soon as the
receiver's queue fills. A message that cannot be sent right now is dropped and counted; no
method ever raises.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Mapping

__all__ = ["Notifier"]


def _socket_address(value: str) -> str | None:
    """`$NOTIFY_SOCKET` to an AF_UNIX address; None for anything we do not speak (vsock:)."""
    if value.startswith("/"):
        return value
    if value.startswith("@") and len(value) > 1:
        return "\0" + value[1:]  # abstract namespace
    return None


def _watchdog_usec(env: Mapping[str, str], pid: int) -> int | None:
    """Like sd_watchdog_enabled(): WATCHDOG_USEC > 0, and WATCHDOG_PID (if set) is us."""
    raw_pid = env.get("WATCHDOG_PID")
    if raw_pid is not None:
        try:
            if int(raw_pid) != pid:
                return None
        except ValueError:
            return None
    try:
        usec = int(env.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    return usec if usec > 0 else None


class Notifier:
    """One datagram socket to systemd's notification socket, or nothing.

    Thread-safe: each message is one `sendto()` and the counters sit behind a lock.
    Counters: `sent` (messages systemd's socket accepted), `dropped` (queue full, socket
    gone, refused, too big: anything `sendto()` refused).
    """

    def __init__(self, address: str | None = None, watchdog_usec: int | None = None) -> None:
        self._address = address
        self._watchdog_usec = watchdog_usec
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self.sent = 0
        self.dropped = 0
        if address is not None:
            try:
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            except OSError:
                self._address = None
            else:
                sock.setblocking(False)
                self._sock = sock

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Notifier:
        """Build from `$NOTIFY_SOCKET`, `$WATCHDOG_USEC`, `$WATCHDOG_PID` (os.environ)."""
        env = os.environ if environ is None else environ
        address = _socket_address(env.get("NOTIFY_SOCKET", ""))
        return cls(address, _watchdog_usec(env, os.getpid()))

    @property
    def enabled(self) -> bool:
        """True when running under systemd with a notification socket we can use."""
        return self._sock is not None

    def fileno(self) -> int:
        """The socket's descriptor, -1 when disabled."""
        return -1 if self._sock is None else self._sock.fileno()

    def watchdog_interval_s(self) -> float | None:
        """How often to call `watchdog()`: half of WATCHDOG_USEC; None if no watchdog."""
        if self._sock is None or self._watchdog_usec is None:
            return None
        return self._watchdog_usec / 2_000_000

    def notify(self, message: str) -> bool:
        """Send one raw sd_notify message (`KEY=value` lines). True if the socket took it."""
        sock = self._sock
        if sock is None or self._address is None:
            return False
        try:
            sock.sendto(message.encode("utf-8", "replace"), self._address)
        except OSError:  # EAGAIN (queue full), ECONNREFUSED, ENOENT, EMSGSIZE, EBADF …
            with self._lock:
                self.dropped += 1
            return False
        with self._lock:
            self.sent += 1
        return True

    def ready(self) -> bool:
        return self.notify("READY=1")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """One line for `systemctl status`; newlines would start new fields, so they go."""
        return self.notify("STATUS=" + " ".join(text.splitlines()))

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def reloading(self) -> bool:
        """RELOADING=1 with MONOTONIC_USEC= (systemd >= 253 needs it for Type=notify-reload).

        Send `ready()` again once the reload is done.
        """
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.notify(f"RELOADING=1\nMONOTONIC_USEC={usec}")

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
