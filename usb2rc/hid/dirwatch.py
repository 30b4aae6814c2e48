"""DirectoryWatch: Linux inotify on one directory, for a thread that sleeps until its entries
change (the replay backend's hot-plug: a file that appears is a plug, one that goes an unplug).

The fd polls readable when a file is created, deleted, moved in or out, closed after a
write, or has its attributes changed; `take()` reads what came and says whether any of it
concerns a name the caller cares about. The directory itself going (deleted, moved,
unmounted) drops the watch: `watch()` sets it again on whatever is at the path then, and
says False while there is nothing to watch (the caller polls meanwhile).

The system calls come from libc through ctypes: Python has no inotify of its own, and three
calls do not justify a dependency. Where they are missing (not Linux, a libc without them)
`DirectoryWatch.create` returns None.
"""

from __future__ import annotations

import ctypes
import errno
import logging
import os
import struct
from collections.abc import Callable
from pathlib import Path

log = logging.getLogger(__name__)

# <sys/inotify.h>
IN_ATTRIB = 0x00000004
IN_CLOSE_WRITE = 0x00000008
IN_MOVED_FROM = 0x00000040
IN_MOVED_TO = 0x00000080
IN_CREATE = 0x00000100
IN_DELETE = 0x00000200
IN_DELETE_SELF = 0x00000400
IN_MOVE_SELF = 0x00000800
IN_UNMOUNT = 0x00002000
IN_Q_OVERFLOW = 0x00004000
IN_IGNORED = 0x00008000
IN_ONLYDIR = 0x01000000

ENTRY_CHANGES = IN_CREATE | IN_DELETE | IN_MOVED_TO | IN_MOVED_FROM | IN_CLOSE_WRITE | IN_ATTRIB
WATCH_MASK = ENTRY_CHANGES | IN_DELETE_SELF | IN_MOVE_SELF | IN_ONLYDIR
# Not about one entry: the directory went, or events were lost. Always a reason to look.
WHOLE_DIRECTORY = IN_DELETE_SELF | IN_MOVE_SELF | IN_UNMOUNT | IN_Q_OVERFLOW | IN_IGNORED

EVENT_HEADER = struct.Struct("iIII")  # wd, mask, cookie, len (of the NUL-padded name)
READ_BYTES = 65536  # many events at once; the kernel returns whole events only


class _Inotify:
    """libc's three calls, or AttributeError/OSError at construction where there are none."""

    def __init__(self) -> None:
        libc = ctypes.CDLL(None, use_errno=True)  # the process's own libc: no ldconfig run
        self.init1 = libc.inotify_init1
        self.init1.argtypes = [ctypes.c_int]
        self.add_watch = libc.inotify_add_watch
        self.add_watch.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_uint32]
        self.rm_watch = libc.inotify_rm_watch
        self.rm_watch.argtypes = [ctypes.c_int, ctypes.c_int]


def _last_error(call: str) -> OSError:
    number = ctypes.get_errno()
    return OSError(number, f"{call}: {os.strerror(number)}")


class DirectoryWatch:
    """The entries of `directory`, watched; `relevant(name)` says which names count (the
    replay backend ignores hidden files, so a file written under a hidden name and renamed
    into place wakes the caller once, at the rename)."""

    def __init__(
        self, calls: _Inotify, fd: int, directory: Path, relevant: Callable[[str], bool]
    ) -> None:
        self._calls = calls
        self._fd = fd
        self.directory = directory
        self._relevant = relevant
        self._wd: int | None = None  # the watch on the directory now, if any
        self._told_unwatched = False

    @classmethod
    def create(
        cls, directory: Path, relevant: Callable[[str], bool] = lambda name: True
    ) -> DirectoryWatch | None:
        """A watch (not set yet: `watch()`), or None where inotify is not available."""
        try:
            calls = _Inotify()
        except (AttributeError, OSError) as exc:
            log.info("no inotify here (%s): %s is polled", exc, directory)
            return None
        fd = calls.init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if fd < 0:
            log.info("%s: %s is polled", _last_error("inotify_init1"), directory)
            return None
        return cls(calls, fd, directory, relevant)

    def fileno(self) -> int:
        return self._fd

    def watch(self) -> bool:
        """Make sure the directory at the path is watched; False when it cannot be (gone,
        not a directory, out of watches): the caller polls until it can. Call it before
        looking at the directory, so no change after the look goes unseen."""
        if self._wd is not None:
            return True
        wd = self._calls.add_watch(self._fd, os.fsencode(self.directory), WATCH_MASK)
        if wd < 0:
            if not self._told_unwatched:
                exc = _last_error("inotify_add_watch")
                log.info("cannot watch %s (%s): polling it until it can be", self.directory, exc)
                self._told_unwatched = True
            return False
        self._wd = wd
        self._told_unwatched = False
        return True

    def take(self) -> bool:
        """Read every event waiting; True when any concerns a relevant name or the whole
        directory (then look again)."""
        changed = False
        while True:
            try:
                data = os.read(self._fd, READ_BYTES)
            except BlockingIOError:
                return changed
            except OSError as exc:
                if exc.errno == errno.EINTR:
                    continue
                raise
            if not data:
                return changed
            changed = self._parse(data) or changed

    def _parse(self, data: bytes) -> bool:
        changed = False
        offset = 0
        while offset + EVENT_HEADER.size <= len(data):
            wd, mask, _cookie, length = EVENT_HEADER.unpack_from(data, offset)
            start = offset + EVENT_HEADER.size
            offset = start + length
            if mask & WHOLE_DIRECTORY:
                self._lost(wd, mask)
                changed = True
            elif length:
                name = os.fsdecode(data[start:offset].rstrip(b"\0"))
                changed = changed or self._relevant(name)
        return changed

    def _lost(self, wd: int, mask: int) -> None:
        """The directory went (deleted, moved away, unmounted): what is at the path from
        now on is watched again by `watch()`. An overflow keeps the watch."""
        if wd != self._wd or not mask & (IN_IGNORED | IN_MOVE_SELF | IN_DELETE_SELF):
            return
        if mask & IN_MOVE_SELF:  # the watch follows the directory, not the path
            self._calls.rm_watch(self._fd, wd)
        self._wd = None

    def close(self) -> None:
        """By the thread that polls it, once it is done with it."""
        os.close(self._fd)
