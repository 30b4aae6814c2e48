"""What every HID backend offers: device identity, the Device / Backend protocols, errors.

This module knows none of the backends (hid/hidapi_backend.py, hid/replay.py); the factory
that picks one is hid/choose.py, and the help text for permission problems hid/permissions.py.

A backend enumerates devices (`DeviceInfo`) and opens them (`Device`). A reader thread owns an
open device and blocks in `read(timeout_s)`. `DeviceGone` from `read` means the device was
unplugged; any other `OSError` is a read failure (`ErrorCode.READ_FAILED`).

Outputs (LEDs, rumble, a display) go through a port of their own (`Device.open_output()`):
a second handle on the device, so a write never shares what the reads use, and never waits
for a read. The reader thread opens, writes and closes it (usb2rc.hid.reader).
"""

from __future__ import annotations

import errno
from dataclasses import dataclass
from enum import IntEnum
from typing import Protocol, runtime_checkable

from usb2rc.hid.outputs import OutputWrite
from usb2rc.hid.usages import is_joystick_like, make_usage, top_level_usage_name


class ErrorCode(IntEnum):
    """Device error codes: payload byte 5 of C2-16B service frame `3`."""

    READ_FAILED = 0x01
    DESCRIPTOR_UNUSABLE = 0x02
    OPEN_FAILED = 0x03
    PERMISSION_DENIED = 0x04
    CONFIG_CLASH = 0x05  # a second device matches a config entry already feeding its node
    BAD_REPORTS = 0x06  # every report of a run was refused (usb2rc.hid.reader)
    SILENT = 0x07  # a streaming device sent no report for too long (usb2rc.nodes.silence)


class _Plain:
    """str() is the message alone: a user reads "permission denied on ...", not "[Errno 13]"."""

    strerror: str | None

    def __str__(self) -> str:
        return self.strerror or OSError.__str__(self)  # type: ignore[arg-type]


class DeviceGone(_Plain, OSError):
    """The device was unplugged (its node vanished); not a read failure."""

    def __init__(self, message: str = "device unplugged") -> None:
        super().__init__(errno.ENODEV, message)


class DevicePermissionError(_Plain, PermissionError):
    """The device node exists but this user may not open it; the message says how to fix it."""


class DeviceOpenError(_Plain, OSError):
    """The device could not be opened for another reason; the message says why."""


@dataclass(frozen=True)
class DeviceInfo:
    key: str  # unique while plugged: hidraw path, replay file path + inode + mtime
    path: str  # what Backend.open takes
    vid: int
    pid: int
    serial: str = ""
    manufacturer: str = ""
    product: str = ""
    interface: int = -1
    port_path: str = ""  # "1-1.2"; replay: "replay-<file stem>"; "" when unknown
    usage_page: int = 0
    usage: int = 0
    hidraw: str = ""  # "/dev/hidraw3" or ""
    bus: str = ""  # "usb", "bluetooth", or "" (other or unknown): vendor output formats differ

    @property
    def identity(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}:{self.serial}"

    @property
    def application(self) -> int:
        """The top-level collection's usage, `(page << 16) | id` (hid/usages.py)."""
        return make_usage(self.usage_page, self.usage)

    @property
    def usable(self) -> bool:
        return is_joystick_like(self.application)

    @property
    def usage_name(self) -> str:
        return top_level_usage_name(self.application)


BUS_USB, BUS_BLUETOOTH = "usb", "bluetooth"


@runtime_checkable
class OutputPort(Protocol):
    """Writes to one device's outputs; one thread at a time (its reader's)."""

    def write(self, w: OutputWrite) -> None:
        """Send one HID output report or USB control transfer. Raises DeviceGone when the
        device is unplugged, another OSError when it refuses the write; its message says
        what was refused and what to do (permissions, a missing library)."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class Device(Protocol):
    info: DeviceInfo

    def report_descriptor(self) -> bytes: ...

    def read(self, timeout_s: float) -> bytes | None:
        """One input report (with its ID byte when the device uses IDs), None on timeout.

        Raises DeviceGone when unplugged, another OSError on a read failure.
        """
        ...

    def open_output(self) -> OutputPort:
        """A port for the device's outputs, apart from the reads (its own handle where the
        backend has handles). Raises OSError (DevicePermissionError, DeviceGone) when it
        cannot be opened; close it before (or with) the device."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class Backend(Protocol):
    name: str

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        """Present devices; only usable top-level usages unless `all`."""
        ...

    def open(self, info: DeviceInfo) -> Device:
        """Raises DevicePermissionError / DeviceOpenError / DeviceGone (all OSError)."""
        ...
