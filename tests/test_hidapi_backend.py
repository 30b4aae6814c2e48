"""HidapiBackend with a fake hid module and a fake sysfs tree (no hardware here)."""

from __future__ import annotations

import errno
import threading
from pathlib import Path
from typing import Any

import hidapi_contract as contract
import pytest

from usb2rc.hid import hidapi_backend
from usb2rc.hid.backend import DeviceGone, DeviceOpenError, DevicePermissionError
from usb2rc.hid.hidapi_backend import HidapiBackend, port_path_from_sysfs

T16000M = bytes.fromhex(
    "05010904a101050919012910150025013500450175019510810205010939150025073500463b016514750495"
    "01814281010930150026ff3f350046ff3f6500750e950181027502950181010931750e950181027502950181"
    "0109350936150026ff00350046ff0065007508950281027508953781010600ff27ffff0000090175089504b1"
    "a2c0"
)
TWCS = bytes.fromhex(
    "05010904a10185010930093109350933093409360937150026ff037510950781020932150027ffff00007510"
    "950181020939150025073500463b016514750495018142650005091901290e150025017501950e8102750695"
    "0181010600ff09217508952c810206f0ff094085f109477508953fb102c0"
)


def entry(path: str, vid: int, pid: int, page: int, usage: int, **kw: Any) -> dict[str, Any]:
    """One enumerate() dict, with the keys and types cython-hidapi 0.15 gives (the contract
    checks them against the real library)."""
    return {
        "path": path.encode(),
        "vendor_id": vid,
        "product_id": pid,
        "serial_number": kw.get("serial", ""),
        "release_number": 0,
        "manufacturer_string": kw.get("manufacturer", "Thrustmaster"),
        "product_string": kw.get("product", "Stick"),
        "usage_page": page,
        "usage": usage,
        "interface_number": 0,
        "bus_type": 1,
    }


BLOCK_LIMIT_S = 10.0  # a blocking read the real library would never end fails after this


class FakeHandle:
    """cython-hidapi's `device` (tests/hidapi_contract.py says what that is, measured):
    blocking after open; read(n) and read(n, 0) wait for a report, read(n, ms > 0) waits at
    most ms; set_nonblocking(1) makes read(n) / read(n, 0) poll; at unplug a waiting read
    wakes and every read raises OSError("read error"); errors carry no errno."""

    def __init__(self, module: FakeHid) -> None:
        self.module = module
        self.path: str | None = None
        self.closed = False
        self.blocking = True
        self.last_error = ""

    def open_path(self, path: bytes) -> None:
        if not isinstance(path, bytes):
            raise TypeError(
                f"Argument 'path' has incorrect type (expected bytes, got {type(path).__name__})"
            )
        name = path.decode()
        if name in self.module.refuse or not self.module.present(name):
            raise OSError("open failed")
        self.path, self.closed, self.blocking = name, False, True

    def _open_path(self) -> str:
        if self.path is None or self.closed:
            raise ValueError("not open")
        return self.path

    def get_report_descriptor(self) -> list[int]:
        return list(self.module.descriptors[self._open_path()])

    def get_input_report(self, report_id: int, length: int) -> list[int]:
        self._open_path()
        if report_id not in self.module.input_reports:
            raise OSError("read error")  # the device does not answer GET_REPORT
        return list(self.module.input_reports[report_id])[:length]

    def set_nonblocking(self, value: int) -> int:
        self._open_path()
        self.blocking = not value
        return 0

    def _wait_s(self, timeout_ms: int) -> float | None:
        """hid_read_timeout(ms) for ms > 0, else hid_read(): forever, or a poll."""
        if timeout_ms > 0:
            return timeout_ms / 1000
        return None if self.blocking else 0.0

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        path = self._open_path()
        self.module.read_timeouts.append(timeout_ms)
        wait = self._wait_s(timeout_ms)
        module = self.module
        with module.changed:
            module.changed.wait_for(
                lambda: path in module.gone or module.reads,
                BLOCK_LIMIT_S if wait is None else wait,
            )
            if path in module.gone:
                raise OSError("read error")  # even with reports still queued
            if not module.reads:
                if wait is None:
                    raise AssertionError(
                        f"read({max_length}, {timeout_ms}) on a blocking handle waited "
                        f"{BLOCK_LIMIT_S} s: the real library would wait forever"
                    )
                return []
            item = module.reads.pop(0)
        if isinstance(item, Exception):
            raise item
        return list(item)[:max_length]  # b"": a scripted empty read (a timeout)

    def write(self, data: Any) -> int:
        """hid_write(): the bytes written, or -1 with the reason in error(); never raises
        for a failed write."""
        path = self._open_path()
        data = bytes(data)
        if path in self.module.gone or path in self.module.refuse_writes:
            self.last_error = contract.WRITE_GONE_ERROR
            return -1
        self.module.written.setdefault(path, bytearray()).extend(data)
        return len(data)

    def error(self) -> str:
        self._open_path()
        return self.last_error

    def close(self) -> None:
        self.closed = True


class FakeHid:
    """The `hidraw` module. `reads`: what the open device sends, in order (bytes, or an
    exception its read raises); `push()` adds one and wakes a waiting read."""

    def __init__(self, entries: list[dict[str, Any]]) -> None:
        self.entries = entries
        self.refuse: set[str] = set()
        self.descriptors: dict[str, bytes] = {}
        self.input_reports: dict[int, bytes] = {}
        self.reads: list[bytes | Exception] = []
        self.read_timeouts: list[int] = []
        self.gone: set[str] = set()
        self.changed = threading.Condition()
        self.written: dict[str, bytearray] = {}  # path -> what its device received
        self.refuse_writes: set[str] = set()  # paths whose writes fail (-1)
        self.opened: list[FakeHandle] = []

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict[str, Any]]:
        return [
            e
            for e in self.entries
            if vendor_id in (0, e["vendor_id"]) and product_id in (0, e["product_id"])
        ]

    def device(self) -> FakeHandle:
        handle = FakeHandle(self)
        self.opened.append(handle)
        return handle

    def present(self, path: str) -> bool:
        return path not in self.gone and any(e["path"] == path.encode() for e in self.entries)

    def push(self, item: bytes | Exception) -> None:
        with self.changed:
            self.reads.append(item)
            self.changed.notify_all()

    def unplug(self, path: str) -> None:
        with self.changed:
            self.entries[:] = [e for e in self.entries if e["path"] != path.encode()]
            self.gone.add(path)
            self.changed.notify_all()


class FakeRig:
    """tests/hidapi_contract.py's Rig on the fake module."""

    def __init__(self) -> None:
        self.hid = FakeHid([])
        self._plugged = 0

    def plug(self) -> bytes:
        self._plugged += 1
        path = f"/dev/hidraw{self._plugged}"
        self.hid.entries.append(entry(path, contract.VID, contract.PID, 1, 4, serial=""))
        self.hid.descriptors[path] = contract.DESCRIPTOR
        self.hid.reads.clear()
        return path.encode()

    def report(self, path: bytes, data: bytes) -> None:
        self.hid.push(data)

    def unplug(self, path: bytes) -> None:
        self.hid.unplug(path.decode())

    def written(self, path: bytes) -> bytes:
        return bytes(self.hid.written.pop(path.decode(), b""))


def test_the_fake_keeps_the_real_librarys_contract() -> None:
    """The same checks pass on the real library over umockdev (test_real_hidapi.py)."""
    assert contract.failures(contract.run_contract(FakeRig())) == []


def make_sysfs(root: Path, hidraw: str, usb_dir: str, descriptor: bytes | None) -> None:
    """/sys/class/hidraw/<hidraw>/device -> .../usb1/<usb_dir>/<usb_dir>:1.0/0003:044F:B10A.0001"""
    hid_dir = (
        root
        / "devices/pci0000:00/0000:00:14.0/usb1"
        / usb_dir
        / f"{usb_dir}:1.0"
        / "0003:044F:B10A.0001"
    )
    hid_dir.mkdir(parents=True)
    if descriptor is not None:
        (hid_dir / "report_descriptor").write_bytes(descriptor)
    node = root / "class/hidraw" / hidraw
    node.mkdir(parents=True)
    (node / "device").symlink_to(hid_dir)


def test_port_path_from_sysfs(tmp_path: Path) -> None:
    make_sysfs(tmp_path, "hidraw3", "1-1.2", None)
    make_sysfs(tmp_path / "b", "hidraw4", "3-10.4.1", None)
    assert port_path_from_sysfs("hidraw3", tmp_path) == "1-1.2"
    assert port_path_from_sysfs("hidraw4", tmp_path / "b") == "3-10.4.1"
    assert port_path_from_sysfs("hidraw9", tmp_path) == ""


def test_bluetooth_device_has_no_port_path(tmp_path: Path) -> None:
    hid_dir = tmp_path / "devices/virtual/misc/uhid/0005:054C:09CC.0007"
    hid_dir.mkdir(parents=True)
    (tmp_path / "class/hidraw/hidraw5").mkdir(parents=True)
    (tmp_path / "class/hidraw/hidraw5/device").symlink_to(hid_dir)
    assert port_path_from_sysfs("hidraw5", tmp_path) == ""


def test_enumerate_filters_and_fills_identity(tmp_path: Path) -> None:
    make_sysfs(tmp_path, "hidraw0", "1-1.10", T16000M)
    fake = FakeHid(
        [
            entry("/dev/hidraw0", 0x044F, 0xB10A, 1, 4, serial="S1", product="T.16000M"),
            entry("/dev/hidraw1", 0x046D, 0xC52B, 1, 6, product="Keyboard"),
            entry("/dev/hidraw1", 0x046D, 0xC52B, 0x0C, 1, product="Keyboard"),
            entry("/dev/hidraw2", 0x06A3, 0x0763, 2, 0xBA, product="Pedals"),
            entry("/dev/hidraw3", 0x1234, 0x0001, 1, 5, product="Pad"),
            entry("/dev/hidraw4", 0x1234, 0x0002, 1, 8, product="SpaceMouse"),
            # one device, several top-level collections: the joystick one is reported
            entry("/dev/hidraw5", 0x1234, 0x0003, 0x0C, 1, product="Combo"),
            entry("/dev/hidraw5", 0x1234, 0x0003, 1, 4, product="Combo"),
        ]
    )
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=True)
    infos = backend.enumerate()
    assert [i.path for i in infos] == [f"/dev/hidraw{n}" for n in (0, 2, 3, 4, 5)]
    stick = infos[0]
    assert (stick.vid, stick.pid, stick.serial, stick.product) == (0x044F, 0xB10A, "S1", "T.16000M")
    assert (stick.key, stick.hidraw, stick.port_path) == ("/dev/hidraw0", "/dev/hidraw0", "1-1.10")
    assert (stick.usage_page, stick.usage, stick.usage_name) == (1, 4, "Joystick")
    assert stick.identity == "044f:b10a:S1"
    assert (infos[-1].usage_page, infos[-1].usage) == (1, 4)
    everything = backend.enumerate(all=True)
    assert [i.path for i in everything] == [f"/dev/hidraw{n}" for n in range(6)]
    assert everything[1].usage_name == "Keyboard"


def test_open_reads_descriptor_from_sysfs_and_current_state(tmp_path: Path) -> None:
    make_sysfs(tmp_path, "hidraw0", "1-2", T16000M)
    fake = FakeHid([entry("/dev/hidraw0", 0x044F, 0xB10A, 1, 4)])
    current = bytes(range(64))
    fake.input_reports = {0: b"\x00" + current}  # hidapi puts report number 0 first
    fake.reads = [b"\x01" * 64, b""]
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=True)
    device = backend.open(backend.enumerate()[0])
    assert device.report_descriptor() == T16000M
    assert device.read(0.1) == current  # the state asked for at open comes first
    assert device.read(0.1) == b"\x01" * 64
    assert fake.read_timeouts == [100]


def test_reads_never_wait_longer_than_asked(tmp_path: Path) -> None:
    """The handle is made non-blocking: a drain (0 s) polls; a wait below 1 ms still waits
    (rounded up), because cython-hidapi's timeout 0 is a wait for the next report."""
    fake = FakeHid([entry("/dev/hidrawX", 0x044F, 0xB10A, 1, 4)])
    fake.descriptors["/dev/hidrawX"] = T16000M
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=False)
    device = backend.open(backend.enumerate()[0])
    fake.reads = [b"\x02" * 64]
    assert device.read(0.0) == b"\x02" * 64
    assert device.read(0.0) is None  # an empty poll: not a reason to look for an unplug
    assert device.read(0.0004) is None
    assert fake.read_timeouts == [0, 0, 1]


def test_current_state_with_report_ids_keeps_the_id(tmp_path: Path) -> None:
    fake = FakeHid([entry("/dev/hidrawX", 0x044F, 0xB687, 1, 4)])
    fake.descriptors["/dev/hidrawX"] = TWCS  # no sysfs: from the device
    fake.input_reports = {1: b"\x01" + bytes(63)}
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=False)
    device = backend.open(backend.enumerate()[0])
    assert device.report_descriptor() == TWCS
    assert device.read(0.1) == b"\x01" + bytes(63)


def test_read_timeout_is_none_and_gone_is_device_gone(tmp_path: Path, monkeypatch) -> None:
    fake = FakeHid([entry("/dev/hidraw0", 1, 2, 1, 4)])
    fake.descriptors["/dev/hidraw0"] = b""
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=True)
    device = backend.open(backend.enumerate()[0])
    present = {"/dev/hidraw0"}
    monkeypatch.setattr(hidapi_backend.os.path, "exists", lambda p: p in present)
    fake.reads = [b"", OSError("read error")]
    assert device.read(0.1) is None
    with pytest.raises(OSError) as caught:
        device.read(0.1)
    assert not isinstance(caught.value, DeviceGone)
    assert caught.value.errno == errno.EIO
    present.clear()
    fake.reads = [OSError("read error")]
    with pytest.raises(DeviceGone):
        device.read(0.1)
    fake.reads = [b""]
    with pytest.raises(DeviceGone):
        device.read(0.1)
    device.close()


def test_gone_without_hidraw_asks_enumerate(tmp_path: Path) -> None:
    fake = FakeHid([entry("IOService:/stick", 1, 2, 1, 4)])
    fake.descriptors["IOService:/stick"] = b""
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=False)
    device = backend.open(backend.enumerate()[0])
    fake.entries.clear()
    fake.reads = [OSError("read error")]
    with pytest.raises(DeviceGone):
        device.read(0.1)


def test_open_errors_name_the_fix(tmp_path: Path, monkeypatch) -> None:
    fake = FakeHid([entry("/dev/hidraw7", 1, 2, 1, 4)])
    fake.refuse.add("/dev/hidraw7")
    backend = HidapiBackend(fake, sysfs_root=tmp_path, linux=True)
    info = backend.enumerate()[0]
    monkeypatch.setattr(hidapi_backend.os.path, "exists", lambda p: True)
    monkeypatch.setattr(hidapi_backend.os, "access", lambda p, mode: False)
    with pytest.raises(DevicePermissionError) as caught:
        backend.open(info)
    message = str(caught.value)
    assert "/dev/hidraw7" in message and "`usb2rc install-system`" in message
    assert "/etc/udev/rules.d/70-usb2rc.rules" in message and "systemd/" not in message
    assert "sudo udevadm control --reload && sudo udevadm trigger" in message
    assert "group" in message
    monkeypatch.setattr(hidapi_backend.os, "access", lambda p, mode: True)
    with pytest.raises(DeviceOpenError):
        backend.open(info)
    monkeypatch.setattr(hidapi_backend.os.path, "exists", lambda p: False)
    with pytest.raises(DeviceGone):
        backend.open(info)


def test_linux_uses_the_hidraw_module(monkeypatch) -> None:
    monkeypatch.setattr(hidapi_backend.sys, "platform", "linux")
    assert hidapi_backend.load_hid_module().__name__ == "hidraw"
    monkeypatch.setattr(hidapi_backend.sys, "platform", "darwin")
    assert hidapi_backend.load_hid_module().__name__ == "hid"
