"""The real devices, through cython-hidapi (>= 0.14).

On Linux this uses the `hidraw` module of the hidapi package (the hidraw backend: it reports
each top-level usage and leaves the kernel driver alone); the default `hid` module there is
libusb, which reports no usage page and detaches the kernel driver. Elsewhere it uses `hid`.
The USB port path comes from sysfs on Linux, from pyusb elsewhere.

Reads: on Linux a device's reports are read from a non-blocking fd of its own on the hidraw
node (`HidapiDevice.read_fd`), one report a `read()`, as hidapi's `hid_read` reads them, but
without its `poll()` before each read and the list of ints cython-hidapi makes of each
report: at 1 kHz a device's reads are its largest cost, and a pulled reader's compiled pull
(`usb2rc.hid._speedups.pull_fd`) reads the fd in C. Each open fd on a hidraw node has its own
queue of every input report, so the hidapi handle's queue (kept for the descriptor and the
reports asked for at open) is never read. Elsewhere, or where the node cannot be opened so,
reads go through hidapi.

Outputs (`HidapiDevice.open_output`) go through a second hidapi handle on the same path:
hidapi keeps each handle's last error string unguarded, so two threads must never share a
handle, and a write never waits for a read. USB control transfers (vendor formats the
descriptor cannot say) go through pyusb, imported only when one is written.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import re
import select
import sys
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from usb2rc.hid.backend import (
    BUS_BLUETOOTH,
    BUS_USB,
    DeviceGone,
    DeviceInfo,
    DeviceOpenError,
    DevicePermissionError,
)
from usb2rc.hid.outputs import HidReport, OutputWrite, UsbControl
from usb2rc.hid.permissions import INSTALL_RULE, permission_message
from usb2rc.hid.usages import is_joystick_like, make_usage

log = logging.getLogger(__name__)

READ_SIZE = 1024  # hidraw returns one report per read; larger than any input report
# What the kernel queues for one open fd of a hidraw node: a ring of HIDRAW_BUFFER_SIZE (64)
# slots, one kept free. When it is full the kernel drops each new report (the newest).
KERNEL_QUEUE_REPORTS = 63
# cython-hidapi's read(n, timeout_ms): 0 (its default) means hid_read(), which waits for a
# report on a blocking handle; > 0 means hid_read_timeout() (poll for that long). Handles are
# blocking when opened, so open() makes them non-blocking: hid_read() then polls.
_USB_DEVICE_DIR = re.compile(r"^\d+-\d+(\.\d+)*$")  # "1-1.2"; not "usb1", not "1-1.2:1.0"
# hidapi's hid_bus_type (enumerate()'s `bus_type`, hidapi >= 0.13) and the kernel's bus
# numbers (sysfs HID_ID "0005:..."), for DeviceInfo.bus
_HIDAPI_BUSES = {1: BUS_USB, 2: BUS_BLUETOOTH}
_KERNEL_BUSES = {0x0003: BUS_USB, 0x0005: BUS_BLUETOOTH}


def load_hid_module() -> ModuleType:
    if sys.platform.startswith("linux"):
        import hidraw

        module: ModuleType = hidraw
    else:
        import hid

        module = hid
    return module


def port_path_from_sysfs(hidraw_name: str, sysfs_root: Path) -> str:
    """'1-1.2' for hidraw3: resolve .../hidraw/hidraw3/device, walk up to the USB device dir."""
    link = sysfs_root / "class" / "hidraw" / hidraw_name / "device"
    try:
        device_dir = link.resolve(strict=True)
    except OSError:
        return ""
    for part in (device_dir, *device_dir.parents):
        if _USB_DEVICE_DIR.match(part.name):
            return part.name
    return ""  # not USB (Bluetooth, uhid)


def bus_from_sysfs(hidraw_name: str, sysfs_root: Path) -> str:
    """The bus from the hid device's uevent HID_ID ("0005:0000054C:..." is "bluetooth")."""
    path = sysfs_root / "class" / "hidraw" / hidraw_name / "device" / "uevent"
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    for line in lines:
        if line.startswith("HID_ID="):
            with contextlib.suppress(ValueError):
                return _KERNEL_BUSES.get(int(line[7:].split(":")[0], 16), "")
    return ""


def descriptor_from_sysfs(hidraw_name: str, sysfs_root: Path) -> bytes | None:
    path = sysfs_root / "class" / "hidraw" / hidraw_name / "device" / "report_descriptor"
    try:
        return path.read_bytes()
    except OSError:
        return None


def port_path_from_pyusb(vid: int, pid: int, serial: str) -> str:
    """'1-1.2' from pyusb's bus and port_numbers; '' when pyusb or its backend is missing."""
    try:
        import usb.core

        for dev in usb.core.find(find_all=True, idVendor=vid, idProduct=pid) or ():
            if serial and _usb_serial(dev) != serial:
                continue
            ports = dev.port_numbers or ()
            if ports:
                return f"{dev.bus}-{'.'.join(str(p) for p in ports)}"
    except Exception as exc:
        log.debug("pyusb port path for %04x:%04x: %s", vid, pid, exc)
    return ""


def _usb_serial(dev: Any) -> str:
    try:
        return str(dev.serial_number or "")
    except Exception:
        return ""


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return str(value or "")


class HidapiBackend:
    name = "hidapi"

    def __init__(
        self,
        hid_module: ModuleType | Any | None = None,
        sysfs_root: str | os.PathLike[str] = "/sys",
        linux: bool | None = None,
    ) -> None:
        self._hid = hid_module if hid_module is not None else load_hid_module()
        self._sysfs = Path(sysfs_root)
        self._linux = sys.platform.startswith("linux") if linux is None else linux

    def _port_path(self, hidraw: str, vid: int, pid: int, serial: str) -> str:
        if self._linux and hidraw:
            return port_path_from_sysfs(os.path.basename(hidraw), self._sysfs)
        return port_path_from_pyusb(vid, pid, serial)

    def _bus(self, entry: dict[str, Any], hidraw: str) -> str:
        bus = _HIDAPI_BUSES.get(int(entry.get("bus_type", 0) or 0), "")
        if not bus and self._linux and hidraw:
            bus = bus_from_sysfs(os.path.basename(hidraw), self._sysfs)
        return bus

    def _info(self, entry: dict[str, Any], usage_page: int, usage: int) -> DeviceInfo:
        path = _text(entry.get("path"))
        hidraw = path if self._linux and path.startswith("/dev/hidraw") else ""
        vid, pid = int(entry.get("vendor_id", 0)), int(entry.get("product_id", 0))
        serial = _text(entry.get("serial_number"))
        return DeviceInfo(
            key=path,
            path=path,
            vid=vid,
            pid=pid,
            serial=serial,
            manufacturer=_text(entry.get("manufacturer_string")),
            product=_text(entry.get("product_string")),
            interface=int(entry.get("interface_number", -1)),
            port_path=self._port_path(hidraw, vid, pid, serial),
            usage_page=usage_page,
            usage=usage,
            hidraw=hidraw,
            bus=self._bus(entry, hidraw),
        )

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        """One DeviceInfo per device path; hidapi lists one entry per top-level usage."""
        usages: dict[str, list[tuple[int, int]]] = {}
        entries: dict[str, dict[str, Any]] = {}
        for entry in self._hid.enumerate(0, 0):
            path = _text(entry.get("path"))
            entries.setdefault(path, entry)
            pair = (int(entry.get("usage_page", 0)), int(entry.get("usage", 0)))
            usages.setdefault(path, []).append(pair)
        infos = []
        for path, pairs in usages.items():
            usable = [p for p in pairs if is_joystick_like(make_usage(*p))]
            if usable or all:
                infos.append(self._info(entries[path], *(usable or pairs)[0]))
        return infos

    def open(self, info: DeviceInfo) -> HidapiDevice:
        handle = open_handle(self._hid, info)
        try:
            handle.set_nonblocking(1)
        except (OSError, ValueError) as exc:
            with contextlib.suppress(Exception):
                handle.close()
            raise open_error(info, exc) from exc
        return HidapiDevice(info, handle, self._hid, self._sysfs)


def open_handle(hid: Any, info: DeviceInfo) -> Any:
    """A new hidapi handle on the device; the errors of `HidapiBackend.open`."""
    handle = hid.device()
    try:
        handle.open_path(info.path.encode())
    except (OSError, ValueError) as exc:
        raise open_error(info, exc) from exc
    return handle


def open_error(info: DeviceInfo, exc: Exception) -> OSError:
    node = info.hidraw
    if node and not os.path.exists(node):
        return DeviceGone(f"{node}: unplugged before it could be opened")
    if node and not os.access(node, os.R_OK | os.W_OK):
        return DevicePermissionError(errno.EACCES, permission_message(node))
    if isinstance(exc, PermissionError):
        return DevicePermissionError(errno.EACCES, permission_message(node or info.path))
    return DeviceOpenError(errno.EIO, f"{node or info.path}: cannot open {info.identity}: {exc}")


def open_read_fd(info: DeviceInfo) -> int | None:
    """A non-blocking fd of its own on the device's hidraw node (Linux), for its reads; None
    where there is none, or it cannot be opened (the reads then go through hidapi)."""
    if not info.hidraw or not sys.platform.startswith("linux"):
        return None
    try:
        return os.open(info.hidraw, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        log.debug("%s: reads go through hidapi (no fd of its own: %s)", info.hidraw, exc)
        return None


class HidapiDevice:
    def __init__(self, info: DeviceInfo, handle: Any, hid_module: Any, sysfs_root: Path) -> None:
        self.info = info
        self._handle = handle
        self._hid = hid_module
        self._sysfs = sysfs_root
        self._descriptor: bytes | None = None
        # opened before the reports at open are asked for: a report sent meanwhile is queued
        self.read_fd = open_read_fd(info)
        # the errno of a read the compiled pull met on `read_fd`: raised by the next read
        self.failed_read: int | None = None
        # drains of `read_fd` that found the kernel's queue full: reports were dropped
        self.queue_full = 0
        # told of each such drain (its pulled reader: it then pulls the device between steps)
        self.on_queue_full: Callable[[int], None] | None = None
        self._drained = 0  # reports this drain of `read_fd` read so far
        self._pending: deque[bytes] = deque(self._current_reports())

    def report_descriptor(self) -> bytes:
        if self._descriptor is None:
            self._descriptor = self._read_descriptor()
        return self._descriptor

    def _read_descriptor(self) -> bytes:
        if self.info.hidraw:
            data = descriptor_from_sysfs(os.path.basename(self.info.hidraw), self._sysfs)
            if data:
                return data
        try:
            return bytes(self._handle.get_report_descriptor())
        except (OSError, ValueError) as exc:
            raise DeviceOpenError(
                errno.EIO, f"{self.info.path}: cannot read its report descriptor: {exc}"
            ) from exc

    def _current_reports(self) -> list[bytes]:
        """Ask the device for each input report (DESIGN: state at open); failures ignored."""
        try:
            from usb2rc.hid.descriptor import parse_descriptor

            layout = parse_descriptor(self.report_descriptor())
        except Exception:
            return []
        reports = []
        for report_id, length in sorted(layout.input_report_lengths.items()):
            with contextlib.suppress(Exception):
                data = bytes(self._handle.get_input_report(report_id, length + 1))
                # hidapi returns the report number first; 0 means "no IDs": drop it
                report = data[1:] if report_id == 0 else data
                if len(report) >= length:
                    reports.append(report)
        return reports

    def _gone(self) -> bool:
        if self.info.hidraw:
            return not os.path.exists(self.info.hidraw)
        try:
            present = self._hid.enumerate(self.info.vid, self.info.pid)
        except Exception:
            return False
        return all(_text(e.get("path")) != self.info.path for e in present)

    def read(self, timeout_s: float) -> bytes | None:
        """A report, or None after at most `timeout_s` (0: poll, never wait)."""
        if self._pending:
            return self._pending.popleft()
        try:
            data = self._read_handle(timeout_s)
        except (OSError, ValueError) as exc:
            if self._gone():
                raise DeviceGone(f"{self.info.path}: unplugged") from exc
            raise OSError(errno.EIO, f"{self.info.path}: read failed: {exc}") from exc
        if data:
            return bytes(data)
        # A poll that finds nothing is the normal end of a drain; only a wait that timed out
        # is worth a look at whether the device is still there.
        if timeout_s > 0 and self._gone():
            raise DeviceGone(f"{self.info.path}: unplugged")
        return None

    def _read_handle(self, timeout_s: float) -> Any:
        if self.read_fd is not None:
            return self._read_fd(self.read_fd, timeout_s)
        if timeout_s <= 0:
            return self._handle.read(READ_SIZE)  # non-blocking handle: hid_read() polls
        # Round up: a timeout that rounds to 0 ms would mean hid_read(), not a short wait.
        return self._handle.read(READ_SIZE, max(1, math.ceil(timeout_s * 1000)))

    def _read_fd(self, fd: int, timeout_s: float) -> bytes | None:
        """One report from the device's own fd, None if none came within `timeout_s`."""
        if self.failed_read is not None:
            code, self.failed_read = self.failed_read, None
            raise OSError(code, os.strerror(code))
        if timeout_s > 0:
            self._drained = 0  # a wait, not a drain
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            if not poller.poll(max(1, math.ceil(timeout_s * 1000))):
                return None
        try:
            report = os.read(fd, READ_SIZE)
        except BlockingIOError:
            drained, self._drained = self._drained, 0
            if drained >= KERNEL_QUEUE_REPORTS:
                self.drained_a_full_queue(drained)
            return None
        if not report:  # a report is never empty: the node hung up (hidapi: POLLHUP, an error)
            raise OSError(errno.ENODEV, "the device's node hung up")
        self._drained += timeout_s <= 0
        return report

    def drained_a_full_queue(self, reports: int) -> None:
        """A drain of `read_fd` read `reports`, as many as the kernel queues: the queue was
        full, and the reports sent while it was were dropped (the newest). Counted (the
        device's stats line), told to its reader (`on_queue_full`: from then on it pulls the
        device between the steps too), and said in the log the first time (the compiled
        pull calls it too)."""
        self.queue_full += 1
        if self.on_queue_full is not None:
            self.on_queue_full(KERNEL_QUEUE_REPORTS)
        if self.queue_full > 1:
            return
        log.warning(
            "%s: %d reports had queued since its last pull, as many as the kernel keeps for"
            " a reader: those sent after them were dropped. Its node is stepped too seldom"
            " for its report rate (a device faster than about 3 kHz, a node no output reads,"
            " a stalled daemon): its reader pulls it between the steps from now on, as often"
            " as its rate needs. The stats count each full pull (`kernel queue full`)",
            self.info.hidraw or self.info.path,
            reports,
        )

    def open_output(self) -> HidapiOutputPort:
        """A second handle on the same path (module docstring: never the reads' handle)."""
        return HidapiOutputPort(self.info, open_handle(self._hid, self.info), self._gone)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._handle.close()
        fd, self.read_fd = self.read_fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)


class HidapiOutputPort:
    """Writes to one device: HID output reports on its own hidapi handle, USB control
    transfers through pyusb (found by VID:PID and port path when the first one is written).
    Used by one thread (the device's reader)."""

    def __init__(self, info: DeviceInfo, handle: Any, gone: Callable[[], bool]) -> None:
        self.info = info
        self._handle = handle
        self._gone = gone
        self._usb: Any = None  # the pyusb device, once a control transfer needed it

    def write(self, w: OutputWrite) -> None:
        if isinstance(w, HidReport):
            self._write_report(w.data)
        else:
            self._control(w)

    def _write_report(self, data: bytes) -> None:
        what = f"{self.info.hidraw or self.info.path}: output report {data[0] if data else 0}"
        try:
            written = self._handle.write(data)
        except (OSError, ValueError) as exc:
            written, cause = -1, str(exc)
        else:
            # cython-hidapi returns hid_write()'s result: -1 on failure (the reason in the
            # handle's error()), never raises for it (tests/hidapi_contract.py)
            cause = "" if written >= 0 else self._handle_error()
        if written >= 0:
            return
        if self._gone():
            raise DeviceGone(f"{what}: unplugged")
        raise OSError(errno.EIO, f"{what} refused by the device: {cause or 'no reason given'}")

    def _handle_error(self) -> str:
        try:
            return str(self._handle.error() or "")
        except Exception:
            return ""

    def _control(self, w: UsbControl) -> None:
        device = self._usb_device()
        try:
            device.ctrl_transfer(w.request_type, w.request, w.w_value, w.w_index, w.data)
        except Exception as exc:  # pyusb's USBError, USBTimeoutError
            raise self._usb_error(exc) from exc

    def _usb_error(self, exc: Exception) -> OSError:
        code = getattr(exc, "errno", None)
        where = f"USB device {self.info.vid:04x}:{self.info.pid:04x} at {self.info.port_path}"
        if code == errno.EACCES:
            return DevicePermissionError(
                errno.EACCES,
                f"permission denied on the {where} (its /dev/bus/usb node): install the udev "
                f"rule with {INSTALL_RULE}, which gives the usb2rc group write access to it",
            )
        if code == errno.ENODEV or self._gone():
            return DeviceGone(f"{where}: unplugged")
        return OSError(errno.EIO, f"{where}: control transfer refused: {exc}")

    def _usb_device(self) -> Any:
        if self._usb is None:
            self._usb = find_usb_device(self.info)
        return self._usb

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._handle.close()
        if self._usb is not None:
            with contextlib.suppress(Exception):
                import usb.util

                usb.util.dispose_resources(self._usb)
            self._usb = None


def find_usb_device(info: DeviceInfo) -> Any:
    """The pyusb device of `info`: its VID:PID at its port path (or with its serial, or the
    only one). OSError saying what is missing when there is none or pyusb cannot look."""
    try:
        import usb.core
    except ImportError as exc:
        raise OSError(errno.ENOPKG, f"USB control transfers need pyusb: {exc}") from exc
    try:
        found = list(usb.core.find(find_all=True, idVendor=info.vid, idProduct=info.pid) or ())
    except Exception as exc:  # usb.core.NoBackendError: no libusb
        raise OSError(
            errno.ENOPKG, f"pyusb cannot reach USB devices ({exc}): install libusb-1.0"
        ) from exc
    for dev in found:
        ports = getattr(dev, "port_numbers", None) or ()
        port_path = f"{dev.bus}-{'.'.join(str(p) for p in ports)}" if ports else ""
        if info.port_path and port_path == info.port_path:
            return dev
        if not info.port_path and info.serial and _usb_serial(dev) == info.serial:
            return dev
    if len(found) == 1 and not info.port_path:
        return found[0]
    raise DeviceGone(
        f"USB device {info.vid:04x}:{info.pid:04x} at {info.port_path or '?'}: not found by pyusb"
    )
