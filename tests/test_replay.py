"""ReplayBackend: files are devices, timing from open, unplug, faults, loop, problems."""

from __future__ import annotations

import errno
import os
import threading
import time
from pathlib import Path

import pytest

from usb2rc.hid.backend import Backend, Device, DeviceGone, DeviceOpenError
from usb2rc.hid.recording import RecordedEvent, Recording, format_recording
from usb2rc.hid.replay import ReplayBackend, install_file

JOYSTICK = bytes.fromhex("05010904a101c0")
MOUSE = bytes.fromhex("05010902a101c0")


def recording_text(
    events: list[tuple[float, bytes]],
    descriptor: bytes = JOYSTICK,
    name: str = "Test Stick",
    fault_at: float | None = None,
) -> str:
    rec = Recording(
        descriptor, name, "", 3, 0x044F, 0xB10A, tuple(RecordedEvent(t, r) for t, r in events)
    )
    text = format_recording(rec)
    if fault_at is not None:
        text = f"# usb2rc-fault: read-error at {fault_at}\n" + text
    return text


def numbered(n: int, step: float = 0.0) -> list[tuple[float, bytes]]:
    return [(i * step, i.to_bytes(2, "little")) for i in range(n)]


def read_all(device: Device, n: int) -> list[bytes]:
    out: list[bytes] = []
    while len(out) < n:
        report = device.read(5.0)
        assert report is not None, f"timed out after {len(out)} of {n} reports"
        out.append(report)
    return out


def test_protocols_and_device_info(tmp_path: Path) -> None:
    install_file(tmp_path / "stick.hid", recording_text(numbered(1)))
    backend = ReplayBackend(tmp_path)
    assert isinstance(backend, Backend)
    [info] = backend.enumerate()
    assert (info.vid, info.pid, info.product) == (0x044F, 0xB10A, "Test Stick")
    assert (info.serial, info.port_path, info.hidraw) == ("stick", "replay-stick", "")
    assert info.identity == "044f:b10a:stick"
    assert (info.usage_page, info.usage, info.usage_name) == (1, 4, "Joystick")
    device = backend.open(info)
    assert isinstance(device, Device)
    assert device.report_descriptor() == JOYSTICK
    device.close()


def test_all_file_names_count_and_problems_are_reported(tmp_path: Path) -> None:
    install_file(tmp_path / "a.hid", recording_text(numbered(1)))
    install_file(tmp_path / "b.txt", recording_text(numbered(1)))
    install_file(tmp_path / "c.rec", recording_text(numbered(1)))
    install_file(tmp_path / "mouse.hid", recording_text(numbered(1), descriptor=MOUSE))
    install_file(tmp_path / "broken.hid", "E: 0.0 1 00\n")
    backend = ReplayBackend(tmp_path)
    assert [i.serial for i in backend.enumerate()] == ["a", "b", "c"]
    assert [i.serial for i in backend.enumerate(all=True)] == ["a", "b", "c", "mouse"]
    [problem] = backend.problems
    assert "broken.hid" in problem and "R:" in problem


def test_plays_every_event_in_order_then_holds(tmp_path: Path) -> None:
    install_file(tmp_path / "s.hid", recording_text(numbered(50, step=0.001)))
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    assert read_all(device, 50) == [i.to_bytes(2, "little") for i in range(50)]
    assert device.read(0.05) is None  # played once; holds
    device.close()


def test_many_events_due_together_come_back_to_back(tmp_path: Path) -> None:
    # 8 kHz for a quarter second, all due by the time the reader looks
    events = [(i / 8000, i.to_bytes(4, "little")) for i in range(2000)]
    install_file(tmp_path / "fast.hid", recording_text(events))
    backend = ReplayBackend(tmp_path, speed=1000.0)
    device = backend.open(backend.enumerate()[0])
    assert read_all(device, 2000) == [r for _, r in events]
    device.close()


def test_events_wait_for_their_time(tmp_path: Path) -> None:
    install_file(tmp_path / "late.hid", recording_text([(30.0, b"\x01")]))
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    assert device.read(0.01) is None
    device.close()


def test_loop_replays_forever(tmp_path: Path) -> None:
    install_file(tmp_path / "l.hid", recording_text(numbered(3, step=0.001)))
    backend = ReplayBackend(tmp_path, loop=True, speed=10.0)
    device = backend.open(backend.enumerate()[0])
    assert read_all(device, 9) == [i.to_bytes(2, "little") for i in (0, 1, 2) * 3]
    device.close()


def test_removed_file_is_unplug(tmp_path: Path) -> None:
    path = install_file(tmp_path / "s.hid", recording_text(numbered(1)))
    backend = ReplayBackend(tmp_path)
    info = backend.enumerate()[0]
    device = backend.open(info)
    assert device.read(5.0) is not None
    raised = threading.Event()

    def reader() -> None:
        with pytest.raises(DeviceGone):
            while True:
                device.read(0.1)
        raised.set()

    thread = threading.Thread(target=reader)
    thread.start()
    path.unlink()
    thread.join(10.0)
    assert raised.is_set()
    assert backend.enumerate() == []
    with pytest.raises(DeviceGone):
        backend.open(info)


def test_a_pull_that_only_calls_read_due_sees_the_unplug(tmp_path: Path) -> None:
    """A 1 kHz device always has a report due: read_due makes the gone check itself."""
    path = install_file(tmp_path / "s.hid", recording_text(numbered(1)))
    backend = ReplayBackend(tmp_path, loop=True, speed=1000.0)  # a report always due
    device = backend.open(backend.enumerate()[0])
    assert device.read_due(10)
    path.unlink()
    deadline = time.monotonic() + 10.0
    with pytest.raises(DeviceGone):
        while time.monotonic() < deadline:
            device.read_due(10)


def test_replaced_file_is_a_new_plug(tmp_path: Path) -> None:
    install_file(tmp_path / "s.hid", recording_text(numbered(1)))
    backend = ReplayBackend(tmp_path)
    old = backend.enumerate()[0]
    device = backend.open(old)
    install_file(tmp_path / "s.hid", recording_text(numbered(2)))
    new = backend.enumerate()[0]
    assert new.key != old.key
    with pytest.raises(DeviceGone):
        while True:
            device.read(0.1)


def test_fault_line_raises_eio_after_earlier_events(tmp_path: Path) -> None:
    text = recording_text(numbered(5, step=0.001), fault_at=0.01)
    install_file(tmp_path / "f.hid", text)
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    assert read_all(device, 5) == [i.to_bytes(2, "little") for i in range(5)]
    with pytest.raises(OSError) as caught:
        device.read(5.0)
    assert caught.value.errno == errno.EIO
    assert not isinstance(caught.value, DeviceGone)


def test_bad_event_line_is_found_when_played_then_the_file_is_a_problem(
    tmp_path: Path,
) -> None:
    # The scan reads the header only; the events are parsed as they are played.
    text = recording_text(numbered(3, step=0.001)) + "E: soon 2 00 01\n"
    install_file(tmp_path / "b.hid", text)
    backend = ReplayBackend(tmp_path, loop=True)
    [info] = backend.enumerate()
    device = backend.open(info)
    assert read_all(device, 3) == [i.to_bytes(2, "little") for i in range(3)]
    with pytest.raises(OSError) as caught:
        device.read(5.0)
    assert caught.value.errno == errno.EIO
    assert "b.hid:9: bad timestamp 'soon'" in str(caught.value)
    assert backend.enumerate() == []
    [problem] = backend.problems
    assert "b.hid: not a hid-recorder file" in problem and "b.hid:9" in problem
    with pytest.raises(DeviceOpenError):
        backend.open(info)


def test_a_file_changed_after_its_bad_line_is_a_device_again(tmp_path: Path) -> None:
    install_file(tmp_path / "b.hid", recording_text(numbered(1)) + "E: 0.0 3 00\n")
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    assert read_all(device, 1) == [b"\x00\x00"]
    with pytest.raises(OSError):
        device.read(1.0)
    assert backend.enumerate() == []
    install_file(tmp_path / "b.hid", recording_text(numbered(2)))
    [info] = backend.enumerate()
    assert read_all(backend.open(info), 2) == [b"\x00\x00", b"\x01\x00"]


def test_read_due_hands_over_what_is_due_in_order_and_read_goes_on_from_there(
    tmp_path: Path,
) -> None:
    install_file(tmp_path / "l.hid", recording_text(numbered(5, step=0.001)))
    backend = ReplayBackend(tmp_path, loop=True, speed=1000.0)  # every report due at once
    device = backend.open(backend.enumerate()[0])
    first = device.read_due(1)  # its gone check made first, as read() makes it
    due = device.read_due(7)  # the rest of the lap and the next lap's first two
    assert [*first, *due] == [i.to_bytes(2, "little") for i in (0, 1, 2, 3, 4, 0, 1, 2)]
    assert device.read(5.0) == (3).to_bytes(2, "little")
    device.close()
    assert device.read_due(10) == []


def test_read_due_stops_before_a_fault_and_read_raises_it(tmp_path: Path) -> None:
    text = recording_text(numbered(5, step=0.001), fault_at=0.0025)
    install_file(tmp_path / "f.hid", text)
    backend = ReplayBackend(tmp_path, speed=0.5)  # the fault at 5 ms, reports every 2 ms
    device = backend.open(backend.enumerate()[0])
    got = [device.read(5.0)]
    while len(got) < 3:
        got += device.read_due(10) or [device.read(5.0)]
    assert got == [i.to_bytes(2, "little") for i in range(3)]
    time.sleep(0.012)  # past the fault and the reports after it: none of them comes out
    assert device.read_due(10) == []
    with pytest.raises(OSError) as caught:
        device.read(5.0)
    assert caught.value.errno == errno.EIO
    device.close()


def test_closed_device_read_fails(tmp_path: Path) -> None:
    install_file(tmp_path / "s.hid", recording_text([]))
    backend = ReplayBackend(tmp_path)
    device = backend.open(backend.enumerate()[0])
    device.close()
    with pytest.raises(OSError):
        device.read(0.01)


def test_open_of_broken_file_explains(tmp_path: Path) -> None:
    install_file(tmp_path / "s.hid", recording_text([]))
    backend = ReplayBackend(tmp_path)
    info = backend.enumerate()[0]
    path = tmp_path / "s.hid"
    mtime_ns = path.stat().st_mtime_ns
    path.write_text("garbage\n")  # same inode
    os.utime(path, ns=(mtime_ns + 10**9, mtime_ns + 10**9))
    with pytest.raises((DeviceGone, DeviceOpenError)):
        backend.open(info)


def test_missing_directory_is_a_problem_not_a_crash(tmp_path: Path) -> None:
    backend = ReplayBackend(tmp_path / "nope")
    assert backend.enumerate() == []
    assert backend.problems
