"""The daemon's signals, from the first line of usb2rc's code to the process's exit.

`usb2rc/__main__.py` (`python -m usb2rc` and the `usb2rc` script alike) blocks the four
signals below on its first line, before any other import: one that arrives while the modules
load waits, pending, and is handled the moment `install_daemon_signals()` has put every
handler in (right after, before the command is even known). For `usb2rc run` SIGTERM, SIGINT,
SIGHUP and SIGUSR1 never get their default action (which is to kill the process) again; the
other commands get theirs back from `install_command_signals()` as soon as `cli.main` knows
the command.

- starting (until the main loop runs): SIGTERM / SIGINT stop at once with exit status 0
  (SystemExit: nothing that needs stopping has been started yet); SIGHUP and SIGUSR1 are
  kept for the main loop (a reload then re-reads the config, which may have changed after
  start-up read it).
- running: each signal becomes a request in `requests`, read by the main loop. While the
  main loop reloads the config (`abandoned_on_stop()`), a stop also raises ReloadAbandoned
  in it, wherever the reload is: a stop never waits for a parse (docs/ICD.md, "Stop").
- stopping (from the first SIGTERM / SIGINT on): all four are ignored; each one is noted and
  logged by the main loop (`take_ignored`), never from the handler itself, since writing to a
  stream from a handler can fail with a reentrant-call error on the stream.
- exit: the handlers are never given back. CPython resets each signal that has a Python
  handler to SIG_DFL while it finalizes (after atexit), which let a late SIGHUP kill a
  process that had already decided to exit 0; an atexit hook sets them to SIG_IGN instead,
  which finalization leaves alone.

Handlers change only while the four are blocked (`_blocked`). CPython's `signal.signal()`
runs the pending handlers, then changes the action: a signal that lands in between is caught
by the old C handler but finds SIG_IGN or SIG_DFL in place of a Python handler, and CPython
reports `OSError: Signal N ignored due to race condition` (with a traceback) instead of
handling it. Blocked, it waits; SIG_IGN discards it, SIG_DFL gives it its default action. Once
stopping, such a report is taken as one more ignored signal, should anything else meet it.

A signal that arrives before usb2rc's first line (while Python itself starts, some tens of
milliseconds after exec on a PC) gets the default action: nothing in the process can catch or
block it yet. The process then ends by that signal, before it opened anything.

Imports stay light (no logging, no typing): this module loads before anything slow.
"""

from __future__ import annotations

import atexit
import contextlib
import enum
import queue
import signal
import sys
import threading
from collections.abc import Iterator
from types import FrameType

__all__ = [
    "DaemonSignals",
    "Phase",
    "ReloadAbandoned",
    "install_command_signals",
    "install_daemon_signals",
    "stop_at_once",
]


class Phase(enum.Enum):
    STARTING = "starting"
    RUNNING = "running"
    STOPPING = "stopping"


# What each signal asks the main loop for. SIGUSR1 does not exist on Windows.
REQUESTS: dict[int, str] = {
    signal.SIGTERM: "stop",
    signal.SIGINT: "stop",
    **({signal.SIGHUP: "reload"} if hasattr(signal, "SIGHUP") else {}),
    **({signal.SIGUSR1: "stats"} if hasattr(signal, "SIGUSR1") else {}),
}


class ReloadAbandoned(BaseException):
    """A stop came while the main loop reloaded the config: the reload is dropped.

    A BaseException, like KeyboardInterrupt: no `except Exception` in the parse may keep it.
    """


class DaemonSignals:
    """The phase the daemon is in and what its signals asked for.

    `handle` is the signal handler; it only touches the queues and the phase (both safe in a
    handler), except in the starting phase, where a stop raises SystemExit(0).
    """

    def __init__(self) -> None:
        self.phase = Phase.STARTING
        self.requests: queue.SimpleQueue[str] = queue.SimpleQueue()  # put() is reentrant
        self.ignored: queue.SimpleQueue[int] = queue.SimpleQueue()
        self._previous_unraisablehook = sys.unraisablehook
        self._reloading = False  # the main loop is in abandoned_on_stop()

    def handle(self, signum: int, _frame: FrameType | None = None) -> None:
        if self.phase is Phase.STOPPING:
            self.ignored.put(signum)
            return
        what = REQUESTS.get(signum, "")
        if what == "stop":
            starting = self.phase is Phase.STARTING
            self.phase = Phase.STOPPING  # from here on, any further signal is ignored
            if starting:
                raise SystemExit(0)
        self.requests.put(what)
        if what == "stop" and self._reloading:
            self._reloading = False  # once: the handler may run again in the except clause
            raise ReloadAbandoned

    @contextlib.contextmanager
    def abandoned_on_stop(self) -> Iterator[None]:
        """A reload: a stop, now or while it runs, raises ReloadAbandoned out of it.

        The handler runs on the main thread between two bytecodes, so the reload stops at
        once wherever it is (a C call, such as one regular expression, finishes first).
        What runs inside must be safe to leave half-way: reading and checking a config,
        waiting for the lifecycle thread.
        """
        self._reloading = True  # before the check: a stop in between raises in the handler
        try:
            if self.stop_requested:
                raise ReloadAbandoned
            yield
        finally:
            self._reloading = False

    @property
    def stop_requested(self) -> bool:
        return self.phase is Phase.STOPPING

    def running(self) -> bool:
        """The main loop is about to start the daemon: stops are requests from now on.

        False if a stop came while starting whose SystemExit did not end the process: raised
        inside a callback (a weakref's, a __del__), Python reports it and goes on. Then the
        caller stops instead of starting.
        """
        if self.phase is Phase.STARTING:
            self.phase = Phase.RUNNING
        return self.phase is Phase.RUNNING

    def stopping(self) -> None:
        """The main loop is stopping (a request, or an error): ignore every signal."""
        self.phase = Phase.STOPPING

    def take_ignored(self) -> list[str]:
        """The names of the signals ignored while stopping since the last call, to log."""
        names = []
        while True:
            try:
                names.append(signal.Signals(self.ignored.get_nowait()).name)
            except queue.Empty:
                return names

    def _unraisable(self, unraisable: sys.UnraisableHookArgs) -> None:
        if unraisable.exc_type is SystemExit and self.stop_requested:
            return  # our start-up stop, swallowed by a callback: `running()` says so later
        dropped = _dropped_by_race(unraisable)
        if dropped is not None and self.stop_requested:
            self.ignored.put(dropped)  # what the stopping phase does with it anyway
            return
        self._previous_unraisablehook(unraisable)

    def install(self) -> None:
        """Handle every signal in REQUESTS in this process, until it exits. Main thread only.

        All at once: with a SIGTERM handler but no SIGHUP one yet, a SIGTERM followed by a
        SIGHUP would still kill the process. The signals are blocked meanwhile (and since
        `usb2rc/__main__.py`'s first line when started from there): they wait, pending, and
        are handled once every handler is in.
        """
        atexit.register(_ignore_for_good)
        self._previous_unraisablehook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        with _blocked():
            for signum in REQUESTS:
                signal.signal(signum, self.handle)


def _dropped_by_race(unraisable: sys.UnraisableHookArgs) -> int | None:
    """The signal number of CPython's `Signal 15 ignored due to race condition`, else None."""
    head, tail = "Signal ", " ignored due to race condition"
    text = str(unraisable.exc_value)
    if unraisable.exc_type is not OSError or not (text.startswith(head) and text.endswith(tail)):
        return None
    number = text[len(head) : -len(tail)]
    return int(number) if number.isdigit() else None


@contextlib.contextmanager
def _blocked() -> Iterator[None]:
    """The signals in REQUESTS wait while handlers change, and are unblocked after, whatever
    the mask was before (`usb2rc/__main__.py` blocks them first thing)."""
    if not hasattr(signal, "pthread_sigmask"):  # Windows: no SIGHUP either
        yield
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, REQUESTS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, REQUESTS)


def _ignore_for_good() -> None:
    # Runs at exit, before CPython would put the default (fatal) actions back. Stopping
    # first: a stop still pending must not raise SystemExit in here, half-way through.
    if _installed is not None:
        _installed.stopping()
    with _blocked():
        for signum in REQUESTS:
            signal.signal(signum, signal.SIG_IGN)


def stop_at_once(_signum: int, _frame: FrameType | None) -> None:
    """SIGTERM handler until a command has its own: a clean stop, and no signal after it
    may turn that into a death by signal."""
    _ignore_for_good()
    raise SystemExit(0)


_installed: DaemonSignals | None = None


def install_daemon_signals() -> DaemonSignals:
    """The process's DaemonSignals, installed on the first call (idempotent; once a process).

    On another thread than the main one (a test running the main loop) no signal can be
    handled: a fresh, uninstalled DaemonSignals, whose `handle` the caller may call itself.
    """
    global _installed
    if threading.current_thread() is not threading.main_thread():
        return DaemonSignals()
    if _installed is None:
        _installed = DaemonSignals()
        _installed.install()
    return _installed


def install_command_signals() -> None:
    """For the other commands (main thread): SIGTERM is a clean stop, Ctrl-C the usual
    KeyboardInterrupt, SIGHUP / SIGUSR1 their default action. Hands back what
    `usb2rc/__main__.py` installed before the command was known."""
    global _installed
    if _installed is not None:
        atexit.unregister(_ignore_for_good)
        sys.unraisablehook = _installed._previous_unraisablehook
        _installed = None
    with _blocked():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for signum in REQUESTS.keys() - {signal.SIGTERM, signal.SIGINT}:
            signal.signal(signum, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, stop_at_once)
