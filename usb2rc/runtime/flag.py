"""WakeFlag: a one-way flag that threads sleep on, for the readers' hot paths.

`threading.Event.wait(timeout)` runs a Condition in Python: a new lock, a deque append and
remove, three lock operations, on every call. A reader at 1 kHz sleeps a few hundred times a
second (pacing, and the replay backend's wait for the next report), and each sleep through
an Event costs ~40 % more CPU than one `Lock.acquire(timeout)`, which is what this is: the
lock is held from the start, `set()` releases it, and a waiter that gets it passes it on.
"""

from __future__ import annotations

import threading


class WakeFlag:
    """Like `threading.Event` without `clear()`: `set()` once, `wait()` until it is set."""

    def __init__(self) -> None:
        self._gate = threading.Lock()
        self._gate.acquire()  # held until set(): a waiter blocks on it
        self._guard = threading.Lock()  # two set() calls must not release the gate twice
        self._set = False

    def is_set(self) -> bool:
        return self._set

    def set(self) -> None:
        with self._guard:
            if self._set:
                return
            self._set = True
            self._gate.release()

    def wait(self, timeout_s: float) -> bool:
        """Sleep up to `timeout_s` (≤ 0: do not block); True when the flag is set."""
        if self._set:
            return True
        if self._gate.acquire(True, min(max(timeout_s, 0.0), threading.TIMEOUT_MAX)):
            self._gate.release()  # let every other waiter through as well
            return True
        return self._set
