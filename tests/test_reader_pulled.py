"""A pulled DeviceReader (usb2rc.hid.reader): the node step drains the device, the thread
only holds it. Every report in order, one on_exit from the thread for a failure a pull met,
and never a pull after the close."""

from __future__ import annotations

import threading
from collections import deque

from output_fakes import RecordingPort
from test_reader import Exits, RecordingDecoder

from usb2rc.hid.backend import DeviceGone, DeviceInfo, ErrorCode
from usb2rc.hid.reader import DeviceReader

WAIT_S = 10.0
INFO = DeviceInfo(key="k", path="/dev/hidraw9", vid=1, pid=2, product="fake")


class QueueDevice:
    """A device whose reports the test queues; `read(0)` polls as hidapi's non-blocking
    read does (None when empty); `fail` makes the next read raise."""

    def __init__(self) -> None:
        self.info = INFO
        self.queued: deque[bytes] = deque()
        self.fail: BaseException | None = None
        self.closed = threading.Event()
        self.reads_after_close = 0

    def read(self, timeout_s: float) -> bytes | None:
        if self.closed.is_set():
            self.reads_after_close += 1
        if self.fail is not None:
            raise self.fail
        return self.queued.popleft() if self.queued else None

    def report_descriptor(self) -> bytes:
        return b""

    def open_output(self) -> RecordingPort:
        return RecordingPort()

    def close(self) -> None:
        self.closed.set()


def pulled_reader() -> tuple[DeviceReader, QueueDevice, RecordingDecoder, Exits]:
    device, decoder, exits = QueueDevice(), RecordingDecoder(), Exits()
    reader = DeviceReader(device, decoder, exits, pulled=True)
    reader.start()
    return reader, device, decoder, exits


def test_a_pull_decodes_every_queued_report_in_order_and_publishes_once() -> None:
    reader, device, decoder, exits = pulled_reader()
    try:
        assert reader.record.reports == 0
        device.queued.extend([b"a", b"b", b"c"])
        reader.pull()
        assert decoder.reports == [b"a", b"b", b"c"]
        assert reader.record.reports == 3
        before = reader.record
        reader.pull()  # nothing queued: nothing published
        assert reader.record is before
    finally:
        reader.stop()
        reader.join(WAIT_S)
    assert device.closed.is_set() and exits.calls == []  # stop: no on_exit


def test_a_failure_a_pull_meets_ends_the_thread_with_one_on_exit() -> None:
    reader, device, _decoder, exits = pulled_reader()
    device.fail = OSError(5, "read failed")
    reader.pull()
    assert exits.event.wait(WAIT_S)
    reader.join(WAIT_S)
    assert exits.calls == [ErrorCode.READ_FAILED]
    assert device.closed.is_set()
    reader.pull()  # after the close: no read
    assert device.reads_after_close == 0


def test_an_unplug_a_pull_meets_is_an_unplug() -> None:
    reader, device, _decoder, exits = pulled_reader()
    device.fail = DeviceGone("unplugged")
    reader.pull()
    reader.pull()  # a second pull after the failure reads nothing more
    assert exits.event.wait(WAIT_S)
    reader.join(WAIT_S)
    assert exits.calls == [None]
