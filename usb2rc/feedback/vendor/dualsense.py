"""The DualSense's and DualSense Edge's outputs: rumble, the RGB lightbar and the five player
LEDs, in the main output report linux drivers/hid/hid-playstation.c builds
(`struct dualsense_output_report_common` inside `_usb` / `_bt`, `dualsense_output_worker`).

USB: report 0x02, 63 bytes. Bluetooth: report 0x31, 78 bytes: a sequence number in the high
nibble of byte 1 (one more each report, mod 16), the tag 0x10 in byte 2, and a CRC32 at the
end (playstation.with_bt_crc). The 47-byte common part puts the motors at 2 (right, weak) and
3 (left, strong), valid_flag2 at 38, the player LEDs at 43 and red, green, blue at 44..46.

Every report sets rumble, lightbar and player LEDs together (valid_flag1 = LIGHTBAR |
PLAYER_INDICATOR). Rumble: the DualSense Edge takes the "v2" compatible vibration
(valid_flag2 bit 2), as the kernel always gives it; the DualSense the original one
(valid_flag0 bit 0), which the kernel notes both pads support: which one the kernel picks for
a DualSense depends on a firmware version read at probe, which a sans-IO driver cannot read.

Indicators: the player LEDs, bit k = player LED k+1 (the kernel's LED_FUNCTION_PLAYER1..5,
named "player-1".."player-5"). The lightbar's setup (the fade-out of the Bluetooth start-up
animation) is left to hid-playstation, which does it at probe.
"""

from __future__ import annotations

from usb2rc.feedback.vendor.playstation import lightbar, motors, with_bt_crc
from usb2rc.hid.outputs import Capabilities, HidReport, OutputState, OutputWrite

USB_REPORT_ID = 0x02  # DS_OUTPUT_REPORT_USB
USB_REPORT_SIZE = 63  # DS_OUTPUT_REPORT_USB_SIZE
BT_REPORT_ID = 0x31  # DS_OUTPUT_REPORT_BT
BT_REPORT_SIZE = 78  # DS_OUTPUT_REPORT_BT_SIZE
BT_TAG = 0x10  # DS_OUTPUT_TAG
COMMON_SIZE = 47

FLAG0_COMPATIBLE_VIBRATION = 0x01
FLAG0_HAPTICS_SELECT = 0x02
FLAG1_LIGHTBAR_CONTROL_ENABLE = 0x04
FLAG1_PLAYER_INDICATOR_CONTROL_ENABLE = 0x10
FLAG2_COMPATIBLE_VIBRATION2 = 0x04

# offsets in the common part
MOTOR_RIGHT, MOTOR_LEFT = 2, 3
VALID_FLAG2 = 38
PLAYER_LEDS = 43
LIGHTBAR_RED = 44

PLAYER_LED_NAMES = tuple(f"player-{n}" for n in range(1, 6))
PLAYER_LED_MASK = (1 << len(PLAYER_LED_NAMES)) - 1

CAPABILITIES = Capabilities(
    indicators=len(PLAYER_LED_NAMES),
    indicator_names=PLAYER_LED_NAMES,
    analog=("rumble_strong", "rumble_weak", "brightness", "red", "green", "blue"),
)


def common_part(state: OutputState, vibration_v2: bool) -> bytes:
    """`struct dualsense_output_report_common` for a state."""
    part = bytearray(COMMON_SIZE)
    if vibration_v2:
        part[0] = FLAG0_HAPTICS_SELECT
        part[VALID_FLAG2] = FLAG2_COMPATIBLE_VIBRATION2
    else:
        part[0] = FLAG0_HAPTICS_SELECT | FLAG0_COMPATIBLE_VIBRATION
    part[1] = FLAG1_LIGHTBAR_CONTROL_ENABLE | FLAG1_PLAYER_INDICATOR_CONTROL_ENABLE
    part[MOTOR_LEFT], part[MOTOR_RIGHT] = motors(state)
    part[PLAYER_LEDS] = state.indicators & PLAYER_LED_MASK
    part[LIGHTBAR_RED : LIGHTBAR_RED + 3] = bytes(lightbar(state))
    return bytes(part)


def usb_report(common: bytes) -> bytes:
    return (bytes([USB_REPORT_ID]) + common).ljust(USB_REPORT_SIZE, b"\0")


def bt_report(common: bytes, sequence: int) -> bytes:
    header = bytes((BT_REPORT_ID, (sequence & 0x0F) << 4, BT_TAG))
    return with_bt_crc((header + common).ljust(BT_REPORT_SIZE - 4, b"\0"))


class DualSenseDriver:
    """A DualSense (vibration_v2=False) or DualSense Edge over USB or Bluetooth. Over
    Bluetooth each report built takes the next sequence number: build only what is sent."""

    def __init__(self, bluetooth: bool, vibration_v2: bool) -> None:
        self.bluetooth = bluetooth
        self.vibration_v2 = vibration_v2
        self.sequence = 0

    @property
    def capabilities(self) -> Capabilities:
        return CAPABILITIES

    def writes(self, state: OutputState, before: OutputState | None) -> tuple[OutputWrite, ...]:
        common = common_part(state, self.vibration_v2)
        if before is not None and common == common_part(before, self.vibration_v2):
            return ()
        if not self.bluetooth:
            return (HidReport(usb_report(common)),)
        report = bt_report(common, self.sequence)
        self.sequence = (self.sequence + 1) % 16
        return (HidReport(report),)
