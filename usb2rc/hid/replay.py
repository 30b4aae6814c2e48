"""Replay backend: every hid-recorder file in a directory is a plugged device.

A file that appears is a plug, a file that goes is an unplug. Files whose names start with
"." are ignored, so write a new file under a hidden name and rename it into place. A device
plays its `E:` events with their recorded timing relative to `open()` (scaled by `speed`),
once, then holds until its file goes; `loop=True` replays forever.

Fault injection: a comment line `# usb2rc-fault: read-error at SECONDS` makes `read()` raise
`OSError(EIO)` once the events before SECONDS are delivered.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from usb2rc.flag import WakeFlag
from usb2rc.hid.backend import DeviceGone, DeviceInfo, DeviceOpenError
from usb2rc.hid.descriptor import top_level_usage
from usb2rc.hid.recording import RecordedEvent, Recording, RecordingError, parse_recording

log = logging.getLogger(__name__)

FAULT_RE = re.compile(r"^\s*#\s*usb2rc-fault:\s*read-error\s+at\s+([0-9.]+)\s*$", re.MULTILINE)
# How often a device looks whether its file is still there (a stat): the unplug latency.
GONE_CHECK_S = 0.05


@dataclass(frozen=True)
class ReplayFile:
    """A parsed recording file and the stat that identifies this 'plug'."""

    path: Path
    stat_id: tuple[int, int, int]  # inode, mtime_ns, size
    recording: Recording
    fault_at: float | None
    info: DeviceInfo


def _stat_id(path: Path) -> tuple[int, int, int] | None:
    return _stat_id_of(str(path))


def _stat_id_of(path: str) -> tuple[int, int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _fault_time(text: str) -> float | None:
    times = [float(m) for m in FAULT_RE.findall(text)]
    return min(times) if times else None


def _make_info(path: Path, stat_id: tuple[int, int, int], rec: Recording) -> DeviceInfo:
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
    """Parse one file; raises RecordingError (or OSError) when it cannot be a device."""
    stat_id = _stat_id(path)
    if stat_id is None:
        raise FileNotFoundError(errno.ENOENT, "file vanished", str(path))
    text = path.read_text(encoding="utf-8", errors="replace")
    rec = parse_recording(text.splitlines(), source=str(path))
    return ReplayFile(path, stat_id, rec, _fault_time(text), _make_info(path, stat_id, rec))


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
        self._cache: dict[Path, ReplayFile | str] = {}  # parsed file or the problem text
        self._cache_ids: dict[Path, tuple[int, int, int]] = {}
        self._reported: set[str] = set()

    def _candidates(self, problems: list[str]) -> list[Path]:
        try:
            entries = sorted(self.directory.iterdir())
        except OSError as exc:
            problems.append(f"{self.directory}: cannot list the replay directory: {exc}")
            return []
        return [p for p in entries if not p.name.startswith(".") and p.is_file()]

    def _load_cached(self, path: Path) -> ReplayFile | str | None:
        stat_id = _stat_id(path)
        if stat_id is None:
            return None
        with self._lock:
            if self._cache_ids.get(path) == stat_id:
                return self._cache[path]
        try:
            entry: ReplayFile | str = load_replay_file(path)
        except (RecordingError, OSError, ValueError) as exc:
            entry = f"{path}: not a hid-recorder file: {exc}"
        with self._lock:
            self._cache[path] = entry
            self._cache_ids[path] = stat_id
        return entry

    def _report_problem(self, problem: str) -> None:
        if problem not in self._reported:
            self._reported.add(problem)
            log.warning("replay: %s", problem)

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        infos: list[DeviceInfo] = []
        problems: list[str] = []
        for path in self._candidates(problems):
            entry = self._load_cached(path)
            if isinstance(entry, str):
                problems.append(entry)
                self._report_problem(entry)
            elif entry is not None and (all or entry.info.usable):
                infos.append(entry.info)
        with self._lock:
            self.problems = problems
        return infos

    def open(self, info: DeviceInfo) -> ReplayDevice:
        path = Path(info.path)
        entry = self._load_cached(path)
        if entry is None or (isinstance(entry, ReplayFile) and entry.info.key != info.key):
            raise DeviceGone(f"{path}: replay file is gone")
        if isinstance(entry, str):
            raise DeviceOpenError(errno.EINVAL, entry)
        return ReplayDevice(entry, loop=self.loop, speed=self.speed)


class ReplayDevice:
    """Plays one recording; `read` sleeps until absolute monotonic deadlines (or close()).

    `read` is on the daemon's hot path (a reader drains ~20 due reports per tick at 1 kHz), so
    the next report's due time is kept ready (`_due`) and a due report costs one clock read
    and a few attribute loads. `busy_s` is the time spent in `read` other than waiting: the
    replay backend's own cost, which a real device (the kernel) does not put on the daemon.
    """

    def __init__(self, source: ReplayFile, loop: bool = False, speed: float = 1.0) -> None:
        self.info = source.info
        self._source = source
        self._path = str(source.path)
        self._reports = tuple(event.report for event in source.recording.events)
        self._times = tuple(event.time_s / speed for event in source.recording.events)
        self._loop = loop and bool(self._reports)
        self._lap_s = self._loop_period(source.recording.events) / speed
        self._closed = WakeFlag()  # close() wakes a read waiting for the next report
        self._t0 = time.monotonic()
        self._lap = 0
        self._i = 0  # the next event of this lap
        self._due = self._due_of(0, 0)  # when events[_i] of lap _lap is due; inf: none left
        self._fault_due = (
            math.inf if source.fault_at is None else self._t0 + source.fault_at / speed
        )
        self._next_gone_check = 0.0
        self._quiet_until = 0.0  # before this, read needs neither a gone check nor a fault
        self.busy_s = 0.0

    @staticmethod
    def _loop_period(events: tuple[RecordedEvent, ...]) -> float:
        if not events:
            return 0.0
        last = events[-1].time_s
        step = last / (len(events) - 1) if len(events) > 1 else 0.01
        return max(last + step, 0.001)

    def report_descriptor(self) -> bytes:
        return self._source.recording.descriptor

    def _due_of(self, lap: int, i: int) -> float:
        if i >= len(self._times):
            if not self._loop:
                return math.inf
            lap, i = lap + 1, 0
            self._lap, self._i = lap, i
        # From t0 each time (not a running sum): a device looped for hours does not drift.
        return self._t0 + lap * self._lap_s + self._times[i]

    def _check_gone(self, now: float) -> None:
        """A stat at most every GONE_CHECK_S: unplug is seen within that, and a 1 kHz device
        does not pay a system call per report."""
        if now < self._next_gone_check:
            return
        self._next_gone_check = now + GONE_CHECK_S
        self._quiet_until = min(self._next_gone_check, self._fault_due)
        if _stat_id_of(self._path) != self._source.stat_id:
            raise DeviceGone(f"{self._source.path}: replay file removed or replaced")

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
                    raise OSError(errno.EIO, f"{self.info.path}: injected read error")
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
