"""HidOutputDriver: a device's output reports, from its own report descriptor.

What it drives (`capabilities`):

- **Indicators**: every 1-bit variable output value on the LED page (0x08), the Ordinal page
  (0x0A), the Button page (0x09), the Generic Device Controls page (0x06) and the vendor
  pages (0xFF00..0xFFFF), whatever its usage, in descriptor order. Indicator k lit = its bit
  1. Each is named by its usage: "LED Num Lock", "Instance 2", "Button 3", "0xFF000001"
  (a name seen before gets " (2)", " (3)", ...: a rule names exactly one).
- **Analog outputs**: multi-bit variable values whose usage says, without doubt, which of
  `ANALOG_NAMES` it is (`ANALOG_USAGES`: the LED page's RGB LED channels and LED Intensity,
  HUT 1.5 §11.7). A value in 0..1 is scaled onto the field's logical range (minimum ..
  maximum); a usage on the table more than once is driven everywhere.
- Everything else in a report it writes is at rest: a variable value at 0 clamped to its
  logical range (its logical minimum for an unsigned range, 0 for a signed one), an array
  and a constant all zero bits (an array selects nothing, as a host's zeroed report).

A report with nothing it drives is never written: a force-feedback device's Physical
Interface reports (effects, gains) stay the host driver's business, and a value at "rest"
there could start an effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from usb2rc.hid.descriptor import DescriptorError, OutputField, OutputLayout, parse_outputs
from usb2rc.hid.outputs import (
    ANALOG_NAMES,
    SIGNED_ANALOG,
    Capabilities,
    HidReport,
    OutputState,
    OutputWrite,
)
from usb2rc.hid.usages import (
    BUTTON_PAGE,
    GENERIC_DEVICE_PAGE,
    VENDOR_PAGE_FIRST,
    make_usage,
    usage_id,
    usage_name,
    usage_page,
)

LED_PAGE = 0x08
ORDINAL_PAGE = 0x0A
INDICATOR_PAGES = frozenset({LED_PAGE, ORDINAL_PAGE, BUTTON_PAGE, GENERIC_DEVICE_PAGE})

# The usages that are an analog output beyond doubt (HUT 1.5, LED page, "RGB LED" §11.7;
# the order there is red, blue, green). Haptics, Physical Interface and vendor usages are
# not here: their values mean something only with the rest of their report.
ANALOG_USAGES: dict[int, str] = {
    make_usage(LED_PAGE, 0x53): "red",
    make_usage(LED_PAGE, 0x54): "blue",
    make_usage(LED_PAGE, 0x55): "green",
    make_usage(LED_PAGE, 0x56): "brightness",
}

# LED page usage names (HUT 1.5 §11), for the indicators' names; one word per usage ID from
# 0, "_" for a space (a compact table: a list literal would take a line per name).
_LED_NAMES = (  # noqa: SIM905
    "Undefined Num_Lock Caps_Lock Scroll_Lock Compose Kana Power Shift Do_Not_Disturb Mute "
    "Tone_Enable High_Cut_Filter Low_Cut_Filter Equalizer_Enable Sound_Field_On "
    "Surround_Field_On Repeat Stereo Sampling_Rate_Detect Spinning CAV CLV "
    "Recording_Format_Detect Off-Hook Ring Message_Waiting Data_Mode Battery_Operation "
    "Battery_OK Battery_Low Speaker Head_Set Hold Microphone Coverage Night_Mode Send_Calls "
    "Call_Pickup Conference Stand-by Camera_On Camera_Off On-Line Off-Line Busy Ready "
    "Paper-Out Paper-Jam Remote Forward Reverse Stop Rewind Fast_Forward Play Pause Record "
    "Error Usage_Selected_Indicator Usage_In_Use_Indicator Usage_Multi_Mode_Indicator "
    "Indicator_On Indicator_Flash Indicator_Slow_Blink Indicator_Fast_Blink Indicator_Off "
    "Flash_On_Time Slow_Blink_On_Time Slow_Blink_Off_Time Fast_Blink_On_Time "
    "Fast_Blink_Off_Time Usage_Indicator_Color Indicator_Red Indicator_Green "
    "Indicator_Amber Generic_Indicator System_Suspend External_Power_Connected "
    "Indicator_Blue Indicator_Orange Good_Status Warning_Status RGB_LED Red_LED_Channel "
    "Blue_LED_Channel Green_LED_Channel LED_Intensity System_Microphone_Mute"
).split()
_LED_PLAYERS = {0x60: "Player Indicator", **{0x60 + n: f"Player {n}" for n in range(1, 9)}}


def output_usage_name(usage: int) -> str:
    """'LED Num Lock', 'Instance 2', 'Button 3', else usages.usage_name ('0xFF000001')."""
    page, number = usage_page(usage), usage_id(usage)
    if page == LED_PAGE:
        name = _LED_NAMES[number] if number < len(_LED_NAMES) else _LED_PLAYERS.get(number)
        return f"LED {name.replace('_', ' ')}" if name else f"LED 0x{number:02X}"
    if page == ORDINAL_PAGE:
        return f"Instance {number}"
    return usage_name(usage)


def is_indicator_page(page: int) -> bool:
    return page in INDICATOR_PAGES or page >= VENDOR_PAGE_FIRST


def _field_bits(value: int, bit_size: int) -> int:
    """`value` as `bit_size` bits (two's complement for a negative one)."""
    return value & ((1 << bit_size) - 1)


@dataclass(frozen=True)
class _Value:
    """One output value the driver sets: where it is and what range it has."""

    report_id: int
    bit_offset: int  # in the report's data (after the ID byte)
    bit_size: int
    logical_min: int
    logical_max: int


def _values(f: OutputField) -> list[_Value]:
    return [
        _Value(f.report_id, f.value_offset(i), f.bit_size, f.logical_min, f.logical_max)
        for i in range(f.count)
    ]


def _rest_value(f: OutputField) -> int:
    """0 clamped to the field's logical range (a variable value); arrays and constants 0."""
    if f.constant or not f.variable or f.logical_max < f.logical_min:
        return 0
    return min(max(0, f.logical_min), f.logical_max)


def _unique(names: list[str]) -> tuple[str, ...]:
    seen: dict[str, int] = {}
    unique = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        unique.append(name if seen[name] == 1 else f"{name} ({seen[name]})")
    return tuple(unique)


def scale(value: float, signed: bool, low: int, high: int) -> int:
    """A value in 0..1 (signed: -1..1) onto low..high, rounded; NaN is rest (the low end,
    signed: the middle)."""
    bottom = -1.0 if signed else 0.0
    if math.isnan(value):
        value = 0.0
    fraction = (min(max(value, bottom), 1.0) - bottom) / (1.0 - bottom)
    return low + round(fraction * (high - low))


class HidOutputDriver:
    """Builds a device's output reports (module docstring says what it drives)."""

    def __init__(self, layout: OutputLayout) -> None:
        self._lengths = layout.report_lengths
        indicators: list[tuple[_Value, str]] = []
        analog: dict[str, list[_Value]] = {}
        rest: dict[int, int] = {}  # report ID -> its bits at rest
        for f in layout.fields:
            if not f.constant and f.variable and f.usages:  # a value with no usage: rest
                for index, value in enumerate(_values(f)):
                    usage = f.usages[index]
                    if f.bit_size == 1 and is_indicator_page(usage_page(usage)):
                        indicators.append((value, output_usage_name(usage)))
                    elif f.bit_size > 1 and usage in ANALOG_USAGES:
                        analog.setdefault(ANALOG_USAGES[usage], []).append(value)
            bits = rest.get(f.report_id, 0)
            fill = _field_bits(_rest_value(f), f.bit_size)
            for i in range(f.count):
                bits |= fill << f.value_offset(i)
            rest[f.report_id] = bits
        self._indicators = tuple(v for v, _ in indicators)
        self._analog = analog
        driven = {v.report_id for v in self._indicators}
        driven |= {v.report_id for values in analog.values() for v in values}
        # descriptor order of the reports (the layout's lengths keep it)
        self._rest = {rid: rest.get(rid, 0) for rid in self._lengths if rid in driven}
        self._capabilities = Capabilities(
            indicators=len(indicators),
            indicator_names=_unique([name for _, name in indicators]),
            analog=tuple(name for name in ANALOG_NAMES if name in analog),
        )

    @classmethod
    def from_descriptor(cls, descriptor: bytes) -> HidOutputDriver | None:
        """The driver of a device with this descriptor; None when it has no output it can
        drive (no output report, or only constants, arrays and values it cannot name), or
        a descriptor it cannot read."""
        try:
            layout = parse_outputs(descriptor)
        except DescriptorError:
            return None
        driver = cls(layout)
        return driver if driver.capabilities.any else None

    @property
    def capabilities(self) -> Capabilities:
        return self._capabilities

    @property
    def report_ids(self) -> tuple[int, ...]:
        """The reports it writes, in descriptor order (0: the device has no report IDs)."""
        return tuple(self._rest)

    def reports(self, state: OutputState) -> dict[int, bytes]:
        """Every report it writes, for `state`: report ID -> what hidapi's write() takes."""
        bits = dict(self._rest)
        lit = state.indicators
        for k, v in enumerate(self._indicators):
            if lit >> k & 1:
                bits[v.report_id] |= 1 << v.bit_offset
        for name, values in self._analog.items():
            level = state.value(name)
            for v in values:
                scaled = scale(level, name in SIGNED_ANALOG, v.logical_min, v.logical_max)
                raw = _field_bits(scaled, v.bit_size)
                mask = ((1 << v.bit_size) - 1) << v.bit_offset
                bits[v.report_id] = bits[v.report_id] & ~mask | raw << v.bit_offset
        return {
            rid: bytes([rid]) + data.to_bytes(self._lengths[rid], "little")
            for rid, data in bits.items()
        }

    def writes(self, state: OutputState, before: OutputState | None) -> tuple[OutputWrite, ...]:
        """The reports whose bytes differ from `before`'s (None: every report it writes)."""
        now = self.reports(state)
        if before is None:
            return tuple(HidReport(data) for data in now.values())
        then = self.reports(before)
        return tuple(HidReport(data) for rid, data in now.items() if then[rid] != data)
