"""Replay backend: every hid-recorder file in a directory is a plugged device.

A file that appears is a plug, a file that goes is an unplug. Files whose names start with
"." are ignored, so write a new file under a hidden name and rename it into place. A device
plays its `E:` events with their recorded timing relative to `open()` (scaled by `speed`),
once, then holds until its file goes; `loop=True` replays forever.

A plug does not parse the whole recording: the directory scan reads a new file but parses
its header only (descriptor, name, IDs: what `DeviceInfo` needs), and a device parses its
events as it plays them, in its own reader thread, a few per read (the first lap of a loop;
later laps reuse them). A 4 s recording at 1 kHz is ~4000 lines and ~5-15 ms of Python:
parsed at once on the hot-plug thread, it competed with the scheduler for the GIL while the
daemon ran (bench/bench_plug_cost.py). The price: an `E:` line that is not valid is found when it
is played, not when the file appears. Its device's `read()` then raises `OSError(EIO)`
naming the line (the daemon sends `3`, read failed), and from then on the file is listed in
`problems` instead of as a device.

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

from usb2rc.flag import WakeFlag
from usb2rc.hid.backend import DeviceGone, DeviceInfo, DeviceOpenError
from usb2rc.hid.descriptor import top_level_usage
from usb2rc.hid.recording import RecordedEvent, Recording, RecordingError, open_recording

log = logging.getLogger(__name__)

FAULT_MARK = "usb2rc-fault"
FAULT_RE = re.compile(r"^\s*#\s*usb2rc-fault:\s*read-error\s+at\s+([0-9.]+)\s*$", re.MULTILINE)
# How often a device looks whether its file is still there (a stat): the unplug latency.
GONE_CHECK_S = 0.05


StatId = tuple[int, int, int]  # inode, mtime_ns, size: one 'plug' of a file


@dataclass(frozen=True)
class ReplayFile:
    """A recording file's header and text, and the stat that identifies this 'plug'."""

    path: Path
    stat_id: StatId
    recording: Recording  # the header: descriptor, name, IDs; no events (see `events()`)
    fault_at: float | None
    info: DeviceInfo
    text: str

    def events(self) -> Iterator[RecordedEvent]:
        """The events, parsed as they are taken (RecordingError at the first bad line)."""
        lines = io.StringIO(self.text, newline=None)  # universal newlines, like open()
        return open_recording(lines, source=str(self.path))[1]


def _stat_id(path: Path) -> StatId | None:
    return _stat_id_of(str(path))


def _stat_id_of(path: str) -> StatId | None:
    try:
        return _id_of(os.stat(path))
    except OSError:
        return None


def _id_of(st: os.stat_result) -> StatId:
    return st.st_ino, st.st_mtime_ns, st.st_size


def _fault_time(text: str) -> float | None:
    # The substring test first: the multi-line regex over a 200 KB recording is one C call
    # of ~1-2 ms that holds the GIL; `in` takes ~50 µs.
    if FAULT_MARK not in text:
        return None
    times = [float(m) for m in FAULT_RE.findall(text)]
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
    text = path.read_text(encoding="utf-8", errors="replace")
    header, _ = open_recording(io.StringIO(text, newline=None), source=str(path))
    info = _make_info(path, stat_id, header)
    return ReplayFile(path, stat_id, header, _fault_time(text), info, text)


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
        # By file name (str: the scan runs 10 times a second, and Path hashing and
        # comparing cost more than the stat): the file read, or the problem text.
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

    `read` is on the daemon's hot path (a reader drains ~20 due reports per tick at 1 kHz), so
    the next report's due time is kept ready (`_due`) and a due report costs one clock read
    and a few attribute loads. `busy_s` is the time spent in `read` other than waiting: the
    replay backend's own cost, which a real device (the kernel) does not put on the daemon.
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
        # The events are parsed as they come due, on the reader's thread (module docstring);
        # the lists grow over the first lap, which later laps replay.
        self._pending: Iterator[RecordedEvent] | None = source.events()
        self._reports: list[bytes] = []
        self._times: list[float] = []  # due after the lap's start (scaled by speed)
        self._last_time_s = 0.0  # the last parsed event's recorded time
        self._want_loop = loop
        self._loop = False  # known once every event is parsed: loop, and there are events
        self._lap_s = 0.0  # the same
        self._closed = WakeFlag()  # close() wakes a read waiting for the next report
        self._t0 = time.monotonic()
        self._fault_due = (
            math.inf if source.fault_at is None else self._t0 + source.fault_at / speed
        )
        self._fault = f"{self.info.path}: injected read error"
        self._lap = 0
        self._i = 0  # the next event of this lap
        self._due = self._due_of(0, 0)  # when events[_i] of lap _lap is due; inf: none left
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

    def _due_of(self, lap: int, i: int) -> float:
        if i >= len(self._times) and not self._parse_next():
            if not self._loop:
                return math.inf
            lap, i = lap + 1, 0
            self._lap, self._i = lap, i
        # From t0 each time (not a running sum): a device looped for hours does not drift.
        return self._t0 + lap * self._lap_s + self._times[i]

    def _parse_next(self) -> bool:
        """Parse the recording's next event; False at its end (or at a bad line)."""
        pending = self._pending
        if pending is None:
            return False
        try:
            event = next(pending)
        except StopIteration:
            self._pending = None
            self._loop = self._want_loop and bool(self._times)
            self._lap_s = self._loop_period(len(self._times), self._last_time_s) / self._speed
            return False
        except RecordingError as exc:
            self._pending = None
            self._bad_line(exc)
            return False
        self._times.append(event.time_s / self._speed)
        self._reports.append(event.report)
        self._last_time_s = event.time_s
        return True

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
        does not pay a system call per report."""
        if now < self._next_gone_check:
            return
        self._next_gone_check = now + GONE_CHECK_S
        self._quiet_until = min(self._next_gone_check, self._fault_due)
        if _stat_id_of(self._path) != self._source.stat_id:
            raise DeviceGone(f"{self._source.path}: replay file removed or replaced")

    def read_due(self, limit: int) -> list[bytes]:
        """The reports due now, at most `limit`, in one call: a reader's drain takes ~10 at
        a time from a 1 kHz device, and a `read(0.0)` each costs more in clock reads and
        calls than the delivery itself. Never blocks, never checks: when a gone check or a
        fault is due it returns [] and the caller's `read` does it (`hid/reader.py` calls
        `read(0.0)` after this until it returns None)."""
        started = time.perf_counter()
        now = time.monotonic()
        due: list[bytes] = []
        if now < self._quiet_until and not self._closed.is_set():
            deliver = self._deliver
            while self._due <= now and len(due) < limit:
                due.append(deliver())
        self.busy_s += time.perf_counter() - started
        return due

    def read(self, timeout_s: float) -> bytes | None:
        started = time.perf_counter()
        now = time.monotonic()
        if self._due <= now < self._quiet_until and not self._closed.is_set():
            # The drain's case: a report is due and neither a gone check nor a fault is.
            report = self._deliver()
            self.busy_s += time.perf_counter() - started
            return report
        waited = 0.0
        try:
            end = now + timeout_s if timeout_s > 0 else now
            while True:
                if self._closed.is_set():
                    raise OSError(errno.EBADF, f"{self.info.path}: device is closed")
                due = self._due
                if now >= self._fault_due and due >= self._fault_due:
                    raise OSError(errno.EIO, self._fault)
                self._check_gone(now)
                if due <= now:
                    return self._deliver()
                if now >= end:
                    return None
                wake = min(end, due, self._quiet_until)
                before = time.perf_counter()
                self._closed.wait(max(wake - now, 0.0))
                waited += time.perf_counter() - before
                now = time.monotonic()
        finally:
            self.busy_s += time.perf_counter() - started - waited

    def _deliver(self) -> bytes:
        i = self._i
        report = self._reports[i]
        self._i = i + 1
        self._due = self._due_of(self._lap, i + 1)
        return report

    def close(self) -> None:
        self._closed.set()
