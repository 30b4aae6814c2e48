"""Output writes by a pulled DeviceReader (usb2rc.hid.reader.post_output): the newest state
wins, at most OUTPUT_RATE_HZ a second (a burst of OUTPUT_BURST), never under the pull's
lock, a refusal logged once and counted while the input goes on; and the backends' output
ports (hidapi's second handle, replay's counting port) and DeviceInfo.bus."""

from __future__ import annotations

import errno
import logging
import math
import threading
import time
from collections import deque
from pathlib import Path

import pytest
from output_fakes import WAIT_S, RecordingPort
from test_hidapi_backend import T16000M, FakeHid, entry, make_sysfs
from test_reader import Exits, RecordingDecoder
from test_replay import recording_text
from umockdev_harness import LED_STICK_DESCRIPTOR, wait_until

from usb2rc.feedback.hid_outputs import HidOutputDriver
from usb2rc.hid.backend import DeviceGone, DeviceInfo
from usb2rc.hid.hidapi_backend import HidapiBackend
from usb2rc.hid.outputs import HidReport, OutputState, UsbControl
from usb2rc.hid.reader import OUTPUT_BURST, OUTPUT_RATE_HZ, DeviceReader
from usb2rc.hid.replay import ReplayBackend, install_file
from usb2rc.runtime.token_bucket import TokenBucket

INFO = DeviceInfo(key="k", path="/dev/hidraw7", vid=1, pid=2, product="LED stick")


def led_driver() -> HidOutputDriver:
    driver = HidOutputDriver.from_descriptor(LED_STICK_DESCRIPTOR)
    assert driver is not None
    return driver


def lit(mask: int) -> bytes:
    """The LED stick's report 2 with the indicators `mask` lit (LEDs bits 0-4, the ordinals
    and the vendor bit 16-18 of its 3 data bytes), brightness unset: full (0xFF, bits 8-15)."""
    bits = (mask & 0x1F) | 0xFF << 8 | (mask >> 5 & 0x07) << 16
    return b"\x02" + bits.to_bytes(3, "little")


class PortDevice:
    """A device whose reports the test queues (polls as a non-blocking hidapi handle does)
    and whose output port is a RecordingPort; `open_error` makes open_output() raise."""

    def __init__(self) -> None:
        self.info = INFO
        self.queued: deque[bytes] = deque()
        self.port = RecordingPort()
        self.opens = 0
        self.open_error: OSError | None = None
        self.closed_at: float | None = None

    def report_descriptor(self) -> bytes:
        return LED_STICK_DESCRIPTOR

    def read(self, timeout_s: float) -> bytes | None:
        return self.queued.popleft() if self.queued else None

    def open_output(self) -> RecordingPort:
        self.opens += 1
        if self.open_error is not None:
            raise self.open_error
        self.port.closed = False
        return self.port

    def close(self) -> None:
        self.closed_at = time.monotonic()


@pytest.fixture
def pulled() -> tuple[DeviceReader, PortDevice, RecordingDecoder]:
    device, decoder = PortDevice(), RecordingDecoder()
    reader = DeviceReader(device, decoder, Exits(), pulled=True)
    reader.start()
    try:
        yield reader, device, decoder
    finally:
        reader.stop()
        reader.join(WAIT_S)


def test_a_post_is_written_and_shown(pulled) -> None:
    reader, device, _ = pulled
    driver = led_driver()
    state = OutputState(indicators=0b101)
    reader.post_output(driver, state)
    wait_until(lambda: reader.outputs.shown == state, WAIT_S, "the state shown")
    assert device.port.written() == [HidReport(lit(0b101))]
    assert (reader.outputs_written, reader.outputs_refused) == (1, 0)
    reader.post_output(driver, state)  # the same again: nothing to write
    reader.post_output(driver, OutputState(indicators=0b100))
    wait_until(lambda: reader.outputs.shown == OutputState(indicators=0b100), WAIT_S, "the second")
    assert device.port.written()[1:] == [HidReport(lit(0b100))]
    assert device.opens == 1  # one port, opened when first needed


def test_a_burst_of_posts_is_rate_limited_and_ends_on_the_newest(pulled) -> None:
    reader, device, _ = pulled
    driver = led_driver()
    started = time.monotonic()
    for i in range(100):
        reader.post_output(driver, OutputState(indicators=i + 1))
    newest = OutputState(indicators=100)
    wait_until(lambda: reader.outputs.shown == newest, WAIT_S, "the newest state shown")
    elapsed = time.monotonic() - started
    times = [t for t, _ in device.port.writes]
    assert device.port.written()[-1] == HidReport(lit(100))
    assert len(times) <= OUTPUT_BURST + math.ceil(elapsed * OUTPUT_RATE_HZ) + 1
    assert len(times) < 100
    # no window of one second holds more than the burst and a second's tokens
    for i, t in enumerate(times):
        assert sum(1 for u in times[i:] if u - t < 1.0) <= OUTPUT_BURST + OUTPUT_RATE_HZ


def test_the_token_bucket() -> None:
    bucket = TokenBucket(OUTPUT_RATE_HZ, OUTPUT_BURST, now=100.0)
    for _ in range(OUTPUT_BURST):  # after a quiet spell: at once
        assert bucket.wait_s(100.0) == 0.0
        bucket.take(100.0)
    assert bucket.wait_s(100.0) == pytest.approx(1 / OUTPUT_RATE_HZ)
    assert bucket.wait_s(100.0 + 1 / OUTPUT_RATE_HZ) == 0.0
    bucket.take(100.0 + 1 / OUTPUT_RATE_HZ)
    assert bucket.wait_s(200.0) == 0.0  # refilled, but never beyond the burst
    for _ in range(OUTPUT_BURST):
        bucket.take(200.0)
    assert bucket.wait_s(200.0) > 0


def test_a_refused_write_is_counted_logged_once_and_the_input_goes_on(pulled, caplog) -> None:
    reader, device, decoder = pulled
    caplog.set_level(logging.WARNING, logger="usb2rc.hid.reader")
    device.port.fail = OSError(errno.EIO, "/dev/hidraw7: output report 2 refused: EPIPE")
    driver = led_driver()
    reader.post_output(driver, OutputState(indicators=1))
    wait_until(lambda: reader.outputs_refused >= 1, WAIT_S, "a refusal")
    reader.post_output(driver, OutputState(indicators=2))
    wait_until(lambda: reader.outputs_refused >= 2, WAIT_S, "a second refusal")
    assert reader.outputs.last_error == "/dev/hidraw7: output report 2 refused: EPIPE"
    refusals = [r for r in caplog.records if "output refused" in r.getMessage()]
    assert len(refusals) == 1 and "EPIPE" in refusals[0].getMessage()
    device.queued.extend([b"a", b"b"])  # the input is unaffected
    reader.pull()
    assert decoder.reports == [b"a", b"b"] and reader.is_alive()
    device.port.fail = None  # the device takes writes again: the newest state goes
    wait_until(lambda: reader.outputs.shown == OutputState(indicators=2), WAIT_S, "the retry")
    assert device.port.written() == [HidReport(lit(2))]


def test_a_port_that_cannot_be_opened_is_a_refusal(pulled, caplog) -> None:
    reader, device, decoder = pulled
    device.open_error = PermissionError(errno.EACCES, "permission denied on /dev/hidraw7")
    reader.post_output(led_driver(), OutputState(indicators=1))
    wait_until(lambda: reader.outputs_refused == 1, WAIT_S, "a refusal")
    assert "permission denied" in reader.outputs.last_error
    assert sum("output refused" in r.getMessage() for r in caplog.records) == 1
    device.queued.append(b"x")
    reader.pull()
    assert decoder.reports == [b"x"]


def test_a_slow_write_never_delays_a_pull(pulled) -> None:
    reader, device, decoder = pulled
    device.port.hold = threading.Event()
    try:
        reader.post_output(led_driver(), OutputState(indicators=1))
        assert device.port.in_write.wait(WAIT_S)  # the reader thread is inside the write
        device.queued.append(b"during")
        pulling = threading.Thread(target=reader.pull)
        pulling.start()
        pulling.join(WAIT_S / 2)
        assert not pulling.is_alive() and decoder.reports == [b"during"]
    finally:
        device.port.hold.set()
    wait_until(lambda: reader.outputs_written == 1, WAIT_S, "the held write")


def test_stop_writes_the_newest_state_then_closes_the_port_before_the_device() -> None:
    device = PortDevice()
    reader = DeviceReader(device, RecordingDecoder(), Exits(), pulled=True)
    reader.start()
    driver = led_driver()
    try:
        for i in range(OUTPUT_BURST + 3):  # more than the burst: the last ones wait
            reader.post_output(driver, OutputState(indicators=i + 1))
    finally:
        reader.stop()
        reader.join(WAIT_S)
    assert device.port.written()[-1] == HidReport(lit(OUTPUT_BURST + 3))
    assert device.port.closed_at is not None and device.closed_at is not None
    assert device.port.closed_at <= device.closed_at


def test_a_reader_that_is_not_pulled_ignores_posts() -> None:
    device = PortDevice()
    reader = DeviceReader(device, RecordingDecoder(), Exits(), read_timeout_s=0.01)
    reader.start()
    try:
        reader.post_output(led_driver(), OutputState(indicators=1))
    finally:
        reader.stop()
        reader.join(WAIT_S)
    assert device.opens == 0 and reader.outputs_written == 0


# --- the backends' ports ---------------------------------------------------------------------


def hidapi_device(tmp_path: Path, bus_type: int = 1) -> tuple[FakeHid, HidapiBackend]:
    if not (tmp_path / "class").exists():
        make_sysfs(tmp_path, "hidraw0", "1-1", T16000M)
    hid = FakeHid([{**entry("/dev/hidraw0", 0x044F, 0xB10A, 1, 4), "bus_type": bus_type}])
    backend = HidapiBackend(hid, sysfs_root=tmp_path, linux=True)
    return hid, backend


def test_hidapi_writes_go_through_a_second_handle(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("os.path.exists", lambda p: True)
    hid, backend = hidapi_device(tmp_path)
    (info,) = backend.enumerate()
    device = backend.open(info)
    port = device.open_output()
    assert len(hid.opened) == 2 and hid.opened[0] is not hid.opened[1]
    port.write(HidReport(b"\x00\x05"))
    assert bytes(hid.written["/dev/hidraw0"]) == b"\x00\x05"
    hid.refuse_writes.add("/dev/hidraw0")
    with pytest.raises(OSError, match="output report 0 refused by the device: Input/output"):
        port.write(HidReport(b"\x00\x06"))
    hid.unplug("/dev/hidraw0")
    monkeypatch.setattr("os.path.exists", lambda p: False)
    with pytest.raises(DeviceGone):
        port.write(HidReport(b"\x00\x07"))
    port.close()
    assert hid.opened[1].closed and not hid.opened[0].closed
    device.close()


class UsbStub:
    """What pyusb's find() gives for one device: bus, port numbers, ctrl_transfer."""

    def __init__(self, bus: int, ports: tuple[int, ...], fail: Exception | None = None) -> None:
        self.bus, self.port_numbers, self.fail = bus, ports, fail
        self.transfers: list[tuple[int, int, int, int, bytes]] = []

    def ctrl_transfer(self, rt: int, req: int, value: int, index: int, data: bytes) -> int:
        if self.fail is not None:
            raise self.fail
        self.transfers.append((rt, req, value, index, data))
        return len(data)


def test_usb_control_transfers_go_to_the_device_at_its_port(tmp_path: Path, monkeypatch) -> None:
    import usb.core

    other, mine = UsbStub(1, (2,)), UsbStub(1, (1,))
    monkeypatch.setattr(usb.core, "find", lambda **kw: [other, mine])
    monkeypatch.setattr("os.path.exists", lambda p: True)
    _, backend = hidapi_device(tmp_path)
    device = backend.open(backend.enumerate()[0])
    port = device.open_output()
    port.write(UsbControl(0x40, 0x91, 0x0001, 0x00D1))
    assert mine.transfers == [(0x40, 0x91, 0x0001, 0x00D1, b"")] and other.transfers == []
    mine.fail = usb.core.USBError("Access denied", errno=errno.EACCES)
    with pytest.raises(PermissionError, match="udev rule"):
        port.write(UsbControl(0x40, 0x91, 0x0002, 0x00D1))
    port.close()
    device.close()


def test_the_bus_from_hidapi_or_sysfs(tmp_path: Path) -> None:
    _, backend = hidapi_device(tmp_path, bus_type=2)
    assert backend.enumerate()[0].bus == "bluetooth"
    uevent = tmp_path / "class" / "hidraw" / "hidraw0" / "device" / "uevent"
    for bus_type, hid_id, bus in ((1, "0005", "usb"), (0, "0005", "bluetooth"), (0, "0003", "usb")):
        uevent.write_text(f"DRIVER=hid-generic\nHID_ID={hid_id}:0000054C:000005C4\n")
        _, backend = hidapi_device(tmp_path, bus_type=bus_type)
        assert backend.enumerate()[0].bus == bus
    uevent.unlink()
    _, backend = hidapi_device(tmp_path, bus_type=0)
    assert backend.enumerate()[0].bus == ""


def test_replay_port_counts_and_keeps_the_last_writes(tmp_path: Path) -> None:
    text = recording_text([]).replace("I: 3 ", "I: 5 ", 1)
    install_file(tmp_path / "pad.hid", text)
    backend = ReplayBackend(tmp_path)
    (info,) = backend.enumerate()
    assert info.bus == "bluetooth"
    device = backend.open(info)
    port = device.open_output()
    for i in range(40):
        port.write(HidReport(bytes([0, i])))
    assert port.written == 40 and len(port.last) == 16 and port.last[-1] == HidReport(b"\x00\x27")
    port.close()
    with pytest.raises(OSError, match="closed"):
        port.write(HidReport(b"\x00"))
    device.close()
