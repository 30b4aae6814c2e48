"""The latest status line from the daemon's status socket, for every page at once.

One task reads the socket line by line and keeps the last record; when the daemon stops (the
socket closes or is gone) the record says `"connected": false` and the task tries again every
RETRY_S, so a page shows live data again by itself once the daemon is back."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from typing import Any

log = logging.getLogger("usb2rc.web")

RETRY_S = 0.5
LINE_LIMIT = 4 * 1024 * 1024  # one status line is a few KiB; a runaway one is refused


class StatusFeed:
    """`record()` is the latest status (with `connected`); `wait_newer(seen)` waits for one."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.connected = False
        self.version = 0  # bumped with each new record or change of `connected`
        self.connects = 0  # connections made (a page's "reconnected" note; tests)
        self._record: dict[str, Any] = {}
        self._changed = asyncio.Event()
        self._since = time.monotonic()  # of the last change of `connected`
        self._last_error = ""
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
            state["error"] = self._last_error
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
                reader, writer = await asyncio.open_unix_connection(self.path, limit=LINE_LIMIT)
            except OSError as exc:
                self._disconnected(exc.strerror or str(exc))
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
            self._disconnected("the daemon closed the status socket")
            await asyncio.sleep(RETRY_S)

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

    def _disconnected(self, why: str) -> None:
        if self.connected or why != self._last_error:
            if self.connected:
                log.warning("status socket %s: %s; retrying", self.path, why)
            self.connected, self._since, self._last_error = False, time.monotonic(), why
            self._record = {}
            self._bump()

    def _bump(self) -> None:
        self.version += 1
        self._changed.set()
        self._changed = asyncio.Event()
