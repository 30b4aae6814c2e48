"""How often a thread wakes, from /proc: its voluntary context switches (it blocked, or woke
from a timed wait), counted over a quiet window. A thread that sleeps until an event costs
none in it; one that polls on a timeout costs one per timeout."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

WAIT_S = 10.0
QUIET_S = 0.5  # the window a sleeping thread is watched in (a 10 Hz poll: 5 wake-ups)
QUIET_WAKEUPS_MAX = 2  # a stray wake-up or two (the thread entering its wait) is not a poll


def voluntary_switches(native_id: int) -> int:
    with open(f"/proc/self/task/{native_id}/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("voluntary_ctxt_switches:"):
                return int(line.split()[1])
    raise AssertionError("no voluntary_ctxt_switches in /proc")


def wakeups_in_quiet_window(thread: threading.Thread) -> int:
    native_id = thread.native_id
    assert native_id is not None, "the thread has not started"
    before = voluntary_switches(native_id)
    threading.Event().wait(QUIET_S)  # the window itself: nothing to wait for in it
    return voluntary_switches(native_id) - before


def until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"never: {what}"
        threading.Event().wait(0.005)
