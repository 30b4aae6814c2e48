"""A fake pyusb device for the vendor outputs' tests: `FakeUsbDevice.ctrl_transfer` takes
pyusb's `usb.core.Device.ctrl_transfer` arguments, records each transfer as the backend would
see it, returns what pyusb returns, and raises what pyusb raises.

What it copies from pyusb 1.x (usb/core.py `Device.ctrl_transfer`, usb/backend/libusb1.py
`_check`), held there by tests/test_vendor_pyusb_contract.py against the real `Device`:
- the data: None is no data; an int is that many zero bytes (OUT) or the wLength (IN); a str
  is its UTF-8; any other sequence of small ints is taken as bytes;
- the timeout: None is the device's default (1000 ms);
- an OUT transfer (bmRequestType bit 7 clear) returns the number of bytes written; an IN
  transfer with a wLength returns an `array('B')` of what the device answered (`replies`);
- a failure raises `usb.core.USBError(strerror, libusb error code, errno)`, a timeout
  `usb.core.USBTimeoutError`, as libusb1's backend maps a libusb error code.
"""

from __future__ import annotations

import array
import errno
from collections.abc import Iterable
from typing import NamedTuple

import usb.core
from usb.backend import libusb1

DEFAULT_TIMEOUT_MS = 1000  # usb.core._DEFAULT_TIMEOUT
DIRECTION_IN = 0x80

# libusb error codes and the errno pyusb's libusb1 backend gives each (its _libusb_errno)
LIBUSB_ERROR_IO = -1
LIBUSB_ERROR_NO_DEVICE = -4
LIBUSB_ERROR_TIMEOUT = -7
LIBUSB_ERROR_PIPE = -9
LIBUSB_ERRNOS = {
    LIBUSB_ERROR_IO: errno.EIO,
    LIBUSB_ERROR_NO_DEVICE: errno.ENODEV,
    LIBUSB_ERROR_TIMEOUT: errno.ETIMEDOUT,
    LIBUSB_ERROR_PIPE: errno.EPIPE,
}


class ControlTransfer(NamedTuple):
    """One control transfer as it reaches the backend: an OUT transfer's data, and the
    buffer's length (an OUT transfer's data length, an IN transfer's wLength)."""

    request_type: int
    request: int
    w_value: int
    w_index: int
    data: bytes
    length: int
    timeout: int


def usb_error(code: int) -> usb.core.USBError:
    """The exception pyusb's libusb1 backend raises for a libusb error code. Its text is
    pyusb's own (`libusb1._strerror`, as its `_check` words it): libusb's
    `libusb_strerror` once a test in this process has loaded the library ("Input/Output
    Error"), pyusb's table before ("Input/output error"), so the text depends on which
    tests ran first in the process, for the real backend and the fake alike."""
    kind = usb.core.USBTimeoutError if code == LIBUSB_ERROR_TIMEOUT else usb.core.USBError
    return kind(libusb1._strerror(code), code, LIBUSB_ERRNOS[code])


def as_buffer(data_or_length: object) -> array.array[int]:
    """pyusb's conversion of `data_or_wLength` to the transfer's byte buffer."""
    if data_or_length is None:
        return array.array("B")
    if isinstance(data_or_length, str):
        return array.array("B", data_or_length.encode("utf-8"))
    if isinstance(data_or_length, int):
        return array.array("B", bytes(data_or_length))
    if isinstance(data_or_length, Iterable):
        return array.array("B", data_or_length)
    raise TypeError(f"cannot make a transfer buffer of {data_or_length!r}")


class FakeUsbDevice:
    """A USB device that answers control transfers and remembers them. `fail_next(code)`
    makes the next transfer fail with that libusb error code; `unplug()` makes every later
    transfer fail as a vanished device does."""

    def __init__(self, vid: int, pid: int) -> None:
        self.idVendor = vid
        self.idProduct = pid
        self.default_timeout = DEFAULT_TIMEOUT_MS
        self.transfers: list[ControlTransfer] = []
        self.replies: dict[tuple[int, int, int, int], bytes] = {}
        self.failures: list[int] = []
        self.unplugged = False

    def fail_next(self, code: int) -> None:
        self.failures.append(code)

    def unplug(self) -> None:
        self.unplugged = True

    def ctrl_transfer(
        self,
        bmRequestType: int,
        bRequest: int,
        wValue: int = 0,
        wIndex: int = 0,
        data_or_wLength: object = None,
        timeout: int | None = None,
    ) -> int | array.array[int]:
        buffer = as_buffer(data_or_wLength)
        used_timeout = self.default_timeout if timeout is None else timeout
        into_caller_array = isinstance(data_or_wLength, array.array)
        incoming = bool(bmRequestType & DIRECTION_IN)
        sent = b"" if incoming else buffer.tobytes()
        self.transfers.append(
            ControlTransfer(
                bmRequestType, bRequest, wValue, wIndex, sent, len(buffer), used_timeout
            )
        )
        if self.unplugged:
            raise usb_error(LIBUSB_ERROR_NO_DEVICE)
        if self.failures:
            raise usb_error(self.failures.pop(0))
        if not incoming:
            return len(buffer)
        reply = self.replies.get((bmRequestType, bRequest, wValue, wIndex), b"")[: len(buffer)]
        buffer[: len(reply)] = array.array("B", reply)
        if into_caller_array:
            return len(reply)
        return buffer[: len(reply)]
