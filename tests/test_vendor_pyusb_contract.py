"""tests/pyusb_fake.py held to pyusb: the same control transfers, made through the real
`usb.core.Device` on a backend that records what reaches it (and fails as pyusb's libusb1
backend does, through its own `_check`), and through `FakeUsbDevice`, record the same
(bmRequestType, bRequest, wValue, wIndex, data, length, timeout), return the same, and raise
the same."""

from __future__ import annotations

import array
from collections.abc import Callable
from functools import partial
from types import SimpleNamespace
from typing import Any

import pytest
import usb.backend
import usb.core
from pyusb_fake import (
    LIBUSB_ERROR_IO,
    LIBUSB_ERROR_NO_DEVICE,
    LIBUSB_ERROR_PIPE,
    LIBUSB_ERROR_TIMEOUT,
    ControlTransfer,
    FakeUsbDevice,
)
from usb.backend import libusb1

from usb2rc.feedback.vendor import x52
from usb2rc.hid.outputs import REST, OutputState, UsbControl

X52_PRO = (0x06A3, 0x0762)
DIRECTION_IN = 0x80


class RecordingBackend(usb.backend.IBackend):  # type: ignore[misc]
    """One device whose control transfers are recorded as they reach a pyusb backend, and
    answered as libusb answers: the bytes transferred, or an error code that libusb1's
    `_check` turns into pyusb's exception."""

    def __init__(self, vid: int, pid: int) -> None:
        self.vid, self.pid = vid, pid
        self.transfers: list[ControlTransfer] = []
        self.replies: dict[tuple[int, int, int, int], bytes] = {}
        self.failures: list[int] = []
        self.unplugged = False

    def enumerate_devices(self) -> list[str]:
        return ["the device"]

    def get_device_descriptor(self, dev: object) -> SimpleNamespace:
        return SimpleNamespace(
            bLength=18,
            bDescriptorType=1,
            bcdUSB=0x0200,
            bDeviceClass=0,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=8,
            idVendor=self.vid,
            idProduct=self.pid,
            bcdDevice=0x0100,
            iManufacturer=1,
            iProduct=2,
            iSerialNumber=0,
            bNumConfigurations=1,
            address=5,
            bus=1,
            port_number=2,
            port_numbers=(2,),
            speed=None,
        )

    def open_device(self, dev: object) -> str:
        return "the handle"

    def close_device(self, dev_handle: object) -> None:
        pass

    def ctrl_transfer(
        self,
        dev_handle: object,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: array.array[int],
        timeout: int,
    ) -> int:
        incoming = bool(bmRequestType & DIRECTION_IN)
        sent = b"" if incoming else data.tobytes()
        self.transfers.append(
            ControlTransfer(bmRequestType, bRequest, wValue, wIndex, sent, len(data), timeout)
        )
        if self.unplugged:
            return int(libusb1._check(LIBUSB_ERROR_NO_DEVICE))
        if self.failures:
            return int(libusb1._check(self.failures.pop(0)))
        if not incoming:
            return int(libusb1._check(len(data)))
        reply = self.replies.get((bmRequestType, bRequest, wValue, wIndex), b"")[: len(data)]
        data[: len(reply)] = array.array("B", reply)
        return int(libusb1._check(len(reply)))


def both() -> tuple[tuple[Any, RecordingBackend], tuple[FakeUsbDevice, FakeUsbDevice]]:
    backend = RecordingBackend(*X52_PRO)
    real = usb.core.Device("the device", backend)
    fake = FakeUsbDevice(*X52_PRO)
    return (real, backend), (fake, fake)


def x52_writes() -> list[UsbControl]:
    driver = x52.X52ProDriver()
    lit = OutputState(
        indicators=0b1_0110_0011, analog=(("brightness", 0.25),), texts=("LQ 87%", "", "ARMED")
    )
    writes = [*driver.writes(REST, None), *driver.writes(lit, REST), *driver.writes(REST, lit)]
    return [w for w in writes if isinstance(w, UsbControl)]


def send(device: Any, write: UsbControl) -> object:
    """As a reader thread makes a vendor write."""
    return device.ctrl_transfer(
        write.request_type, write.request, write.w_value, write.w_index, write.data
    )


def test_the_x52_writes_reach_the_backend_the_same_through_pyusb_and_the_fake() -> None:
    (real, backend), (fake, record) = both()
    writes = x52_writes()
    assert len(writes) > 30
    assert [send(real, w) for w in writes] == [send(fake, w) for w in writes] == [0] * len(writes)
    assert backend.transfers == record.transfers
    assert [
        (t.request_type, t.request, t.w_value, t.w_index, t.data) for t in record.transfers
    ] == [tuple(w) for w in writes]


# Other ways to call ctrl_transfer: (args, kwargs)
CALLS: list[tuple[tuple[Any, ...], dict[str, Any]]] = [
    ((0x40, 0x91), {}),  # wValue, wIndex and the data default
    ((0x40, 0x91, 0x1234, 0xB8), {"timeout": 5000}),  # libx52's timeout
    ((0x40, 0x91, 1, 2, b"\x01\x02\x03"), {}),
    ((0x40, 0x91, 1, 2, [4, 5]), {}),
    ((0x40, 0x91, 1, 2, "hé"), {}),  # a str: its UTF-8
    ((0x40, 0x91, 1, 2, 3), {}),  # an int on OUT: that many zero bytes
    ((0x40, 0x91, 1, 2, array.array("B", [9, 8])), {}),
    ((0x40, 0x91), {"wValue": 7, "wIndex": 8, "data_or_wLength": None, "timeout": 0}),
    ((0xC0, 0x01, 0, 0, 8), {}),  # IN, a full answer: pyusb gives the array
    ((0xC0, 0x02, 0, 0, 8), {}),  # IN, a short answer: pyusb gives its first bytes
    ((0xC0, 0x03, 0, 0, 8), {}),  # IN, nothing: an empty array
    ((0xC0, 0x02, 0, 0, array.array("B", bytes(8))), {}),  # IN into the caller's array
]
REPLIES = {(0xC0, 0x01, 0, 0): bytes(range(8)), (0xC0, 0x02, 0, 0): b"\xaa\xbb"}


def test_other_calls_record_and_return_the_same() -> None:
    (real, backend), (fake, record) = both()
    backend.replies = fake.replies = dict(REPLIES)
    for args, kwargs in CALLS:
        from_real = real.ctrl_transfer(*args, **kwargs)
        from_fake = fake.ctrl_transfer(*args, **kwargs)
        assert type(from_fake) is type(from_real)
        assert from_fake == from_real, (args, kwargs)
    assert backend.transfers == record.transfers


def raised(call: Callable[[], object]) -> tuple[type[BaseException], int | None, int, str]:
    with pytest.raises(usb.core.USBError) as caught:
        call()
    error = caught.value
    return type(error), error.errno, error.backend_error_code, error.strerror


@pytest.mark.parametrize("libusb_loaded", [False, True])
@pytest.mark.parametrize(
    "code", [LIBUSB_ERROR_PIPE, LIBUSB_ERROR_TIMEOUT, LIBUSB_ERROR_NO_DEVICE, LIBUSB_ERROR_IO]
)
def test_a_failed_transfer_raises_the_same(code: int, libusb_loaded: bool) -> None:
    """Whether or not a test before this one in the process loaded libusb (pyusb then
    words its errors with libusb's own `libusb_strerror`; where libusb is not installed
    nothing loads, and both sides use pyusb's table)."""
    if libusb_loaded:
        libusb1.get_backend()
    (real, backend), (fake, record) = both()
    write = x52_writes()[0]
    backend.failures.append(code)
    fake.fail_next(code)
    from_real = raised(lambda: send(real, write))
    assert raised(lambda: send(fake, write)) == from_real
    assert issubclass(from_real[0], usb.core.USBTimeoutError) == (code == LIBUSB_ERROR_TIMEOUT)
    assert send(real, write) == send(fake, write) == 0  # the next one goes through
    assert backend.transfers == record.transfers


def test_an_unplugged_device_refuses_every_transfer_the_same() -> None:
    (real, backend), (fake, record) = both()
    backend.unplugged = True
    fake.unplug()
    for write in x52_writes()[:3]:
        assert raised(partial(send, fake, write)) == raised(partial(send, real, write))
    assert backend.transfers == record.transfers
