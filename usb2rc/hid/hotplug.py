"""HotplugMonitor: a thread that reports devices as they come and go.

It diffs `backend.enumerate()` by `DeviceInfo.key` every `poll_s`; on Linux with the hidapi
backend a pyudev monitor on the `hidraw` subsystem wakes it at once. Devices present when it
starts are reported in USB port-path order (natural sort: "1-1.2" < "1-1.10"), unless the
daemon took them first with `initial_devices()`. Removals are reported here too, though a
reader usually notices an unplug first.
"""

from __future__ import annotations

import contextlib
import logging
import re
import select
import sys
import threading
from collections.abc import Callable, Iterable
from typing import Any

from usb2rc.hid.backend import Backend, DeviceInfo
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

    def wait(self, timeout_s: float) -> None:
        ready, _, _ = select.select([self._monitor.fileno()], [], [], timeout_s)
        if ready:
            while self._monitor.poll(timeout=0) is not None:
                pass  # drain: one enumerate covers them all

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
        super().__init__("hid-hotplug")

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

    def run(self) -> None:
        waker = _UdevWaker.create() if self._use_udev else None
        try:
            while not self.stopping:
                self.scan()
                if waker is not None:
                    waker.wait(self._poll_s)
                else:
                    self.sleep(self._poll_s)
        finally:
            if waker is not None:
                waker.close()
