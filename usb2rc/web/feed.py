"""The latest status line from the daemon's status socket, for every page at once.

One task reads the socket line by line and keeps the last record; when the daemon stops (the
socket closes or is gone) the record says `"connected": false`, why, and what to do (`hint`,
logged once per reason too), and the task tries again every RETRY_S, so a page shows live
data again by itself once the daemon is back."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import os
import time
from typing import Any

from usb2rc.status_socket import (
    SERVICE_SOCKET,
    NotPrivateError,
    check_private,
    is_user_directory,
    os_reason,
)

log = logging.getLogger("usb2rc.web")

RETRY_S = 0.5
LINE_LIMIT = 4 * 1024 * 1024  # one status line is a few KiB; a runaway one is refused


def hint(path: str, exc: OSError | None, default: bool) -> str:
    """What to do when nothing answers at `path` (exc: why; None: the daemon closed it).
    `default`: the path is `usb2rc run`'s default for this user (no --socket given)."""
    if isinstance(exc, NotPrivateError):
        return f"{os_reason(exc)}; or give --socket PATH"
    if exc is not None and exc.errno in (errno.EACCES, errno.EPERM):
        return (
            f"this user may not connect to {path}: join the daemon's group (the usb2rc "
            "service's: `sudo usermod -aG usb2rc $USER`, then log in again), or run usb2rc "
            "web as the daemon's user"
        )
    service = "" if path == SERVICE_SOCKET else f"; the usb2rc service's is {SERVICE_SOCKET}"
    if default:
        return (
            f"nothing answers at {path}: start the daemon as this user from a shell like "
            "this one (`usb2rc run` puts its status socket there by default), or give "
            f'--socket PATH with the path the daemon logged at start ("status socket: PATH"'
            f"{service})"
        )
    return (
        f"nothing answers at {path}: is the daemon running? It logs "
        f'"status socket: PATH" at start: give that path to --socket{service}'
    )


class StatusFeed:
    """`record()` is the latest status (with `connected`); `wait_newer(seen)` waits for one.
    `default`: `path` is `usb2rc run`'s default (no --socket given; for the hint)."""

    def __init__(self, path: str, default: bool = False) -> None:
        self.path = path
        self.default = default
        self.connected = False
        self.version = 0  # bumped with each new record or change of `connected`
        self.connects = 0  # connections made (a page's "reconnected" note; tests)
        self._record: dict[str, Any] = {}
        self._changed = asyncio.Event()
        self._since = time.monotonic()  # of the last change of `connected`
        self._last_error = ""
        self._hint = ""
        self.closing = False  # set by close(): the live streams end

    def record(self) -> dict[str, Any]:
        """The latest status line, or what is known while the daemon is not there."""
        state = {
            "connected": self.connected,
            "socket": self.path,
            "connects": self.connects,
            "since_s": round(time.monotonic() - self._since, 1),
        }
        if not self.connected:
            state["error"], state["hint"] = self._last_error, self._hint
        return {**self._record, "web": state}

    def close(self) -> None:
        """The server is stopping: every live stream ends at its next wake-up (now)."""
        self.closing = True
        self._bump()

    async def wait_newer(self, seen: int, timeout: float) -> int:
        """The version after `seen`, or `seen` again when none came within `timeout`."""
        if self.version == seen:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), timeout)
        return self.version

    async def run(self) -> None:
        """Read the socket forever, reconnecting (cancel to stop)."""
        while True:
            try:
                reader, writer = await self._connect()
            except OSError as exc:
                self._disconnected(os_reason(exc), exc)
                await asyncio.sleep(RETRY_S)
                continue
            self.connects += 1
            log.info("status socket %s: connected", self.path)
            try:
                await self._read(reader)
            finally:
                writer.close()
                with contextlib.suppress(OSError):
                    await writer.wait_closed()
            self._disconnected("the daemon closed the status socket", None)
            await asyncio.sleep(RETRY_S)

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """Connect; in the user's own folder only while it is private (NotPrivateError):
        whoever else could make it could put a socket of theirs there."""
        directory = os.path.dirname(self.path)
        if is_user_directory(directory) and os.path.lexists(directory):
            check_private(directory)
        return await asyncio.open_unix_connection(self.path, limit=LINE_LIMIT)

    async def _read(self, reader: asyncio.StreamReader) -> None:
        while True:
            try:
                line = await reader.readline()
            except (OSError, ValueError) as exc:  # ValueError: a line over LINE_LIMIT
                log.warning("status socket %s: %s", self.path, exc)
                return
            if not line:
                return
            try:
                record = json.loads(line)
            except ValueError:
                log.warning("status socket %s: a line that is not JSON, skipped", self.path)
                continue
            if not self.connected:
                self.connected, self._since = True, time.monotonic()
            self._record = record
            self._bump()

    def _disconnected(self, why: str, exc: OSError | None) -> None:
        """Not connected: why, and what to do, on the page and once per reason in the log."""
        if self.connected or why != self._last_error:
            self._hint = hint(self.path, exc, self.default)
            log.warning("status socket %s: %s (retrying): %s", self.path, why, self._hint)
            self.connected, self._since, self._last_error = False, time.monotonic(), why
            self._record = {}
            self._bump()

    def _bump(self) -> None:
        self.version += 1
        self._changed.set()
        self._changed = asyncio.Event()
