"""The DualShock 4's outputs: its two rumble motors and RGB lightbar, in the one output
report linux drivers/hid/hid-playstation.c builds (`struct dualshock4_output_report_usb`,
`struct dualshock4_output_report_bt`, `dualshock4_output_worker`).

USB (and the wireless adapter, which speaks USB): report 0x05, 32 bytes. Bluetooth: report
0x11, 78 bytes, ending in a CRC32 (playstation.with_bt_crc). Both carry the same 10-byte
common part (`struct dualshock4_output_report_common`): valid_flag0, valid_flag1, reserved,
motor_right, motor_left, red, green, blue, blink_on, blink_off.

Every report sets rumble and lightbar together (valid_flag0 = MOTOR | LED), as the kernel
does for pads that cancel one when sent the other alone; the lightbar's hardware blink is
left alone (the feedback engine blinks indicators itself). The DS4 has no indicators.
"""

from __future__ import annotations

from usb2rc.feedback.vendor.playstation import lightbar, motors, with_bt_crc
from usb2rc.hid.outputs import Capabilities, HidReport, OutputState, OutputWrite

USB_REPORT_ID = 0x05  # DS4_OUTPUT_REPORT_USB
USB_REPORT_SIZE = 32  # DS4_OUTPUT_REPORT_USB_SIZE
BT_REPORT_ID = 0x11  # DS4_OUTPUT_REPORT_BT
BT_REPORT_SIZE = 78  # DS4_OUTPUT_REPORT_BT_SIZE
VALID_FLAG0_MOTOR = 0x01
VALID_FLAG0_LED = 0x02
# Bluetooth hw_control: HID data follows, with a CRC32 (DS4_OUTPUT_HWCTL_HID | _CRC32); its
# low 6 bits are the pad's report interval, given as the kernel's default (4 ms, as on USB)
# so that a write of ours never changes the rate the pad reports at.
BT_HW_CONTROL = 0x80 | 0x40 | 4

CAPABILITIES = Capabilities(
    analog=("rumble_strong", "rumble_weak", "brightness", "red", "green", "blue"),
)


def common_part(state: OutputState) -> bytes:
    """`struct dualshock4_output_report_common` for a state."""
    strong, weak = motors(state)
    red, green, blue = lightbar(state)
    flags = VALID_FLAG0_MOTOR | VALID_FLAG0_LED
    return bytes((flags, 0, 0, weak, strong, red, green, blue, 0, 0))


def usb_report(state: OutputState) -> bytes:
    report = bytes([USB_REPORT_ID]) + common_part(state)
    return report.ljust(USB_REPORT_SIZE, b"\0")


def bt_report(state: OutputState) -> bytes:
    header = bytes((BT_REPORT_ID, BT_HW_CONTROL, 0))  # audio_control: 0, untouched
    body = (header + common_part(state)).ljust(BT_REPORT_SIZE - 4, b"\0")
    return with_bt_crc(body)


class DualShock4Driver:
    """A DualShock 4 over USB (bluetooth=False) or Bluetooth."""

    def __init__(self, bluetooth: bool) -> None:
        self.bluetooth = bluetooth

    @property
    def capabilities(self) -> Capabilities:
        return CAPABILITIES

    def writes(self, state: OutputState, before: OutputState | None) -> tuple[OutputWrite, ...]:
        if before is not None and common_part(state) == common_part(before):
            return ()
        report = bt_report(state) if self.bluetooth else usb_report(state)
        return (HidReport(report),)
