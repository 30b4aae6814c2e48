"""Worker: the one shape of every usb2rc thread (readers, hot-plug, lifecycle, outputs, demo).

A worker has a name, runs `run()` on its own thread, is asked to stop with `stop()` (which
also ends any `sleep()` at once), and is joined with a deadline. A thread still alive after
its deadline is named in the log: a stop that hangs shows which thread hung, instead of a
process that does not exit.
"""

from __future__ import annotations

import logging
import threading

from usb2rc.runtime.flag import WakeFlag

log = logging.getLogger("usb2rc")


class Worker:
    def __init__(self, name: str) -> None:
        self.name = name
        self._stopping = WakeFlag()
        self._thread = threading.Thread(target=self._main, name=name)

    def run(self) -> None:
        """The thread's work; return when `stopping` is set."""
        raise NotImplementedError

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        """Ask the thread to end; it does at its next `stopping` check or `sleep`."""
        self._stopping.set()

    @property
    def stopping(self) -> bool:
        return self._stopping.is_set()

    def sleep(self, seconds: float) -> bool:
        """Wait up to `seconds`; True (at once) when the worker is asked to stop."""
        return self._stopping.wait(seconds)

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    @property
    def native_id(self) -> int | None:
        """The OS's id of its thread (None before it started)."""
        return self._thread.native_id

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the thread to end (never for itself, never before it started); True
        when it has ended. One that outlives `timeout` is named in the log."""
        if self._thread is threading.current_thread() or self._thread.ident is None:
            return not self._thread.is_alive()
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning(
                "thread %s is still running %s s after it was asked to stop", self.name, timeout
            )
            return False
        return True

    def _main(self) -> None:
        try:
            self.run()
        except Exception:  # a thread must not die without a word
            log.exception("thread %s failed", self.name)
