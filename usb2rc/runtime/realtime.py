"""Real-time scheduling for the daemon's threads, where the system grants it.

The outputs' ticks are written on absolute deadlines (usb2rc.lines.driver). At normal
priority any other runnable thread on the CPU can hold a woken tick back for milliseconds:
on a busy host a plain 2 ms sleep loop misses ticks, and so did CRSF at 500 Hz. At a
real-time priority a woken thread runs at once. Every thread of the daemon gets it, not only
the drivers': they share one GIL, and a thread at normal priority preempted while it holds
the GIL holds the drivers' thread back with it (bench/README.md, "CRSF at 500 Hz: the
host's stalls"). SCHED_RR, not SCHED_FIFO: the daemon's threads share one priority, and
round-robin slices them, so none of them can keep the CPU from the others for good.

Best effort: the system may refuse (no CAP_SYS_NICE, RLIMIT_RTPRIO too low, a hardened
service unit); the daemon then runs at normal priority and says why. It never fails to start
for it. Threads made after the request inherit the policy (Linux's default for
pthread_create); the request is made on the thread that starts the others.
"""

from __future__ import annotations

import contextlib
import os
import resource
from dataclasses import dataclass

# The real-time priority: above every normal thread, below the kernel's threaded interrupt
# handlers (50 on PREEMPT_RT kernels), so USB and UART interrupts are still served first.
DEFAULT_PRIORITY = 10
MAX_PRIORITY = 49


@dataclass(frozen=True)
class Scheduling:
    """What the daemon's threads run at: `policy` is "SCHED_RR <priority>" or "normal";
    `reason` says why it is normal (refused, off), empty when real-time."""

    policy: str
    reason: str = ""
    restore: tuple[int, int] | None = None  # the calling thread's (policy, priority) before

    def describe(self) -> str:
        """One line for the log and the stats."""
        return self.policy + (f" ({self.reason})" if self.reason else "")


def request(priority: int) -> Scheduling:
    """SCHED_RR at `priority` for the calling thread, and so for every thread it starts
    after this; 0: not asked. The outcome, with what to restore (`release`)."""
    if priority <= 0:
        return Scheduling("normal", "real-time priority off (--realtime-priority 0)")
    if not hasattr(os, "sched_setscheduler"):
        return Scheduling("normal", "no real-time scheduling on this system")
    try:  # a system call filter may refuse the reads too
        before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority))
    except OSError as exc:
        return Scheduling("normal", refused(exc, priority))
    return Scheduling(f"SCHED_RR {priority}", restore=before)


def release(scheduling: Scheduling) -> None:
    """The calling thread back to what it ran at before `request` (a process that runs
    daemons one after another, as the tests do, is not left real-time)."""
    if scheduling.restore is None:
        return
    policy, priority = scheduling.restore
    with contextlib.suppress(OSError):  # lowering one's own priority is always allowed
        os.sched_setscheduler(0, policy, os.sched_param(priority))


def refused(exc: OSError, priority: int) -> str:
    """Why real-time priority was refused, and what would allow it."""
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    reason = os.strerror(exc.errno) if exc.errno else str(exc)
    return (
        f"real-time priority refused: {reason}; RLIMIT_RTPRIO is {soft}, needs {priority} "
        "or CAP_SYS_NICE: `LimitRTPRIO=` in a systemd unit (systemd/SERVICE.md), `rtprio` in "
        "/etc/security/limits.conf, or run as root; --realtime-priority 0 turns this off"
    )
