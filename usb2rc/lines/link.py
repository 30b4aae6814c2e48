"""The one `Link` protocol every output line is reached through (serial, pty, `socket://`,
`loop://`, `spy://`, UDP), and the small values links and the driver exchange.

A link does IO only: it opens (again every second, in the background, while it is gone),
writes without blocking and says how much went (`Written`), reads, reports what it holds
(`lines.session.LinkState`) and drops it when asked, closes. What to do about a full queue or
a far end that stopped reading is the session's decision (`lines.session.Backpressure`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final, Protocol

from usb2rc.lines.session import LinkState

BITS_PER_BYTE_ON_WIRE = 10  # 8N1: start + 8 data + stop (SBUS: its own, `sbus.BITS_PER_BYTE`)


@dataclass
class LinkStats:
    """A link's counters. Each has one writer: the driver thread, except `bytes_read` (a
    reader thread's, on a link read on its own thread); the stats thread only reads them."""

    bytes_written: int = 0
    writes: int = 0
    writes_skipped_queue_full: int = 0  # UDP: datagrams the OS refused (send buffer full)
    write_timeouts: int = 0
    short_writes: int = 0  # the OS took less than the whole write (the far end stalls)
    bytes_read: int = 0
    losses: int = 0
    opens: int = 0  # ports adopted by the driver
    flushes: int = 0  # the link dropped what it held, when a stall began or drained


class Written:
    """What one write put out: `sent` bytes surely (a prefix), then `unsure` bytes that may
    or may not have gone; `lost`: the write failed and the port is closed. A plain class,
    not a NamedTuple: compiled, one is made in C (a NamedTuple's `__new__` is Python code),
    and one is made at every write."""

    def __init__(self, sent: int, unsure: int = 0, lost: bool = False) -> None:
        self.sent: Final = sent
        self.unsure: Final = unsure
        self.lost: Final = lost

    def __repr__(self) -> str:
        return f"Written(sent={self.sent}, unsure={self.unsure}, lost={self.lost})"


class LineEvent(enum.Enum):
    OPENED = "opened"  # the driver adopted a new port: a fresh line
    LOST = "lost"  # the port failed and is closed


class Link(Protocol):
    """What the driver (`lines.driver.LineDriver`) uses of a link, whatever its kind."""

    url: str
    baudrate: int
    stats: LinkStats
    last_error: str

    @property
    def is_open(self) -> bool: ...
    def open_now(self) -> bool: ...
    def try_open(self) -> bool: ...
    def line_event(self) -> LineEvent | None: ...
    def state(self, probe_writable: bool) -> LinkState: ...
    def write(self, data: bytes) -> Written: ...
    def flush(self, counted: bool = True) -> bool: ...
    def wait_writable(self, timeout_s: float) -> bool: ...
    def take_received(self) -> list[tuple[bytes, float]]: ...
    def counters(self) -> dict[str, int | str]: ...
    def close(self) -> None: ...
