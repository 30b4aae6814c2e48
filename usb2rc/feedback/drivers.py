"""Which output driver a device gets: its vendor format when the device database knows it
(what the descriptor cannot say: a pad's rumble, an MFD), else what its own report
descriptor declares (`hid_outputs.HidOutputDriver`), else none."""

from __future__ import annotations

from usb2rc.feedback.hid_outputs import HidOutputDriver
from usb2rc.feedback.vendor import vendor_capabilities, vendor_driver
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.outputs import Capabilities, OutputDriver


def output_driver(info: DeviceInfo, descriptor: bytes) -> OutputDriver | None:
    """The driver for a plugged device; None: it has no output usb2rc can drive."""
    vendor = vendor_driver(info)
    if vendor is not None:
        return vendor
    return HidOutputDriver.from_descriptor(descriptor)


def known_capabilities(vid: int, pid: int) -> Capabilities | None:
    """What a device can show, known before it is plugged (`check`): the vendor database's
    entries only; a device driven by its descriptor is known once plugged."""
    return vendor_capabilities(vid, pid)
