"""No process a test starts outlives it, whether the test passes or fails.

tests/conftest.py wraps every test: afterwards the harness's own processes that the test left
running (`owned`: the daemon harness registers each DaemonProcess) are stopped as their
harness stops them, and any other process the test started and left running is ended
(SIGTERM, then SIGKILL) and named in an error: a test that starts a process by hand stops it
itself, in a `finally` or a fixture.

"Started by the test" is found from /proc: the descendants of the pytest process that were not
there before the test. The pytest process is made a child subreaper
(PR_SET_CHILD_SUBREAPER), so a process whose parent has gone (a daemon started through `sh -c
'... &'`, `setsid`, a wrapper killed before its child) stays its descendant instead of
passing to init, out of sight.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Protocol

PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h
GRACE_S = 10.0  # for a SIGTERM, then for a SIGKILL: a loaded host may be slow to run them
EXITING_S = 3.0  # for what is already on its way out when the test ends


class Stoppable(Protocol):
    def stop(self) -> object: ...


# What the harnesses started and have not stopped yet (they add and discard themselves)
owned: set[Stoppable] = set()
# The log files of what they started for the running test (shown when it fails)
logs: list[Path] = []


def become_subreaper() -> None:
    """Orphans among this process's descendants become its children, not init's (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def children(pid: int) -> set[int]:
    found: set[int] = set()
    with contextlib.suppress(FileNotFoundError, ProcessLookupError):
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(FileNotFoundError, ProcessLookupError):
                found.update(int(word) for word in (task / "children").read_text().split())
    return found


def descendants(pid: int | None = None) -> set[int]:
    """Every live process below `pid` (this one by default), zombies left out."""
    found: set[int] = set()
    todo = [os.getpid() if pid is None else pid]
    while todo:
        for child in children(todo.pop()) - found:
            found.add(child)
            todo.append(child)
    return {child for child in found if not _gone(child)}


def _gone(pid: int) -> bool:
    """Exited: no such process, or a zombie (its parent reaps it, or reap() does)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True
    return stat.rpartition(")")[2].split()[0] == "Z"


def command_line(pid: int) -> str:
    try:
        words = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except (FileNotFoundError, ProcessLookupError):
        return "(gone)"
    return " ".join(word.decode(errors="replace") for word in words if word)


def stop_owned() -> None:
    """Stop what the harnesses started and the test did not stop, the harness's way."""
    while owned:
        owned.pop().stop()


def still_running(pids: Iterable[int], within_s: float = EXITING_S) -> set[int]:
    """Those of `pids` that have not exited within `within_s`: a process told to stop (a
    tmux server's panes after kill-server, a daemon after its SIGTERM) may take a moment."""
    deadline = time.monotonic() + within_s
    left = {pid for pid in pids if not _gone(pid)}
    while left and time.monotonic() < deadline:
        time.sleep(0.02)
        left = {pid for pid in left if not _gone(pid)}
    return left


def end(pids: Iterable[int]) -> None:
    """SIGTERM, and SIGKILL what is still there after GRACE_S; wait until they are gone."""
    pids = list(pids)
    for signum in (signal.SIGTERM, signal.SIGKILL):
        left = [pid for pid in pids if not _gone(pid)]
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signum)
        deadline = time.monotonic() + GRACE_S
        while any(not _gone(pid) for pid in left) and time.monotonic() < deadline:
            time.sleep(0.02)


def reap(keep: set[int]) -> None:
    """Collect the exit status of exited children but those in `keep` (what started before
    the test: their Popen waits for them): the orphans a subreaper inherits, and what the
    test started and never waited for, would stay zombies until pytest exits."""
    for pid in children(os.getpid()) - keep:
        if _gone(pid):
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, os.WNOHANG)


def pty_writers_outside(pid: int | None = None) -> dict[int, str]:
    """usb2rc processes that write to a pty and are not below `pid` (this process): a test
    run's leftover opens its port's path again, and takes over a pty a test opens next."""
    mine = descendants(pid) | {os.getpid() if pid is None else pid}
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) in mine:
            continue
        command = command_line(int(entry.name))
        if "usb2rc" in command and "/dev/pts/" in command:
            found[int(entry.name)] = command
    return found
