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

from usb2rc.hid.backend import DeviceGone, DeviceInfo, DeviceOpenError
from usb2rc.hid.descriptor import top_level_usage
from usb2rc.hid.recording import Recording, RecordingError, parse_recording

log = logging.getLogger(__name__)

FAULT_RE = re.compile(r"^\s*#\s*usb2rc-fault:\s*read-error\s+at\s+([0-9.]+)\s*$", re.MULTILINE)
GONE_CHECK_S = 0.02  # how often an idle or busy device looks whether its file is still there


@dataclass(frozen=True)
class ReplayFile:
    """A parsed recording file and the stat that identifies this 'plug'."""

    path: Path
    stat_id: tuple[int, int, int]  # inode, mtime_ns, size
    recording: Recording
    fault_at: float | None
    info: DeviceInfo


def _stat_id(path: Path) -> tuple[int, int, int] | None:
    try:
        st = path.stat()
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
    """Plays one recording; `read` waits on an Event with absolute monotonic deadlines."""

    def __init__(self, source: ReplayFile, loop: bool = False, speed: float = 1.0) -> None:
        self.info = source.info
        self._source = source
        self._events = source.recording.events
        self._loop = loop and bool(self._events)
        self._speed = speed
        self._period = self._loop_period()
        self._closed = threading.Event()
        self._t0 = time.monotonic()
        self._index = 0  # events delivered, counting over loops
        self._fault_due = (
            math.inf if source.fault_at is None else self._t0 + source.fault_at / speed
        )
        self._next_gone_check = 0.0

    def _loop_period(self) -> float:
        if not self._events:
            return 0.0
        last = self._events[-1].time_s
        step = last / (len(self._events) - 1) if len(self._events) > 1 else 0.01
        return max(last + step, 0.001)

    def report_descriptor(self) -> bytes:
        return self._source.recording.descriptor

    def _next_due(self) -> float:
        n = len(self._events)
        if n == 0 or (self._index >= n and not self._loop):
            return math.inf
        lap, i = divmod(self._index, n)
        return self._t0 + (lap * self._period + self._events[i].time_s) / self._speed

    def _check_gone(self, now: float) -> None:
        if now < self._next_gone_check:
            return
        self._next_gone_check = now + GONE_CHECK_S
        if _stat_id(self._source.path) != self._source.stat_id:
            raise DeviceGone(f"{self._source.path}: replay file removed or replaced")

    def read(self, timeout_s: float) -> bytes | None:
        now = time.monotonic()
        end = now + max(timeout_s, 0.0)
        while True:
            if self._closed.is_set():
                raise OSError(errno.EBADF, f"{self.info.path}: device is closed")
            due = self._next_due()
            if now >= self._fault_due and due >= self._fault_due:
                raise OSError(errno.EIO, f"{self.info.path}: injected read error")
            self._check_gone(now)
            if due <= now:
                report = self._events[self._index % len(self._events)].report
                self._index += 1
                return report
            if now >= end:
                return None
            wake = min(end, due, self._fault_due, self._next_gone_check)
            self._closed.wait(max(wake - now, 0.0))
            now = time.monotonic()

    def close(self) -> None:
        self._closed.set()
