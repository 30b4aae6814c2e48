"""HotplugMonitor: a thread that reports devices as they come and go.

It diffs `backend.enumerate()` by `DeviceInfo.key`, each time something says the devices
may have changed, and sleeps in between: on Linux the hidapi backend's pyudev monitor on the
`hidraw` subsystem wakes it (its netlink socket's fd), a backend with a `change_source()`
(the replay backend: inotify on its directory) its own fd. Without either it polls every
`poll_s`. Devices present when it starts are reported in USB port-path order (natural sort:
"1-1.2" < "1-1.10"), unless the daemon took them first with `initial_devices()`. Removals
are reported here too, though a reader usually notices an unplug first. A device the
daemon `forget`s is looked for again `poll_s` later.
"""

from __future__ import annotations

import contextlib
import logging
import re
import select
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, Protocol, runtime_checkable

from usb2rc.hid.backend import Backend, DeviceInfo
from usb2rc.runtime.doorbell import Doorbell
from usb2rc.runtime.worker import Worker

log = logging.getLogger(__name__)

_NUMBER = re.compile(r"(\d+)")


def port_path_key(port_path: str) -> tuple[tuple[int, int | str], ...]:
    """Natural sort key: digits compare as numbers, so '1-1.2' < '1-1.10'."""
    parts = _NUMBER.split(port_path)
    return tuple((0, int(p)) if p.isdigit() else (1, p) for p in parts if p)


def sort_by_port_path(infos: Iterable[DeviceInfo]) -> list[DeviceInfo]:
    """Port-path order; devices without a port path last, then by key for stability."""
    return sorted(infos, key=lambda i: (not i.port_path, port_path_key(i.port_path), i.key))


def initial_devices(backend: Backend) -> list[DeviceInfo]:
    """The usable devices present now, in USB port-path order."""
    return sort_by_port_path(backend.enumerate())


class ChangeSource(Protocol):
    """What tells the hot-plug thread that the devices may have changed: an fd that polls
    readable then (`fileno`); `take()` reads what came, True when it is worth a scan;
    `watch()` before each scan, False while it cannot tell (the thread polls then)."""

    def fileno(self) -> int: ...
    def watch(self) -> bool: ...
    def take(self) -> bool: ...
    def close(self) -> None: ...


@runtime_checkable
class WatchableBackend(Protocol):
    """A backend that can say when its devices may have changed (the replay backend)."""

    def change_source(self) -> ChangeSource | None: ...


class _UdevWaker:
    """Wakes on any hidraw uevent; the caller still re-enumerates."""

    def __init__(self, monitor: Any) -> None:
        self._monitor = monitor

    @classmethod
    def create(cls) -> _UdevWaker | None:
        try:
            import pyudev

            monitor = pyudev.Monitor.from_netlink(pyudev.Context())
            monitor.filter_by("hidraw")
            monitor.start()
        except Exception as exc:  # no pyudev, no netlink (containers): poll instead
            log.info("hotplug: no udev monitor (%s); polling", exc)
            return None
        return cls(monitor)

    def fileno(self) -> int:
        fd: int = self._monitor.fileno()
        return fd

    def watch(self) -> bool:
        return True  # the netlink socket was bound at create(): every uevent queues on it

    def take(self) -> bool:
        while self._monitor.poll(timeout=0) is not None:
            pass  # drain: one enumerate covers them all
        return True

    def wait(self, timeout_s: float) -> None:
        """Until a uevent came (drained), or `timeout_s`."""
        ready, _, _ = select.select([self.fileno()], [], [], timeout_s)
        if ready:
            self.take()

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._monitor.stop()


class HotplugMonitor(Worker):
    def __init__(
        self,
        backend: Backend,
        on_added: Callable[[DeviceInfo], None],
        on_removed: Callable[[DeviceInfo], None],
        poll_s: float = 0.1,
        use_udev: bool | None = None,
    ) -> None:
        self.backend = backend
        self._on_added = on_added
        self._on_removed = on_removed
        self._poll_s = poll_s
        if use_udev is None:
            use_udev = sys.platform.startswith("linux") and backend.name == "hidapi"
        self._use_udev = use_udev
        self._known: dict[str, DeviceInfo] | None = None
        self._lock = threading.Lock()  # guards _known: forget() comes from the lifecycle thread
        self._rescan = False  # a device was forgotten since the last scan (under _lock)
        self._doorbell = Doorbell()  # stop() and forget() wake the thread's wait
        super().__init__("hid-hotplug")

    def stop(self) -> None:
        super().stop()
        self._doorbell.ring()

    def initial_devices(self) -> list[DeviceInfo]:
        """Take the present devices (port-path order); `start()` then reports only changes."""
        present = initial_devices(self.backend)
        with self._lock:
            self._known = {info.key: info for info in present}
        return present

    def forget(self, key: str) -> None:
        """Treat a device as unseen: if it is still present, the next scan reports it added
        again (the daemon retries a device whose reads failed)."""
        with self._lock:
            if self._known is not None:
                self._known.pop(key, None)
            self._rescan = True
        self._doorbell.ring()

    def _enumerate(self) -> list[DeviceInfo] | None:
        try:
            return self.backend.enumerate()
        except Exception:
            log.exception("hotplug: enumerate failed; trying again")
            return None

    def _call(self, callback: Callable[[DeviceInfo], None], info: DeviceInfo) -> None:
        try:
            callback(info)
        except Exception:
            log.exception("hotplug: handler for %s failed", info.path)

    def scan(self) -> None:
        """One diff against the last scan (the thread calls this; tests may too)."""
        with self._lock:
            self._rescan = False  # this scan reports a forgotten device still present
        present = self._enumerate()
        if present is None:
            return
        current = {info.key: info for info in present}
        with self._lock:
            known = self._known or {}
            removed = [info for key, info in known.items() if key not in current]
            added = [info for key, info in current.items() if key not in known]
            self._known = current
        for info in removed:
            self._call(self._on_removed, info)
        for info in sort_by_port_path(added):
            self._call(self._on_added, info)

    def _change_source(self) -> ChangeSource | None:
        if self._use_udev:
            return _UdevWaker.create()
        if isinstance(self.backend, WatchableBackend):
            return self.backend.change_source()
        return None

    def run(self) -> None:
        source = self._change_source()
        try:
            while not self.stopping:
                watching = source is not None and source.watch()  # before the scan's look
                self.scan()
                self._wait(source if watching else None)
        finally:
            if source is not None:
                source.close()

    def _wait(self, source: ChangeSource | None) -> None:
        """Asleep until the devices may have changed: `source` says so, or `poll_s` after a
        device was forgotten (one that cannot be opened yet is not retried in a loop), or
        the stop; with no source, `poll_s` (a poll)."""
        poller = select.poll()
        bell = self._doorbell.fileno()
        poller.register(bell, select.POLLIN)
        if source is not None:
            poller.register(source.fileno(), select.POLLIN)
        due = None if source is not None else time.monotonic() + self._poll_s
        while not self.stopping:
            with self._lock:
                if self._rescan and due is None:
                    due = time.monotonic() + self._poll_s
            timeout_ms = None if due is None else max(0.0, due - time.monotonic()) * 1000
            ready = dict(poller.poll(timeout_ms))
            if not ready:
                return  # `due`: a poll, or a forgotten device's rescan
            if bell in ready:
                self._doorbell.clear()  # then look at `stopping` and `_rescan` again
            elif source is not None and source.take():
                return
