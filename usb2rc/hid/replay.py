"""Replay backend: every hid-recorder file in a directory is a plugged device.

A file that appears is a plug, a file that goes is an unplug. Files whose names start with
"." are ignored, so write a new file under a hidden name and rename it into place. The
hot-plug thread looks at the directory when inotify says an entry changed
(`change_source()`: created, deleted, renamed, closed after a write, its attributes
changed), or every 0.1 s where inotify is not available. A device
plays its `E:` events with their recorded timing relative to `open()` (scaled by `speed`),
once, then holds until its file goes; `loop=True` replays forever.

A plug does not read the whole recording: the directory scan parses a new file's header
only (descriptor, name, IDs: what `DeviceInfo` needs) and looks for a fault mark (a scan in
1 MB chunks), and a device reads its events from the file as they come due, in its reader's
thread: it holds the open file, its position and one batch of parsed events
(`recording.PACKED_BLOCK_CHARS` of text, packed), never the text nor the events it played
(a loop reads the file again from the top each lap). So a 20 MB recording costs a batch's
memory, and a plug does not parse thousands of lines at once on a thread that shares the
GIL with the outputs (bench/bench_plug_cost.py). The price: an `E:` line that is not valid
is found when its batch is played, not when the file appears. Its device's `read()` then
raises `OSError(EIO)` naming the line, after the events before it (the daemon sends `3`,
read failed), and from then on the file is listed in `problems` instead of as a device.

A device costs what the kernel's hidraw queue costs a real one: no thread of its own, no
wake-up per report. `read` hands over the next report if it is due; `read_due` every
report due, in one call to the batch in play (`recording.PlayedEvents.take`); only when
none is due does `read` wait (a plain timed wait on the close flag) until the next one's
time.

Outputs: `open_output()` gives a port that takes every write (nothing is refused) and counts
them, keeping the last few (`ReplayOutputPort.last`) for tests and the monitor.

Fault injection: a comment line `# usb2rc-fault: read-error at SECONDS` makes `read()` raise
`OSError(EIO)` once the events before SECONDS are delivered.
"""

from __future__ import annotations

import errno
import io
import logging
import math
import os
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from usb2rc.hid.backend import BUS_BLUETOOTH, BUS_USB, DeviceGone, DeviceInfo, DeviceOpenError
from usb2rc.hid.descriptor import top_level_usage
from usb2rc.hid.dirwatch import DirectoryWatch
from usb2rc.hid.outputs import OutputWrite
from usb2rc.hid.recording import (
    EventList,
    PlayedEvents,
    Recording,
    RecordingError,
    open_recording,
    open_recording_played,
)
from usb2rc.runtime.flag import WakeFlag

log = logging.getLogger(__name__)

FAULT_MARK = b"usb2rc-fault"
FAULT_RE = re.compile(r"^\s*#\s*usb2rc-fault:\s*read-error\s+at\s+([0-9.]+)\s*$")
SCAN_CHUNK = 1 << 20  # the fault-mark scan reads this much at a time
# How often a device looks whether its file is still there (a stat): the unplug latency.
GONE_CHECK_S = 0.05
WRITES_KEPT = 16  # the writes a replay device's output port keeps, newest last
# hid-recorder's bus numbers (the kernel's: `I: 3 ...` USB, `I: 5 ...` Bluetooth)
_BUSES = {0x03: BUS_USB, 0x05: BUS_BLUETOOTH}


StatId = tuple[int, int, int]  # inode, mtime_ns, size: one 'plug' of a file


@dataclass(frozen=True)
class ReplayFile:
    """A recording file's header and the stat that identifies this 'plug' (not its text:
    a device reads its events from the file, `EventFile`)."""

    path: Path
    stat_id: StatId
    recording: Recording  # the header: descriptor, name, IDs; no events
    fault_at: float | None
    info: DeviceInfo


def _open_text(path: Path) -> io.TextIOWrapper:
    """A recording as text: UTF-8 (what cannot be decoded replaced), universal newlines."""
    return open(path, encoding="utf-8", errors="replace")


class EventFile:
    """One device's events, read from its file a batch at a time as they come due: the open
    file and its position, never the text. `restart()` reads them again from the top (a
    loop's next lap). `next_batch()` and `close()` may come from different threads (a
    reader, a closer)."""

    def __init__(self, source: ReplayFile) -> None:
        self.source = str(source.path)
        self._lock = threading.Lock()
        self._fh: io.TextIOWrapper | None = None
        try:
            self._fh = _open_text(source.path)
        except FileNotFoundError:
            raise DeviceGone(f"{source.path}: replay file is gone") from None
        if _id_of(os.fstat(self._fh.fileno())) != source.stat_id:  # replaced since its scan
            self.close()
            raise DeviceGone(f"{source.path}: replay file replaced")
        self._batches: Iterator[PlayedEvents] = iter(())
        self.restart()

    def restart(self) -> None:
        with self._lock:
            if self._fh is not None:
                self._fh.seek(0)
                self._batches = open_recording_played(self._fh, source=self.source)[1]

    def next_batch(self) -> PlayedEvents | None:
        """The next events (at least one); None at the end (or once closed). RecordingError at
        a bad line, after the events before it."""
        with self._lock:
            if self._fh is None:
                return None
            return next(self._batches, None)

    def close(self) -> None:
        with self._lock:
            fh, self._fh = self._fh, None
        if fh is not None:
            fh.close()

    def __del__(self) -> None:  # a device dropped without close() (a test's) closes its file
        self.close()


def _stat_id(path: Path) -> StatId | None:
    return _stat_id_of(str(path))


def _stat_id_of(path: str) -> StatId | None:
    try:
        return _id_of(os.stat(path))
    except OSError:
        return None


def _id_of(st: os.stat_result) -> StatId:
    return st.st_ino, st.st_mtime_ns, st.st_size


def _fault_time(path: Path) -> float | None:
    """The earliest `# usb2rc-fault: read-error at SECONDS` of the file, if any. A substring
    scan of the bytes in chunks first (C speed, a chunk's memory); the lines are parsed
    only in a file that has the mark (a test's)."""
    with open(path, "rb") as fh:
        tail = b""
        while chunk := fh.read(SCAN_CHUNK):
            if FAULT_MARK in tail + chunk[: len(FAULT_MARK)] or FAULT_MARK in chunk:
                break
            tail = chunk[-len(FAULT_MARK) :]
        else:
            return None
    with _open_text(path) as lines:
        times = [float(m.group(1)) for line in lines if (m := FAULT_RE.match(line))]
    return min(times) if times else None


def _make_info(path: Path, stat_id: StatId, rec: Recording) -> DeviceInfo:
    page, usage = top_level_usage(rec.descriptor)
    return DeviceInfo(
        key=f"{path}:{stat_id[0]}:{stat_id[1]}",
        path=str(path),
        vid=rec.vid,
        pid=rec.pid,
        serial=path.stem,
        product=rec.name,
        interface=0,
        port_path=f"replay-{path.stem}",
        usage_page=page,
        usage=usage,
        bus=_BUSES.get(rec.bus, ""),
    )


def install_file(path: str | os.PathLike[str], text: str) -> Path:
    """Write `text` to `path` atomically (a hidden temp file renamed into place): one plug."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, target)
    return target


def load_replay_file(path: Path) -> ReplayFile:
    """Read one file and parse its header; raises RecordingError (or OSError) when it cannot
    be a device. Its events are parsed when it is played (`ReplayFile.events`)."""
    stat_id = _stat_id(path)
    if stat_id is None:
        raise FileNotFoundError(errno.ENOENT, "file vanished", str(path))
    with _open_text(path) as lines:
        header, _ = open_recording(lines, source=str(path))
    info = _make_info(path, stat_id, header)
    return ReplayFile(path, stat_id, header, _fault_time(path), info)


def _not_a_recording(path: Path, exc: Exception) -> str:
    return f"{path}: not a hid-recorder file: {exc}"


class ReplayBackend:
    name = "replay"

    def __init__(self, directory: str | os.PathLike[str], loop: bool = False, speed: float = 1.0):
        if speed <= 0:
            raise ValueError(f"replay speed must be > 0, got {speed}")
        self.directory = Path(directory)
        self.loop = loop
        self.speed = speed
        self.problems: list[str] = []  # files that are not usable recordings, from enumerate()
        self._lock = threading.Lock()
        # By file name (str: the scan runs at every change, or 10 times a second where the
        # directory cannot be watched, and Path hashing and comparing cost more than the
        # stat): the file read, or the problem text.
        self._cache: dict[str, ReplayFile | str] = {}
        self._cache_ids: dict[str, StatId] = {}
        self._reported: set[str] = set()

    def _candidates(self) -> list[tuple[str, StatId]]:
        """The visible files' names and stats, by name: one `stat` each (scandir knows the
        type). Raises OSError when the directory cannot be listed."""
        found = []
        with os.scandir(self.directory) as entries:
            for entry in entries:
                if entry.name.startswith("."):
                    continue
                try:
                    if entry.is_file():
                        found.append((entry.name, _id_of(entry.stat())))
                except OSError:
                    continue  # gone meanwhile
        found.sort()
        return found

    def _load_cached(self, name: str, stat_id: StatId | None) -> ReplayFile | str | None:
        if stat_id is None:
            return None
        with self._lock:
            if self._cache_ids.get(name) == stat_id:
                return self._cache[name]
        path = self.directory / name
        try:
            entry: ReplayFile | str = load_replay_file(path)
        except (RecordingError, OSError, ValueError) as exc:
            entry = _not_a_recording(path, exc)
        with self._lock:
            self._cache[name] = entry
            self._cache_ids[name] = stat_id
        return entry

    def _broken(self, source: ReplayFile, exc: RecordingError) -> None:
        """A device found a bad line while playing: from now on this file (as long as it is
        not changed) is a problem, not a device, so it is not opened again and again."""
        name = source.path.name
        with self._lock:
            if self._cache_ids.get(name) == source.stat_id:
                self._cache[name] = _not_a_recording(source.path, exc)

    def change_source(self) -> DirectoryWatch | None:
        """What wakes the hot-plug thread when the directory's visible entries change;
        None where inotify is not available (it polls)."""
        return DirectoryWatch.create(self.directory, relevant=lambda name: not name.startswith("."))

    def _report_problem(self, problem: str) -> None:
        if problem not in self._reported:
            self._reported.add(problem)
            log.warning("replay: %s", problem)

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        infos: list[DeviceInfo] = []
        problems: list[str] = []
        try:
            candidates = self._candidates()
        except OSError as exc:
            with self._lock:
                self.problems = [f"{self.directory}: cannot list the replay directory: {exc}"]
            return []
        for name, stat_id in candidates:
            entry = self._load_cached(name, stat_id)
            if isinstance(entry, str):
                problems.append(entry)
                self._report_problem(entry)
            elif entry is not None and (all or entry.info.usable):
                infos.append(entry.info)
        with self._lock:
            self.problems = problems
            if len(self._cache) > len(candidates):
                self._forget_gone({name for name, _ in candidates})
        return infos

    def _forget_gone(self, present: set[str]) -> None:
        """Drop what is cached for files that are gone (under the lock)."""
        for name in [n for n in self._cache if n not in present]:
            del self._cache[name], self._cache_ids[name]

    def open(self, info: DeviceInfo) -> ReplayDevice:
        path = Path(info.path)
        entry = self._load_cached(path.name, _stat_id(path))
        if entry is None or (isinstance(entry, ReplayFile) and entry.info.key != info.key):
            raise DeviceGone(f"{path}: replay file is gone")
        if isinstance(entry, str):
            raise DeviceOpenError(errno.EINVAL, entry)
        return ReplayDevice(entry, loop=self.loop, speed=self.speed, on_broken=self._broken)


class ReplayDevice:
    """Plays one recording; `read` sleeps until absolute monotonic deadlines (or close()).

    `read` and `read_due` are on the daemon's hot path (a pulled reader drains the due
    reports at every node step: a few at 1 kHz). The batch in play (`_batch`,
    `recording.PlayedEvents`: packed in C where the HID stage's C loops are built) holds
    the reports and their due times (monotonic, never earlier than the report before:
    reports come out in file order) and hands over those due in one call. `busy_s` is the
    time spent in `read` and `read_due` other than waiting: the replay backend's own cost,
    which a real device (the kernel) does not put on the daemon.
    """

    def __init__(
        self,
        source: ReplayFile,
        loop: bool = False,
        speed: float = 1.0,
        on_broken: Callable[[ReplayFile, RecordingError], None] | None = None,
    ) -> None:
        self.info = source.info
        self._source = source
        self._path = str(source.path)
        self._speed = speed
        self._on_broken = on_broken
        # The events are read from the file as they come due, on the reader's thread
        # (module docstring); only the batch in play is held.
        self._events = EventFile(source)
        self._want_loop = loop
        self._lap = 0
        self._lap_s = 0.0  # a lap's length, known at the end of the first lap
        self._lap_events = 0  # events of the first lap, and its last one's recorded time
        self._last_time_s = 0.0
        self._closed = WakeFlag()  # close() wakes a read waiting for the next report
        self._t0 = time.monotonic()
        self._fault_due = (
            math.inf if source.fault_at is None else self._t0 + source.fault_at / speed
        )
        self._fault = f"{self.info.path}: injected read error"
        self._gone: str | None = None  # once the file is seen gone, every read says so
        # what the gone check compares (the compiled pull reads these three too)
        self._stat_path = os.fsencode(self._path)
        self._stat_id = source.stat_id
        self._gone_check_s = GONE_CHECK_S
        self._batch: PlayedEvents = EventList([], [])  # the batch in play
        self._last_due = -math.inf  # the due time of the last report taken into a batch
        self._next_gone_check = 0.0
        self._quiet_until = 0.0  # before this, read needs neither a gone check nor a fault
        self.busy_s = 0.0

    @staticmethod
    def _loop_period(count: int, last: float) -> float:
        if not count:
            return 0.0
        step = last / (count - 1) if count > 1 else 0.01
        return max(last + step, 0.001)

    def report_descriptor(self) -> bytes:
        return self._source.recording.descriptor

    def _refill(self) -> bool:
        """The batch in play is all handed over: take the next one (a loop's next lap starts
        over at the file's top). False when none is left."""
        batch = self._read_batch()
        if batch is None and self._next_lap():
            batch = self._read_batch()
        if batch is None:
            return False
        # From t0 each time (not a running sum): a device looped for hours does not drift.
        start = self._t0 + self._lap * self._lap_s
        # a time before the one before is due with it: the file's order is kept
        self._last_due = batch.schedule(start, self._speed, self._last_due)
        self._batch = batch
        return True

    def _read_batch(self) -> PlayedEvents | None:
        try:
            batch = self._events.next_batch()
        except RecordingError as exc:
            self._events.close()
            self._bad_line(exc)
            return None
        if batch is not None and self._lap == 0:
            self._lap_events += len(batch)
            self._last_time_s = batch.last_time
        return batch

    def _next_lap(self) -> bool:
        """At the end of the events: start the next lap if looping (and there are events)."""
        if not self._want_loop or not self._lap_events:
            return False
        if self._lap == 0:
            self._lap_s = self._loop_period(self._lap_events, self._last_time_s) / self._speed
        self._lap += 1
        self._events.restart()
        return True

    def _next_due(self) -> float:
        """When the next report is due; inf when none is left."""
        if not self._batch.left and not self._refill():
            return math.inf
        return self._batch.next_due

    def _bad_line(self, exc: RecordingError) -> None:
        """The events before the bad line were played: the next read fails (EIO), as a
        device that breaks does, and the backend lists the file as a problem from now on."""
        self._fault_due = -math.inf
        self._quiet_until = -math.inf
        self._fault = f"{exc}: the recording cannot be played on"
        if self._on_broken is not None:
            self._on_broken(self._source, exc)

    def _check_gone(self, now: float) -> None:
        """A stat at most every GONE_CHECK_S: unplug is seen within that, and a 1 kHz device
        does not pay a system call per report. Once gone, every read raises (as hidapi's
        does after an unplug, even with reports still queued)."""
        if self._gone is None:
            if now < self._next_gone_check:
                return
            self._next_gone_check = now + self._gone_check_s
            self._quiet_until = min(self._next_gone_check, self._fault_due)
            if _stat_id_of(self._path) == self._stat_id:
                return
            self._gone = f"{self._source.path}: replay file removed or replaced"
            self._quiet_until = -math.inf
        raise DeviceGone(self._gone)

    def read_due(self, limit: int) -> list[bytes]:
        """The reports due now, at most `limit`, in one call: a reader's drain takes ~10 at
        a time from a 1 kHz device, and a `read(0.0)` each costs more in clock reads and
        calls than the delivery itself. Never blocks. Its gone check (a stat every
        GONE_CHECK_S) is made here as in `read`, and raises as `read` does once the file is
        gone; when a fault is due, or the device is gone or closed, it returns [] and the
        caller's `read` raises (`hid/reader.py` calls `read(0.0)` after this until it
        returns None)."""
        started = time.perf_counter()
        now = time.monotonic()
        due: list[bytes] = []
        try:
            if self._quiet_until <= now < self._fault_due and self._gone is None:
                self._check_gone(now)  # a stat, at most every GONE_CHECK_S
            if now < self._quiet_until and not self._closed.is_set():
                while len(due) < limit and (self._batch.left or self._refill()):
                    due += self._batch.take(now, limit - len(due))
                    if self._batch.left:  # the next one is not due yet (or the limit is reached)
                        break
        finally:
            self.busy_s += time.perf_counter() - started
        return due

    def read(self, timeout_s: float) -> bytes | None:
        started = time.perf_counter()
        now = time.monotonic()
        batch = self._batch
        if batch.left and now < self._quiet_until and not self._closed.is_set():
            # The drain's cases, when neither a gone check nor a fault is due: a report is
            # due, or a poll finds none is.
            if batch.next_due <= now:
                self.busy_s += time.perf_counter() - started
                return batch.take(now, 1)[0]
            if timeout_s <= 0:
                self.busy_s += time.perf_counter() - started
                return None
        waited = 0.0
        try:
            end = now + timeout_s if timeout_s > 0 else now
            while True:
                if self._closed.is_set():
                    raise OSError(errno.EBADF, f"{self.info.path}: device is closed")
                due = self._next_due()
                if now >= self._fault_due and due >= self._fault_due:
                    raise OSError(errno.EIO, self._fault)
                self._check_gone(now)
                if due <= now:
                    return self._batch.take(now, 1)[0]
                if now >= end:
                    return None
                wake = min(end, due, self._quiet_until)
                before = time.perf_counter()
                self._closed.wait(max(wake - now, 0.0))
                waited += time.perf_counter() - before
                now = time.monotonic()
        finally:
            self.busy_s += time.perf_counter() - started - waited

    def open_output(self) -> ReplayOutputPort:
        return ReplayOutputPort(self.info)

    def close(self) -> None:
        self._closed.set()
        self._events.close()


class ReplayOutputPort:
    """A recording has no outputs: the port takes every write, counts it and keeps the last
    WRITES_KEPT (what tests and the monitor look at). A write after close() is refused, as
    a closed hidapi handle refuses one."""

    def __init__(self, info: DeviceInfo) -> None:
        self.info = info
        self.written = 0
        self.last: tuple[OutputWrite, ...] = ()  # replaced whole: read from any thread
        self.closed = False

    def write(self, w: OutputWrite) -> None:
        if self.closed:
            raise OSError(errno.EBADF, f"{self.info.path}: output port is closed")
        self.written += 1
        self.last = (*self.last, w)[-WRITES_KEPT:]

    def close(self) -> None:
        self.closed = True
