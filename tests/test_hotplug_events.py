"""The hot-plug thread sleeps until the devices may have changed: the replay directory's
inotify watch (usb2rc.hid.dirwatch), or any change source's fd (the hidapi backend's udev
monitor: tests/test_real_hidapi.py holds that one to the testbed's uevents). No periodic
scan while nothing changes; a plug, an unplug, a forgotten device and the stop wake it.

Wake-ups are the thread's voluntary context switches (/proc) over a quiet window: the
monitor used to scan 10 times a second, and wake as often with the udev monitor too.
"""

from __future__ import annotations

import os
import queue
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from test_replay import numbered, recording_text
from thread_wakeups import QUIET_WAKEUPS_MAX, WAIT_S, until, wakeups_in_quiet_window

from usb2rc.hid import dirwatch
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.hotplug import HotplugMonitor
from usb2rc.hid.replay import ReplayBackend, ReplayDevice, install_file
from usb2rc.runtime.doorbell import Doorbell


class Events:
    def __init__(self) -> None:
        self.q: queue.Queue[tuple[str, str]] = queue.Queue()

    def added(self, info: DeviceInfo) -> None:
        self.q.put(("added", info.serial))

    def removed(self, info: DeviceInfo) -> None:
        self.q.put(("removed", info.serial))

    def next(self) -> tuple[str, str]:
        return self.q.get(timeout=WAIT_S)


class CountingBackend(ReplayBackend):
    """The replay backend, its scans counted."""

    scans = 0

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        self.scans += 1
        return super().enumerate(all)


def plug(directory: Path, stem: str) -> Path:
    return install_file(directory / f"{stem}.hid", recording_text(numbered(1)))


@pytest.fixture
def monitored() -> Iterator[Callable[..., tuple[HotplugMonitor, Events]]]:
    """Starts a monitor (its first scan done: its devices reported); stops and joins it
    whatever happens."""
    started: list[HotplugMonitor] = []

    def start(backend: ReplayBackend, poll_s: float = 0.1) -> tuple[HotplugMonitor, Events]:
        events = Events()
        monitor = HotplugMonitor(backend, events.added, events.removed, poll_s=poll_s)
        started.append(monitor)
        monitor.start()
        return monitor, events

    try:
        yield start
    finally:
        for monitor in started:
            monitor.stop()
            assert monitor.join(WAIT_S), "the monitor did not end after its stop"


def test_an_unchanged_replay_directory_is_not_scanned_and_a_plug_wakes_the_monitor(
    tmp_path: Path, monitored: Callable[..., tuple[HotplugMonitor, Events]]
) -> None:
    plug(tmp_path, "a")
    backend = CountingBackend(tmp_path)
    monitor, events = monitored(backend, 0.02)  # a poll would scan 25 times in the window
    assert events.next() == ("added", "a")
    scans = backend.scans
    assert wakeups_in_quiet_window(monitor._thread) <= QUIET_WAKEUPS_MAX
    assert backend.scans == scans
    plug(tmp_path, "b")
    assert events.next() == ("added", "b")
    (tmp_path / "a.hid").unlink()
    assert events.next() == ("removed", "a")


def test_a_file_written_under_a_hidden_name_is_scanned_once_at_its_rename(
    tmp_path: Path, monitored: Callable[..., tuple[HotplugMonitor, Events]]
) -> None:
    plug(tmp_path, "a")
    backend = CountingBackend(tmp_path)
    _, events = monitored(backend)
    assert events.next() == ("added", "a")  # the first scan
    (tmp_path / ".scratch").write_text("not a recording yet")  # hidden: not a device
    plug(tmp_path, "b")  # written as .b.hid.tmp, renamed to b.hid
    assert events.next() == ("added", "b")
    assert backend.scans == 2


def test_a_forgotten_device_is_reported_again_without_any_change_in_the_directory(
    tmp_path: Path, monitored: Callable[..., tuple[HotplugMonitor, Events]]
) -> None:
    """The daemon forgets a device whose reads failed: if it is still there, it comes again
    (`poll_s` later: a device that cannot be opened yet is not retried in a loop)."""
    plug(tmp_path, "a")
    monitor, events = monitored(ReplayBackend(tmp_path))
    assert events.next() == ("added", "a")
    [info] = ReplayBackend(tmp_path).enumerate()
    monitor.forget(info.key)
    assert events.next() == ("added", "a")


def test_the_stop_wakes_a_monitor_that_waits_for_a_change(
    tmp_path: Path, monitored: Callable[..., tuple[HotplugMonitor, Events]]
) -> None:
    plug(tmp_path, "a")
    monitor, events = monitored(ReplayBackend(tmp_path), 3600.0)  # no timeout ends its wait
    assert events.next() == ("added", "a")  # the first scan: waiting now
    monitor.stop()
    assert monitor.join(WAIT_S)


class WatchKeepingBackend(CountingBackend):
    """The replay backend, its scans counted and its directory watch kept at hand."""

    watch: dirwatch.DirectoryWatch | None = None

    def change_source(self) -> dirwatch.DirectoryWatch | None:
        self.watch = super().change_source()
        return self.watch


def test_a_replay_directory_removed_and_made_again_is_watched_again(
    tmp_path: Path, monitored: Callable[..., tuple[HotplugMonitor, Events]]
) -> None:
    """The watch goes with the directory; the monitor polls while there is none and
    watches the new one once it is there."""
    directory = tmp_path / "replay"
    directory.mkdir()
    plug(directory, "a")
    backend = WatchKeepingBackend(directory)
    monitor, events = monitored(backend)
    assert events.next() == ("added", "a")
    shutil.rmtree(directory)
    assert events.next() == ("removed", "a")
    directory.mkdir()
    plug(directory, "b")
    assert events.next() == ("added", "b")
    until(lambda: backend.watch is not None and backend.watch._wd is not None, "watched again")
    plug(directory, "c")
    assert events.next() == ("added", "c")
    scans = backend.scans
    assert wakeups_in_quiet_window(monitor._thread) <= QUIET_WAKEUPS_MAX
    assert backend.scans == scans


def test_without_inotify_the_replay_directory_is_polled(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    monitored: Callable[..., tuple[HotplugMonitor, Events]],
) -> None:
    monkeypatch.setattr(dirwatch, "_Inotify", MissingInotify)
    assert ReplayBackend(tmp_path).change_source() is None
    backend = CountingBackend(tmp_path)
    _, events = monitored(backend, 0.02)
    until(lambda: backend.scans >= 3, "a few polls")
    plug(tmp_path, "a")
    assert events.next() == ("added", "a")


class MissingInotify:
    """What ctypes raises where libc has no inotify_init1 (not Linux)."""

    def __init__(self) -> None:
        raise AttributeError("undefined symbol: inotify_init1")


class PipeSource:
    """A change source as the udev monitor is one: an fd that polls readable when an event
    queued, drained by `take()`."""

    def __init__(self) -> None:
        self.bell = Doorbell()
        self.closed = False

    def fileno(self) -> int:
        return self.bell.fileno()

    def watch(self) -> bool:
        return True

    def take(self) -> bool:
        self.bell.clear()
        return True

    def close(self) -> None:
        self.closed = True


class SourcedBackend:
    """A backend whose change source is `source` (as the hidapi one's is udev)."""

    name = "sourced"

    def __init__(self, inner: CountingBackend, source: PipeSource) -> None:
        self.inner = inner
        self.source = source

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        return self.inner.enumerate(all)

    def open(self, info: DeviceInfo) -> ReplayDevice:
        return self.inner.open(info)

    def change_source(self) -> PipeSource:
        return self.source


def test_any_change_source_wakes_the_monitor_and_nothing_else_does(
    tmp_path: Path, monitored: Callable[..., tuple[HotplugMonitor, Events]]
) -> None:
    """The udev monitor's case: no scan between two events, however small `poll_s` (with
    udev the monitor used to scan every `poll_s` too)."""
    plug(tmp_path, "a")
    source = PipeSource()
    backend = SourcedBackend(CountingBackend(tmp_path), source)
    monitor, events = monitored(backend, 0.02)
    assert events.next() == ("added", "a")  # the first scan
    plug(tmp_path, "b")  # nothing tells the monitor (this source does not watch files)
    assert wakeups_in_quiet_window(monitor._thread) <= QUIET_WAKEUPS_MAX
    assert backend.inner.scans == 1 and events.q.empty()
    source.bell.ring()  # a uevent
    assert events.next() == ("added", "b")
    monitor.stop()
    assert monitor.join(WAIT_S) and source.closed


def test_inotify_reports_the_entry_changes_a_replay_directory_sees(tmp_path: Path) -> None:
    """The real kernel's events, one kind of change at a time: each wakes the fd and counts,
    but a hidden name's."""
    watch = dirwatch.DirectoryWatch.create(tmp_path, lambda name: not name.startswith("."))
    assert watch is not None
    try:
        assert watch.watch()
        path = tmp_path / "a.hid"
        changes: list[Callable[[], object]] = [
            lambda: path.write_text("x"),  # created, closed after a write
            lambda: os.utime(path, (1, 1)),  # attributes
            lambda: path.rename(tmp_path / "b.hid"),  # moved out of a's name, into b's
            lambda: (tmp_path / "b.hid").unlink(),  # deleted
        ]
        for change in changes:
            change()
            assert wait_readable(watch.fileno())
            assert watch.take()
        (tmp_path / ".hidden").write_text("x")
        assert wait_readable(watch.fileno())
        assert not watch.take()  # only hidden names: nothing to scan for
    finally:
        watch.close()


def wait_readable(fd: int) -> bool:
    import select

    return bool(select.select([fd], [], [], WAIT_S)[0])


def test_a_directory_that_is_not_there_is_not_watched_until_it_is(tmp_path: Path) -> None:
    directory = tmp_path / "later"
    watch = dirwatch.DirectoryWatch.create(directory)
    assert watch is not None
    try:
        assert not watch.watch()
        directory.mkdir()
        assert watch.watch()
        os.rename(directory, tmp_path / "moved")
        assert wait_readable(watch.fileno()) and watch.take()
        assert not watch.watch()  # the path has no directory now: the moved one is let go
    finally:
        watch.close()
