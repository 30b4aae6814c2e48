"""The Saitek/Logitech X52 Pro's outputs: the MFD's three 16-character lines, its shift
indicator, the button LEDs, and the MFD and LED brightness, each set by a USB vendor control
request as libx52 (github.com/nirenjan/libx52) documents them: docs/specs/vendor_api.md, the
constants in libx52/commands.h, the order of libx52_update in libx52/control.c.

Every request is the same: bmRequestType 0x40 (vendor, device, host to device), bRequest
0x91, the function in wIndex, its argument in wValue, no data.

- Indicators, in libx52's update-bit order (libx52/common.h X52_BIT_*): 0 "shift" (the MFD's
  shift indicator, wIndex 0xfd, wValue 0x51 on / 0x50 off), then the 20 LEDs 1..20 (wIndex
  0xb8, wValue LED number << 8 | on). A two-colour LED is two indicators, its red and its green
  (both on: amber). Names follow libx52's x52cli words ("fire", "a red", "pov green", ...).
- Text: a changed line is cleared (wIndex 0xd9 / 0xda / 0xdc) and its characters then written
  two per request (wIndex 0xd1 / 0xd2 / 0xd4, wValue second << 8 | first; an odd last
  character goes with a space), as libx52's _x52_write_line does. Characters are the MFD's
  own code page: printable ASCII is itself but for "\\" and "~", which the MFD lacks; those
  and every other character show as the MFD's box glyph 0xdb, as libx52util's map does.
  A line longer than 16 characters is cut.
- Brightness: `brightness` 0..1 -> 0..128 (0x80, vendor_api.md's maximum) for both the MFD
  (wIndex 0xb1) and the LEDs (0xb2). A state without `brightness` shows full brightness: a
  display at rest stays readable.

`writes(state, before)` sends only what differs from `before`, in libx52_update's order
(shift, LEDs, lines, MFD brightness, LED brightness); `before=None` sends everything.
"""

from __future__ import annotations

import math

from usb2rc.hid.outputs import Capabilities, OutputState, OutputWrite, UsbControl

REQUEST_TYPE = 0x40  # LIBUSB_REQUEST_TYPE_VENDOR | LIBUSB_RECIPIENT_DEVICE | ENDPOINT_OUT
VENDOR_REQUEST = 0x91  # X52_VENDOR_REQUEST

SHIFT_INDICATOR = 0xFD
SHIFT_ON, SHIFT_OFF = 0x51, 0x50
LED = 0xB8
MFD_LINES = (0xD1, 0xD2, 0xD4)  # X52_MFD_LINE1..3: append two characters
MFD_CLEAR_LINE = 0x08  # or'd onto a line's index: clear it
MFD_BRIGHTNESS = 0xB1
LED_BRIGHTNESS = 0xB2
BRIGHTNESS_MAX = 0x80

LINE_WIDTH = 16
BOX_GLYPH = 0xDB  # what libx52util shows for a character the MFD lacks
MISSING_ASCII = frozenset("\\~")

# Indicator k is libx52's update bit k: 0 the shift indicator, 1..20 the LED of that number.
INDICATOR_NAMES = (
    "shift",
    "fire",
    "a red",
    "a green",
    "b red",
    "b green",
    "d red",
    "d green",
    "e red",
    "e green",
    "t1 red",
    "t1 green",
    "t2 red",
    "t2 green",
    "t3 red",
    "t3 green",
    "pov red",
    "pov green",
    "clutch red",
    "clutch green",
    "throttle",
)
SHIFT_BIT = 0
LED_BITS = range(1, len(INDICATOR_NAMES))

CAPABILITIES = Capabilities(
    indicators=len(INDICATOR_NAMES),
    indicator_names=INDICATOR_NAMES,
    analog=("brightness",),
    text_lines=len(MFD_LINES),
    text_width=LINE_WIDTH,
)


def command(w_index: int, w_value: int) -> UsbControl:
    """libx52_vendor_command(index, value): one vendor request without data."""
    return UsbControl(REQUEST_TYPE, VENDOR_REQUEST, w_value, w_index)


def mfd_bytes(text: str) -> bytes:
    """A line in the MFD's code page, at most 16 characters."""
    return bytes(
        ord(c) if " " <= c <= "}" and c not in MISSING_ASCII else BOX_GLYPH
        for c in text[:LINE_WIDTH]
    )


def line_of(state: OutputState | None, index: int) -> bytes:
    if state is None or index >= len(state.texts):
        return b""
    return mfd_bytes(state.texts[index])


def brightness_of(state: OutputState | None) -> int:
    level = dict(state.analog).get("brightness", 1.0) if state is not None else 1.0
    if math.isnan(level):
        level = 0.0
    return round(min(max(level, 0.0), 1.0) * BRIGHTNESS_MAX)


def is_lit(state: OutputState, bit: int) -> bool:
    return bool(state.indicators >> bit & 1)


def line_writes(index: int, text: bytes) -> list[UsbControl]:
    """Clear the line, then its characters two per request (the second in the high byte)."""
    line = MFD_LINES[index]
    padded = text + b" " if len(text) % 2 else text
    pairs = [padded[i] | padded[i + 1] << 8 for i in range(0, len(padded), 2)]
    return [command(line | MFD_CLEAR_LINE, 0)] + [command(line, pair) for pair in pairs]


class X52ProDriver:
    """The X52 Pro's MFD, LEDs and brightness through vendor control requests."""

    @property
    def capabilities(self) -> Capabilities:
        return CAPABILITIES

    def writes(self, state: OutputState, before: OutputState | None) -> tuple[OutputWrite, ...]:
        out: list[OutputWrite] = []
        if before is None or is_lit(state, SHIFT_BIT) != is_lit(before, SHIFT_BIT):
            out.append(
                command(SHIFT_INDICATOR, SHIFT_ON if is_lit(state, SHIFT_BIT) else SHIFT_OFF)
            )
        for bit in LED_BITS:
            if before is None or is_lit(state, bit) != is_lit(before, bit):
                out.append(command(LED, bit << 8 | is_lit(state, bit)))
        for index in range(len(MFD_LINES)):
            text = line_of(state, index)
            if before is None or text != line_of(before, index):
                out.extend(line_writes(index, text))
        level = brightness_of(state)
        if before is None or level != brightness_of(before):
            out.append(command(MFD_BRIGHTNESS, level))
            out.append(command(LED_BRIGHTNESS, level))
        return tuple(out)
