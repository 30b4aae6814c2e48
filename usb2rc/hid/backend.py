"""What every HID backend offers: device identity, the Device / Backend protocols, errors.

A backend enumerates devices (`DeviceInfo`) and opens them (`Device`). A reader thread owns an
open device and blocks in `read(timeout_s)`. `DeviceGone` from `read` means the device was
unplugged; any other `OSError` is a read failure (`ErrorCode.READ_FAILED`).
"""

from __future__ import annotations

import errno
from dataclasses import dataclass
from enum import IntEnum
from typing import Protocol, runtime_checkable

UDEV_RULES_FILE = "systemd/70-usb2rc.rules"
UDEV_RULES_INSTALLED = "/etc/udev/rules.d/70-usb2rc.rules"

# Top-level collections usb2rc uses: (usage page, usage); page 0x02 (Simulation Controls) whole.
GENERIC_DESKTOP = 0x01
SIMULATION_CONTROLS = 0x02
USABLE_DESKTOP_USAGES = {
    0x04: "Joystick",
    0x05: "Gamepad",
    0x08: "Multi-axis Controller",
}
DESKTOP_USAGE_NAMES = {
    0x01: "Pointer",
    0x02: "Mouse",
    0x06: "Keyboard",
    0x07: "Keypad",
    0x80: "System Control",
    **USABLE_DESKTOP_USAGES,
}
PAGE_NAMES = {0x0C: "Consumer", 0x0D: "Digitizer"}


class ErrorCode(IntEnum):
    """Device error codes: payload byte 5 of C2-16B service frame `3`."""

    READ_FAILED = 0x01
    DESCRIPTOR_UNUSABLE = 0x02
    OPEN_FAILED = 0x03
    PERMISSION_DENIED = 0x04
    CONFIG_CLASH = 0x05  # a second device matches a config entry already feeding its node


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


def permission_message(node: str) -> str:
    return (
        f"permission denied on {node}: install the udev rule {UDEV_RULES_FILE} to "
        f"{UDEV_RULES_INSTALLED} and run `sudo udevadm control --reload && "
        "sudo udevadm trigger --subsystem-match=hidraw`, or add your user to the group that "
        f"owns {node} (see `ls -l {node}`) and log in again"
    )


def is_usable_usage(usage_page: int, usage: int) -> bool:
    """Joystick-like top-level collections: Joystick, Gamepad, Multi-axis, Simulation page."""
    if usage_page == SIMULATION_CONTROLS:
        return True
    return usage_page == GENERIC_DESKTOP and usage in USABLE_DESKTOP_USAGES


def top_level_usage_name(usage_page: int, usage: int) -> str:
    if usage_page == GENERIC_DESKTOP and usage in DESKTOP_USAGE_NAMES:
        return DESKTOP_USAGE_NAMES[usage]
    if usage_page == SIMULATION_CONTROLS:
        return f"Simulation Controls 0x{usage:02X}"
    if usage_page in PAGE_NAMES:
        return PAGE_NAMES[usage_page]
    return f"0x{usage_page:04X}{usage:04X}"


def top_level_usage(descriptor: bytes) -> tuple[int, int]:
    """(usage page, usage) of the first top-level collection, from the items before it.

    Only the leading Usage Page / Usage items are read; field layout is descriptor.py's job.
    Returns (0, 0) when the descriptor opens no collection.
    """
    page = usage = 0
    pos = 0
    while pos < len(descriptor):
        prefix = descriptor[pos]
        if prefix == 0xFE:  # long item: never used for usages
            return 0, 0
        size = (0, 1, 2, 4)[prefix & 0x03]
        value = int.from_bytes(descriptor[pos + 1 : pos + 1 + size], "little")
        tag = prefix & 0xFC
        if tag == 0x04:  # Usage Page
            page = value
        elif tag == 0x08:  # Usage (4-byte form carries its own page)
            page, usage = (value >> 16, value & 0xFFFF) if size == 4 else (page, value)
        elif tag == 0xA0:  # Collection
            return page, usage
        pos += 1 + size
    return 0, 0


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

    @property
    def identity(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}:{self.serial}"

    @property
    def usable(self) -> bool:
        return is_usable_usage(self.usage_page, self.usage)

    @property
    def usage_name(self) -> str:
        return top_level_usage_name(self.usage_page, self.usage)


@runtime_checkable
class Device(Protocol):
    info: DeviceInfo

    def report_descriptor(self) -> bytes: ...

    def read(self, timeout_s: float) -> bytes | None:
        """One input report (with its ID byte when the device uses IDs), None on timeout.

        Raises DeviceGone when unplugged, another OSError on a read failure.
        """
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


def choose_backend(replay: str | None, loop: bool = False) -> Backend:
    """The replay backend on a folder of hid-recorder files, else hidapi (real devices)."""
    if replay:
        from usb2rc.hid.replay import ReplayBackend

        return ReplayBackend(replay, loop=loop)
    from usb2rc.hid.hidapi_backend import HidapiBackend

    return HidapiBackend()
