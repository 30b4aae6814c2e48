"""The vendor device database: the ids its entries answer to (as their public sources define
them), the source each names, and the driver and capabilities `vendor_driver` and
`vendor_capabilities` give a plugged device."""

from __future__ import annotations

import pytest

from usb2rc.feedback.vendor import (
    DEVICES,
    ds4,
    dualsense,
    vendor_capabilities,
    vendor_driver,
    x52,
)
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.outputs import REST, HidReport, UsbControl

# The ids as their sources define them: linux drivers/hid/hid-ids.h (USB_VENDOR_ID_SONY,
# USB_DEVICE_ID_SONY_PS4_CONTROLLER, _2, _DONGLE, USB_DEVICE_ID_SONY_PS5_CONTROLLER, _2) and
# libx52 (the X52 Pro's product id).
DOCUMENTED_IDS = {
    (0x054C, 0x05C4): "hid-playstation",
    (0x054C, 0x09CC): "hid-playstation",
    (0x054C, 0x0BA0): "hid-playstation",
    (0x054C, 0x0CE6): "hid-playstation",
    (0x054C, 0x0DF2): "hid-playstation",
    (0x06A3, 0x0762): "libx52",
}


def test_every_entry_names_its_public_source() -> None:
    assert {(d.vid, d.pid): d.source for d in DEVICES}.keys() == DOCUMENTED_IDS.keys()
    for device in DEVICES:
        assert DOCUMENTED_IDS[device.vid, device.pid] in device.source
        assert ".c" in device.source or ".md" in device.source  # a file, not just a name


def plugged(vid: int, pid: int, bus: str = "usb") -> DeviceInfo:
    return DeviceInfo(key="/dev/hidraw7", path="/dev/hidraw7", vid=vid, pid=pid, bus=bus)


def first_write(vid: int, pid: int, bus: str) -> HidReport | UsbControl:
    driver = vendor_driver(plugged(vid, pid, bus))
    assert driver is not None
    return driver.writes(REST, None)[0]


@pytest.mark.parametrize(
    ("pid", "bus", "report_id"),
    [
        (0x05C4, "usb", ds4.USB_REPORT_ID),
        (0x09CC, "", ds4.USB_REPORT_ID),  # an unknown bus: the USB format
        (0x0BA0, "usb", ds4.USB_REPORT_ID),
        (0x05C4, "bluetooth", ds4.BT_REPORT_ID),
        (0x09CC, "bluetooth", ds4.BT_REPORT_ID),
        (0x0CE6, "usb", dualsense.USB_REPORT_ID),
        (0x0DF2, "usb", dualsense.USB_REPORT_ID),
        (0x0CE6, "bluetooth", dualsense.BT_REPORT_ID),
        (0x0DF2, "bluetooth", dualsense.BT_REPORT_ID),
    ],
)
def test_a_playstation_pad_gets_its_buss_report(pid: int, bus: str, report_id: int) -> None:
    write = first_write(0x054C, pid, bus)
    assert isinstance(write, HidReport)
    assert write.data[0] == report_id


def test_the_dualsense_edge_takes_the_v2_vibration_and_the_dualsense_the_original() -> None:
    edge, plain = first_write(0x054C, 0x0DF2, "usb"), first_write(0x054C, 0x0CE6, "usb")
    assert isinstance(edge, HidReport) and isinstance(plain, HidReport)
    flag2 = 1 + dualsense.VALID_FLAG2
    assert (edge.data[1], edge.data[flag2]) == (0x02, 0x04)
    assert (plain.data[1], plain.data[flag2]) == (0x03, 0x00)


def test_the_x52_pro_gets_vendor_requests_on_any_bus() -> None:
    assert isinstance(first_write(0x06A3, 0x0762, "usb"), UsbControl)


def test_each_plug_gets_a_driver_of_its_own() -> None:
    info = plugged(0x054C, 0x0CE6, "bluetooth")
    first, second = vendor_driver(info), vendor_driver(info)
    assert first is not None and second is not None and first is not second
    sequences = [d.writes(REST, None)[0] for d in (first, second)]
    assert all(isinstance(w, HidReport) and w.data[1] == 0x00 for w in sequences)


def test_capabilities_by_id() -> None:
    assert vendor_capabilities(0x054C, 0x09CC) == ds4.CAPABILITIES
    assert vendor_capabilities(0x054C, 0x0DF2) == dualsense.CAPABILITIES
    assert vendor_capabilities(0x06A3, 0x0762) == x52.CAPABILITIES
    for device in DEVICES:
        driver = vendor_driver(plugged(device.vid, device.pid))
        assert driver is not None
        assert driver.capabilities == vendor_capabilities(device.vid, device.pid)


@pytest.mark.parametrize(
    ("vid", "pid"),
    [(0x06A3, 0x075C), (0x054C, 0x0268), (0x046D, 0xC215), (0x0000, 0x0000)],
    ids=["X52 (not Pro)", "DualShock 3", "Extreme 3D Pro", "nothing"],
)
def test_a_device_not_in_the_database_has_no_vendor_format(vid: int, pid: int) -> None:
    assert vendor_capabilities(vid, pid) is None
    assert vendor_driver(plugged(vid, pid)) is None
