"""Vendor output formats: devices whose outputs their HID descriptor cannot say (the
PlayStation pads' rumble and lightbar live in one vendor-defined output report; the X52
Pro's MFD and LEDs are USB vendor requests). A small database by vid:pid, each entry naming
the public source its format is taken from; `vendor_driver` gives a plugged device its
output driver, `vendor_capabilities` tells `check` what such a device can show.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from usb2rc.feedback.vendor import ds4, dualsense, x52
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.outputs import Capabilities, OutputDriver

KERNEL_PLAYSTATION = "linux drivers/hid/hid-playstation.c (v6.2+), ids in drivers/hid/hid-ids.h"
LIBX52 = "github.com/nirenjan/libx52 docs/specs/vendor_api.md, libx52/commands.h, libx52/control.c"

# What builds a device's driver, given whether it is on Bluetooth.
DriverFactory = Callable[[bool], OutputDriver]


class VendorDevice(NamedTuple):
    vid: int
    pid: int
    name: str
    capabilities: Capabilities
    driver: DriverFactory
    source: str


def _dualshock4(bluetooth: bool) -> OutputDriver:
    return ds4.DualShock4Driver(bluetooth)


def _dualsense(bluetooth: bool) -> OutputDriver:
    return dualsense.DualSenseDriver(bluetooth, vibration_v2=False)


def _dualsense_edge(bluetooth: bool) -> OutputDriver:
    return dualsense.DualSenseDriver(bluetooth, vibration_v2=True)


def _x52_pro(bluetooth: bool) -> OutputDriver:
    return x52.X52ProDriver()


DEVICES = (
    VendorDevice(0x054C, 0x05C4, "DualShock 4", ds4.CAPABILITIES, _dualshock4, KERNEL_PLAYSTATION),
    VendorDevice(
        0x054C, 0x09CC, "DualShock 4 (CUH-ZCT2)", ds4.CAPABILITIES, _dualshock4, KERNEL_PLAYSTATION
    ),
    VendorDevice(
        0x054C,
        0x0BA0,
        "DualShock 4 USB wireless adapter",
        ds4.CAPABILITIES,
        _dualshock4,
        KERNEL_PLAYSTATION,
    ),
    VendorDevice(
        0x054C, 0x0CE6, "DualSense", dualsense.CAPABILITIES, _dualsense, KERNEL_PLAYSTATION
    ),
    VendorDevice(
        0x054C,
        0x0DF2,
        "DualSense Edge",
        dualsense.CAPABILITIES,
        _dualsense_edge,
        KERNEL_PLAYSTATION,
    ),
    VendorDevice(0x06A3, 0x0762, "Saitek X52 Pro", x52.CAPABILITIES, _x52_pro, LIBX52),
)
BY_ID = {(device.vid, device.pid): device for device in DEVICES}


def vendor_device(vid: int, pid: int) -> VendorDevice | None:
    return BY_ID.get((vid, pid))


def vendor_capabilities(vid: int, pid: int) -> Capabilities | None:
    """What a device in the database can show; None: not in it."""
    device = vendor_device(vid, pid)
    return device.capabilities if device is not None else None


def vendor_driver(info: DeviceInfo) -> OutputDriver | None:
    """A new output driver for a plugged device in the database (one per plug: a driver may
    count its reports); None: not in it."""
    device = vendor_device(info.vid, info.pid)
    if device is None:
        return None
    # DeviceInfo.bus ("usb", "bluetooth" or "") is being added beside this; until it is,
    # a device reads as not on Bluetooth.
    bus: str = getattr(info, "bus", "")
    return device.driver(bus == "bluetooth")
