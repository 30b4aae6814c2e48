"""Test-only HID report encoder and reference decoder, independent of usb2rc's parser.

Field positions come from hid-tools' own parse (`hidtools.hid.ReportDescriptor`), never from
usb2rc's layout, so tests that encode here and decode with usb2rc compare two implementations.

Fields are named by `(usage, k)`: the k-th variable non-constant field with that usage in the
report (in descriptor order). Buttons are HID button numbers.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

import hidtools.hid

BUTTON_PAGE = 0x09

ValueKey = tuple[int, int]


def _twos(value: int, size: int) -> int:
    return value & ((1 << size) - 1)


@dataclass(frozen=True)
class RefReport:
    """One input report as hid-tools sees it."""

    report_id: int  # 0 when the device uses no report IDs
    numbered: bool
    size: int  # bytes, ID byte included
    values: dict[ValueKey, hidtools.hid.HidField]
    buttons: dict[int, hidtools.hid.HidField]  # button number -> its first variable field
    arrays: list[hidtools.hid.HidField]  # Button-page arrays


def _is_button_array(f: hidtools.hid.HidField) -> bool:
    return f.is_array and any(u >> 16 == BUTTON_PAGE for u in f.usages or [])


def ref_reports(descriptor: bytes) -> dict[int, RefReport]:
    rdesc = hidtools.hid.ReportDescriptor.from_bytes(list(descriptor))
    reports = {}
    for rid, report in rdesc.input_reports.items():
        values: dict[ValueKey, hidtools.hid.HidField] = {}
        buttons: dict[int, hidtools.hid.HidField] = {}
        arrays = []
        for f in report.fields:
            if f.is_const:
                continue
            if f.is_array:
                if _is_button_array(f):
                    arrays.append(f)
                continue
            if f.usage >> 16 == BUTTON_PAGE:
                if f.usage & 0xFFFF:
                    buttons.setdefault(f.usage & 0xFFFF, f)
                continue
            k = sum(1 for key in values if key[0] == f.usage)
            values[(f.usage, k)] = f
        number = max(rid, 0)
        size = (report.bitsize + 7) // 8  # hid-tools' own `size` rounds down
        reports[number] = RefReport(number, rid >= 0, size, values, buttons, arrays)
    return reports


def _field_value(f: hidtools.hid.HidField, data: list[int], idx: int = 0) -> int:
    value = f.get_values(data)[idx]
    assert isinstance(value, int)
    return value


def decode(ref: RefReport, report: bytes) -> tuple[dict[ValueKey, int], set[int]]:
    """hid-tools' reading of one report: values by (usage, k), and the pressed buttons."""
    data = list(report)
    values = {key: _field_value(f, data) for key, f in ref.values.items()}
    pressed = {n for n, f in ref.buttons.items() if _field_value(f, data)}
    for f in ref.arrays:
        usages = f.usages or []
        for v in f.get_values(data):
            assert isinstance(v, int)  # a Button-page array holds indices, never strings
            index = v - f.logical_min
            if 0 <= index < len(usages) and v <= f.logical_max:
                usage = usages[index]
                if usage >> 16 == BUTTON_PAGE and usage & 0xFFFF:
                    pressed.add(usage & 0xFFFF)
    return values, pressed


def _put(buf: bytearray, start: int, size: int, value: int) -> None:
    for bit in range(size):
        byte, shift = divmod(start + bit, 8)
        if (value >> bit) & 1:
            buf[byte] |= 1 << shift
        else:
            buf[byte] &= ~(1 << shift) & 0xFF


def encode(
    ref: RefReport,
    values: dict[ValueKey, int] | None = None,
    buttons: set[int] | frozenset[int] = frozenset(),
    fill: bytes | None = None,
) -> bytes:
    """A report with the given values (logical, signed where the field is) and buttons pressed;
    other bits from `fill` (default zero). Bit positions are hid-tools' `field.start`."""
    buf = bytearray(fill if fill is not None else bytes(ref.size))
    if ref.numbered:
        buf[0] = ref.report_id
    for key, value in (values or {}).items():
        f = ref.values[key]
        _put(buf, f.start, f.size, _twos(value, f.size))
    for number, f in ref.buttons.items():
        _put(buf, f.start, f.size, 1 if number in buttons else 0)
    for f in ref.arrays:
        _fill_array(buf, f, buttons)
    return bytes(buf)


def _fill_array(
    buf: bytearray, f: hidtools.hid.HidField, buttons: set[int] | frozenset[int]
) -> None:
    slots = [
        f.logical_min + i
        for i, usage in enumerate(f.usages or [])
        if usage >> 16 == BUTTON_PAGE and (usage & 0xFFFF) in buttons
    ][: f.count]
    empty = f.logical_max + 1 if f.logical_min > 0 or f.logical_max + 1 < (1 << f.size) else 0
    for i in range(f.count):
        value = slots[i] if i < len(slots) else empty
        _put(buf, f.start + i * f.size, f.size, _twos(value, f.size))


def random_values(ref: RefReport, rng: random.Random) -> dict[ValueKey, int]:
    """A value for each field, mostly inside its logical range, sometimes anywhere it fits."""
    out = {}
    for key, f in ref.values.items():
        signed = f.logical_min < 0 and f.size > 1
        low = -(1 << (f.size - 1)) if signed else 0
        high = (1 << (f.size - 1)) - 1 if signed else (1 << f.size) - 1
        if rng.random() < 0.8 and low <= f.logical_min <= f.logical_max <= high:
            out[key] = rng.randint(f.logical_min, f.logical_max)
        else:
            out[key] = rng.randint(low, high)
    return out
