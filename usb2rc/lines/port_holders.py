"""Which process holds a serial port, from /proc: named when the port's lock fails.

usb2rc opens a serial port with an exclusive lock (pyserial's `exclusive=True`, a flock);
when another process holds it, the kernel says only EAGAIN, and the user is left to guess
who. /proc/locks names the pid that holds each lock, with the locked file's device and
inode: that is the process to name (usually a second usb2rc). A port refused for another
reason (EBUSY: its own exclusive mode, TIOCEXCL) has no lock there; then every process with
the port open is named, found through the links under /proc/PID/fd (without root, other
users' processes cannot be read: none may be found). psutil's `open_files()` lists regular
files only, so it cannot answer this.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass

PROC = "/proc"
LOCKS = "/proc/locks"
MAX_COMMAND_CHARS = 160  # a command line longer than this is cut (a log line, not a dump)


@dataclass(frozen=True)
class Holder:
    pid: int
    command: str  # its command line, cut to MAX_COMMAND_CHARS

    def __str__(self) -> str:
        own = ", this usb2rc" if self.pid == os.getpid() else ""
        return f"pid {self.pid} ({self.command}{own})"


def lock_holders(port: str, locks: str = LOCKS) -> list[int]:
    """The pids holding a lock on `port`'s device file (a symlink's target counts)."""
    try:
        info = os.stat(port)
        with open(locks, encoding="ascii", errors="replace") as file:
            lines = file.read().splitlines()
    except OSError:
        return []
    wanted = (os.major(info.st_dev), os.minor(info.st_dev), info.st_ino)
    pids = []
    for line in lines:
        # `1: FLOCK  ADVISORY  WRITE 812 00:1a:4 0 EOF`; a waiter's line has `->` after `1:`
        fields = line.split()
        if len(fields) < 6 or fields[1] == "->" or not fields[4].isdigit():
            continue
        if _locked_file(fields[5]) == wanted:
            pids.append(int(fields[4]))
    return sorted(set(pids))


def _locked_file(field: str) -> tuple[int, int, int] | None:
    """`00:1a:4` (major and minor in hex, inode in decimal) as numbers."""
    parts = field.split(":")
    try:
        return int(parts[0], 16), int(parts[1], 16), int(parts[2])
    except (IndexError, ValueError):
        return None


def port_holders(port: str, proc: str = PROC) -> list[Holder]:
    """Every process with `port` open (the device a symlink names counts), lowest pid first."""
    device = os.path.realpath(port)
    return [
        Holder(pid, command_line(pid, proc))
        for pid in sorted(_pids(proc))
        if _has_open(f"{proc}/{pid}/fd", device)
    ]


def _pids(proc: str) -> Iterator[int]:
    try:
        with os.scandir(proc) as entries:
            yield from (int(e.name) for e in entries if e.name.isdigit())
    except OSError:
        return


def _has_open(fd_dir: str, device: str) -> bool:
    """Whether a link in fd_dir names `device` (unreadable: another user's, or gone)."""
    try:
        with os.scandir(fd_dir) as fds:
            for fd in fds:
                try:
                    if os.readlink(fd.path) == device:
                        return True
                except OSError:
                    continue
    except OSError:
        return False
    return False


def command_line(pid: int, proc: str = PROC) -> str:
    """The process's arguments joined by blanks; `[comm]` when it has none (a kernel
    thread) and `?` when it is gone."""
    try:
        with open(f"{proc}/{pid}/cmdline", "rb") as file:
            arguments = file.read().replace(b"\0", b" ").decode(errors="replace")
        text = " ".join(arguments.split())  # one line: a newline in an argument is a blank
        if not text:
            with open(f"{proc}/{pid}/comm", "rb") as file:
                text = f"[{file.read().strip().decode(errors='replace')}]"
    except OSError:
        return "?"
    if len(text) > MAX_COMMAND_CHARS:
        return text[: MAX_COMMAND_CHARS - 1] + "…"
    return text


def holders_text(port: str) -> str:
    """`locked by pid 812 (...)` and what to do, for the log line of a port held."""
    locking = [Holder(pid, command_line(pid)) for pid in lock_holders(port)]
    if locking:
        who = "locked by " + ", ".join(map(str, locking))
    elif found := port_holders(port):
        who = "open in " + ", ".join(map(str, found))
    else:
        who = f"held by a process this user cannot see (`sudo fuser -v {port}` names it)"
    return (
        f"{who}. A usb2rc service may be running: `sudo systemctl stop usb2rc` stops it; "
        "or give this usb2rc another port"
    )
