"""HID report descriptors: parse into a field layout, compile a per-device decode plan.

Terms are the HID 1.11 spec's: usage page / usage, logical minimum / maximum, report size /
count, report ID, Main / Global / Local items.
"""

from __future__ import annotations

from dataclasses import dataclass


class DescriptorError(ValueError):
    """A report descriptor usb2rc cannot use; the message says why."""


@dataclass(frozen=True)
class InputField:
    """One variable input value (an axis, a hat, a vendor value): not buttons, not constants."""

    index: int  # position in DeviceLayout.inputs and InputState.values
    report_id: int  # 0 when the device uses no report IDs
    usage: int  # (page << 16) | id
    bit_offset: int  # from the first data byte (after the report-ID byte)
    bit_size: int
    logical_min: int
    logical_max: int  # signed when logical_min < 0 (DECISIONS.md)
    has_null: bool
    occurrence: int  # 0 for the first field with this usage in the device, 1 for the second ...


@dataclass(frozen=True)
class InputState:
    """A device's decoded state: one raw logical value per InputField, buttons as one mask."""

    values: tuple[int, ...]
    buttons: int  # HID button n -> bit n-1


@dataclass(frozen=True)
class DeviceLayout:
    application: int  # top-level collection usage, e.g. 0x00010004 (Joystick)
    uses_report_ids: bool
    inputs: tuple[InputField, ...]
    button_count: int  # highest HID button number seen
    input_report_lengths: dict[int, int]  # report ID -> data bytes, without the ID byte

    def initial_state(self) -> InputState:
        return InputState(tuple(0 for _ in self.inputs), 0)
