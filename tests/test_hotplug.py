"""HotplugMonitor over the replay backend: plug and unplug at runtime, port-path order."""

from __future__ import annotations

import queue
from pathlib import Path

from test_replay import numbered, recording_text

from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.hotplug import HotplugMonitor, initial_devices, port_path_key, sort_by_port_path
from usb2rc.hid.replay import ReplayBackend, install_file

WAIT_S = 10.0


class Events:
    def __init__(self) -> None:
        self.q: queue.Queue[tuple[str, DeviceInfo]] = queue.Queue()

    def added(self, info: DeviceInfo) -> None:
        self.q.put(("added", info))

    def removed(self, info: DeviceInfo) -> None:
        self.q.put(("removed", info))

    def next(self) -> tuple[str, str]:
        kind, info = self.q.get(timeout=WAIT_S)
        return kind, info.serial


def test_natural_port_path_order() -> None:
    paths = ["1-1.10", "1-1.2", "2-1", "1-1", "1-1.2.3", "10-1", "replay-b", "replay-a"]
    assert sorted(paths, key=port_path_key) == [
        "1-1",
        "1-1.2",
        "1-1.2.3",
        "1-1.10",
        "2-1",
        "10-1",
        "replay-a",
        "replay-b",
    ]


def test_devices_without_port_path_sort_last() -> None:
    a = DeviceInfo("k1", "p", 1, 1, port_path="")
    b = DeviceInfo("k2", "p", 1, 1, port_path="3-1")
    assert sort_by_port_path([a, b]) == [b, a]


def test_initial_set_in_port_order_then_runtime_plug_and_unplug(tmp_path: Path) -> None:
    for stem in ("z", "a", "m"):
        install_file(tmp_path / f"{stem}.hid", recording_text(numbered(1)))
    events = Events()
    monitor = HotplugMonitor(ReplayBackend(tmp_path), events.added, events.removed, poll_s=0.02)
    monitor.start()
    try:
        assert [events.next() for _ in range(3)] == [("added", s) for s in ("a", "m", "z")]
        install_file(tmp_path / "new.hid", recording_text(numbered(1)))
        assert events.next() == ("added", "new")
        (tmp_path / "m.hid").unlink()
        assert events.next() == ("removed", "m")
    finally:
        monitor.stop()
        monitor.join(WAIT_S)
    assert events.q.empty()


def test_initial_devices_taken_by_daemon_are_not_reported_again(tmp_path: Path) -> None:
    install_file(tmp_path / "b.hid", recording_text(numbered(1)))
    install_file(tmp_path / "a.hid", recording_text(numbered(1)))
    backend = ReplayBackend(tmp_path)
    assert [i.serial for i in initial_devices(backend)] == ["a", "b"]
    events = Events()
    monitor = HotplugMonitor(backend, events.added, events.removed, poll_s=0.02)
    assert [i.serial for i in monitor.initial_devices()] == ["a", "b"]
    monitor.start()
    try:
        install_file(tmp_path / "c.hid", recording_text(numbered(1)))
        assert events.next() == ("added", "c")
    finally:
        monitor.stop()
        monitor.join(WAIT_S)
    assert events.q.empty()


class FlakyBackend:
    name = "flaky"

    def __init__(self, inner: ReplayBackend) -> None:
        self.inner = inner
        self.calls = 0

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        self.calls += 1
        if self.calls == 1:
            raise OSError("udev hiccup")
        return self.inner.enumerate(all)

    def open(self, info: DeviceInfo):
        return self.inner.open(info)


def test_failing_enumerate_and_handler_do_not_kill_the_thread(tmp_path: Path) -> None:
    install_file(tmp_path / "a.hid", recording_text(numbered(1)))
    events = Events()

    def bad_added(info: DeviceInfo) -> None:
        events.added(info)
        raise RuntimeError("handler bug")

    backend = FlakyBackend(ReplayBackend(tmp_path))
    monitor = HotplugMonitor(backend, bad_added, events.removed, poll_s=0.02)
    monitor.start()
    try:
        assert events.next() == ("added", "a")
        install_file(tmp_path / "b.hid", recording_text(numbered(1)))
        assert events.next() == ("added", "b")
    finally:
        monitor.stop()
        monitor.join(WAIT_S)


def test_forget_makes_a_present_device_come_again(tmp_path: Path) -> None:
    install_file(tmp_path / "a.hid", recording_text(numbered(1)))
    events = Events()
    monitor = HotplugMonitor(ReplayBackend(tmp_path), events.added, events.removed)
    [info] = monitor.initial_devices()
    monitor.scan()
    assert events.q.empty()
    monitor.forget(info.key)
    monitor.scan()
    assert events.next() == ("added", "a")
