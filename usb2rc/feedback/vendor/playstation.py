"""What the PlayStation pads' output reports share (linux drivers/hid/hid-playstation.c):
an analog output as the byte the pad takes, the rumble motors and lightbar colour of a state,
and the CRC32 a Bluetooth report ends with.

- Rumble: `rumble_strong` drives the left (heavy, low-frequency) motor, `rumble_weak` the
  right (light) one, as hid-playstation maps a force-feedback effect's strong and weak
  magnitudes onto `motor_left` and `motor_right`.
- Lightbar: `red`, `green`, `blue` (0..1 -> 0..255), scaled by `brightness` when the state has
  one; a state without `brightness` shows the colour as given (brightness 1). A state with
  `brightness` 0 therefore turns the lightbar off whatever its colour.
- Bluetooth: a report's last 4 bytes are the CRC-32 (zlib's) of the seed byte 0xA2
  (PS_OUTPUT_CRC32_SEED) followed by the report without those 4 bytes, little-endian.
"""

from __future__ import annotations

import math
import zlib

from usb2rc.hid.outputs import OutputState

OUTPUT_CRC32_SEED = 0xA2  # hid-playstation.c PS_OUTPUT_CRC32_SEED
CRC_SIZE = 4


def unit_byte(value: float) -> int:
    """0.0..1.0 -> 0..255, rounded; out of range clamps, NaN reads as rest (0)."""
    if math.isnan(value):
        return 0
    return round(min(max(value, 0.0), 1.0) * 255)


def motors(state: OutputState) -> tuple[int, int]:
    """(left/strong, right/weak) motor bytes."""
    return unit_byte(state.value("rumble_strong")), unit_byte(state.value("rumble_weak"))


def lightbar(state: OutputState) -> tuple[int, int, int]:
    """(red, green, blue) bytes, the colour scaled by the state's brightness if it has one."""
    analog = dict(state.analog)
    scale = analog.get("brightness", 1.0)
    scale = 0.0 if math.isnan(scale) else min(max(scale, 0.0), 1.0)
    return (
        unit_byte(state.value("red") * scale),
        unit_byte(state.value("green") * scale),
        unit_byte(state.value("blue") * scale),
    )


def with_bt_crc(report_without_crc: bytes) -> bytes:
    """The report followed by the CRC32 the pad checks on a Bluetooth output report."""
    crc = zlib.crc32(bytes([OUTPUT_CRC32_SEED]) + report_without_crc)
    return report_without_crc + crc.to_bytes(CRC_SIZE, "little")
