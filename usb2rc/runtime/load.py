"""The daemon's own load, as a pilot checks a Pi with it: the CPU share it has taken since
it started (every thread, and the drivers' thread alone), and each output's missed ticks
said in the log, rate limited, with that share beside them.

A missed tick (its start came a whole period late: usb2rc.lines.driver skips it, never
catches up with a burst) means the host did not run usb2rc in time: a CPU too busy or too
slow for the config, or a stall of the host. It is counted in the stats and, from here,
never silent in the log.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("usb2rc.load")

# After an output's first missed tick, at most one line per this many seconds (with the
# count since the line before): a host that stalls every few seconds fills no log.
MISSED_LOG_INTERVAL_S = 10.0


@dataclass(frozen=True)
class CpuMark:
    """A moment on the monotonic clock and the process's CPU time (all threads) then."""

    at: float
    process_s: float

    @classmethod
    def now(cls) -> CpuMark:
        return cls(time.monotonic(), time.process_time())

    def share_pct(self, later: CpuMark) -> float | None:
        """The CPU taken from this mark to `later`, in % of one core (None: no time passed)."""
        return share_pct(later.process_s - self.process_s, later.at - self.at)


def share_pct(cpu_s: float | None, elapsed_s: float) -> float | None:
    """CPU time over a wall-clock span, in % of one core (None: not known, no time)."""
    return None if cpu_s is None or elapsed_s <= 0 else cpu_s / elapsed_s * 100


def thread_cpu_s(native_id: int | None) -> float | None:
    """A thread of this process: its CPU time so far, from its schedstat (Linux, ns). None
    where that is not known (another OS, a thread that has not started or has ended)."""
    if native_id is None:
        return None
    try:
        text = Path(f"/proc/self/task/{native_id}/schedstat").read_text()
        return int(text.split()[0]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


class MissedTickLog:
    """One output's missed ticks in the log: the first at once, then at most one line each
    `interval_s`, with how many were missed since the line before. `since`: where the CPU
    share the line gives is counted from (the output's start)."""

    def __init__(
        self,
        name: str,
        since: CpuMark,
        interval_s: float = MISSED_LOG_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
        cpu_mark: Callable[[], CpuMark] = CpuMark.now,
    ) -> None:
        self.name = name
        self.since = since
        self.interval_s = interval_s
        self._clock = clock
        # the CPU share a line gives (all threads' time: a system call), read for the line
        # only: `note` is asked at every tick while a line is owed
        self._cpu_mark = cpu_mark
        self._said_at: float | None = None
        self.unsaid = 0  # missed since the last line: said once the interval is over

    def note(self, missed: int, total: int) -> None:
        """`missed` ticks were just skipped (0: none, but a line may be owed: the driver
        asks at each tick while `unsaid`); `total`: the output's count so far."""
        self.unsaid += missed
        if not self.unsaid:
            return
        now = self._clock()
        if self._said_at is not None and now - self._said_at < self.interval_s:
            return
        before, self._said_at = self._said_at, now
        count, self.unsaid = self.unsaid, 0
        share = self.since.share_pct(self._cpu_mark())
        used = (
            "" if share is None else f"; usb2rc has used {share:.1f} % of a core since it started"
        )
        log.warning(
            "%s: %d tick(s) missed%s (%d since start): a tick's start came a whole period "
            "late, so the host did not run usb2rc in time: a CPU too busy or too slow for "
            "this config (fewer outputs or lower rates help), or a stall of the host%s%s",
            self.name,
            count,
            "" if before is None else f" in the {now - before:.0f} s since the last such line",
            total,
            used,
            "" if before is not None else f" (more: a line every {self.interval_s:g} s at most)",
        )
