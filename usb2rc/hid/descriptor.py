"""HID report descriptors: parse into a field layout, compile a per-device decode plan.

(Over 500 lines on purpose: the parser and the plan compiler share the item tables and the
field types, and the plan is only correct for layouts this parser makes; split, each half
would have to know the other's invariants.)

Terms are the HID 1.11 spec's: usage page / usage, logical minimum / maximum, report size /
count, report ID, Main / Global / Local items.

Where the spec leaves room, usb2rc does what the Linux kernel's hid-core does:

- A Usage Page given after the Usages of a Main item (but before it) applies to those Usages
  (hid-core's "concatenate last usage page"); 4-byte (extended) usages keep their own page.
- Report Count larger than the usage list: the last usage repeats (HID 1.11 §6.2.2.8). For
  values each repeat is one more InputField (its `occurrence` counts up). For buttons only the
  first bit of a button number in a report is that button: repeats are ignored, so a stray bit
  in such a run can never press a button (the FR-TEC Raptor sends 128 bits for buttons 1..29).
- Logical Minimum is read as signed. Logical Maximum is read as signed when the minimum is
  negative, else as unsigned (hid-core does the same), so `15 00 26 FF FF` is 0..65535 and not
  0..-1 (Windows' synthesized Xbox 360 descriptor has exactly that).
- A logical range with max < min on a data input is refused, as hid-core refuses it.
- Unknown Main and Local items are skipped; an unknown Global item is refused (it may change
  the meaning of everything that follows). Long items are skipped.
- Limits (as hid-core): Report Size <= 256, Report Count <= 12288, Report ID 1..255, an input
  report of at most 16383 data bytes, Push nested at most 16 deep, at most 16384 input values
  and button bits in one descriptor.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from usb2rc.hid import speedups
from usb2rc.hid.usages import BUTTON_PAGE, GD_HAT_SWITCH

if TYPE_CHECKING:  # the C loops may not be built here (usb2rc.hid.speedups)
    from usb2rc.hid._speedups import Plan

C_BUTTON_BITS = 64  # the C drain's button mask is a uint64
C_FIELD_BITS = 32


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
    logical_max: int  # signed when logical_min < 0 (docs/ICD.md, "Axis scaling")
    has_null: bool
    occurrence: int  # 0 for the first field with this usage in the device, 1 for the second ...

    @property
    def is_signed(self) -> bool:
        return self.logical_min < 0

    def null_value(self) -> int:
        """A raw value outside [logical_min, logical_max], preferably one the field can hold."""
        low, high = _representable(self.bit_size, self.is_signed)
        if self.logical_max < high:
            return self.logical_max + 1
        if self.logical_min > low:
            return self.logical_min - 1
        return self.logical_max + 1

    def centre(self) -> int:
        return (self.logical_min + self.logical_max + 1) // 2


@dataclass(frozen=True)
class InputState:
    """A device's decoded state: one raw logical value per InputField, buttons as one mask."""

    values: tuple[int, ...]
    buttons: int  # HID button n -> bit n-1


@dataclass(frozen=True)
class ButtonField:
    """`count` buttons numbered from `first_button`, each `bit_size` bits (normally 1) wide,
    side by side from `bit_offset`. A button is pressed when its bits are not all zero."""

    report_id: int
    first_button: int  # 1-based HID button number
    count: int
    bit_offset: int
    bit_size: int = 1

    @property
    def mask(self) -> int:
        return ((1 << self.count) - 1) << (self.first_button - 1)


@dataclass(frozen=True)
class ButtonArray:
    """An array input on the Button page: `count` slots of `bit_size` bits, each holding the
    index (from `logical_min`) of a pressed button, or a value outside the range for none."""

    report_id: int
    bit_offset: int
    bit_size: int
    count: int
    logical_min: int
    logical_max: int
    # (first index, end index (exclusive), button number at the first index)
    segments: tuple[tuple[int, int, int], ...]

    @property
    def mask(self) -> int:
        mask = 0
        for start, end, first in self.segments:
            mask |= ((1 << (end - start)) - 1) << (first - 1)
        return mask

    def button_at(self, value: int) -> int:
        """The button number a slot value stands for, 0 for none."""
        if not self.logical_min <= value <= self.logical_max:
            return 0
        index = value - self.logical_min
        for start, end, first in self.segments:
            if start <= index < end:
                return first + index - start
        return 0


@dataclass(frozen=True)
class DeviceLayout:
    application: int  # top-level collection usage, e.g. 0x00010004 (Joystick)
    uses_report_ids: bool
    inputs: tuple[InputField, ...]
    button_count: int  # highest HID button number seen
    input_report_lengths: dict[int, int]  # report ID -> data bytes, without the ID byte
    buttons: tuple[ButtonField, ...] = ()
    button_arrays: tuple[ButtonArray, ...] = ()

    def hat_fields(self) -> tuple[InputField, ...]:
        return tuple(f for f in self.inputs if f.usage == GD_HAT_SWITCH)

    def initial_state(self) -> InputState:
        """Axes at the centre of their logical range, hats at a null (centred) value."""
        values = tuple(
            f.null_value() if f.usage == GD_HAT_SWITCH else f.centre() for f in self.inputs
        )
        return InputState(values, 0)

    def make_decoder(self) -> ReportDecoder:
        return ReportDecoder(self)

    @functools.cached_property
    def report_plans(self) -> dict[int, _ReportPlan]:
        """The decode plan of each input report ID, compiled once per layout: a device of a
        model seen before gets the cached layout (`parse_descriptor`), so a replug compiles
        nothing (compiling is Python that competes with the output threads for the GIL). Plans
        hold no state; each ReportDecoder keeps its own values."""
        return {rid: _compile_report(self, rid) for rid in self.input_report_lengths}

    @functools.cached_property
    def c_plan(self) -> Plan | None:
        """The C drain's plan of this layout (`ReportDecoder.feed_batch`), or None: the C
        drain is not built or is switched off (PURE_PYTHON_ENV), or the layout is outside
        it (a Button-page array, a value wider than C_FIELD_BITS, a button above
        C_BUTTON_BITS)."""
        return _c_plan(self)

    @functools.cached_property
    def id_scan(self) -> _IdScanFn:
        """A device with report IDs: a batch's button masks and each ID's last valid report
        in one generated loop (`ReportDecoder.feed_batch`), compiled once per layout."""
        return _compile_id_scan(self)


def _representable(bit_size: int, signed: bool) -> tuple[int, int]:
    if signed and bit_size > 1:
        return -(1 << (bit_size - 1)), (1 << (bit_size - 1)) - 1
    return 0, (1 << bit_size) - 1


# --------------------------------------------------------------------------------------------
# Parsing


MAX_REPORT_SIZE = 256  # bits per Report Size
MAX_REPORT_COUNT = 12288
MAX_REPORT_BYTES = 16383  # data bytes of one input report
MAX_PUSH_DEPTH = 16
MAX_INPUT_ELEMENTS = 16384  # values and button bits over the whole descriptor

INPUT, OUTPUT, FEATURE, COLLECTION, END_COLLECTION = 0x80, 0x90, 0xB0, 0xA0, 0xC0
USAGE_PAGE, LOGICAL_MIN, LOGICAL_MAX = 0x04, 0x14, 0x24
PHYSICAL_MIN, PHYSICAL_MAX, UNIT_EXPONENT, UNIT = 0x34, 0x44, 0x54, 0x64
REPORT_SIZE, REPORT_ID, REPORT_COUNT, PUSH, POP = 0x74, 0x84, 0x94, 0xA4, 0xB4
USAGE, USAGE_MIN, USAGE_MAX, DELIMITER = 0x08, 0x18, 0x28, 0xA8
LONG_ITEM = 0xFE

FLAG_CONSTANT, FLAG_VARIABLE, FLAG_NULL_STATE = 0x01, 0x02, 0x40
COLLECTION_APPLICATION = 0x01

_DATA_SIZES = (0, 1, 2, 4)


@dataclass(frozen=True)
class _Item:
    offset: int  # byte offset of the item's header in the descriptor
    tag: int  # header byte with the size bits cleared
    size: int  # data bytes: 0, 1, 2 or 4
    value: int  # data, unsigned little-endian


def _items(data: bytes) -> Iterator[_Item]:
    pos = 0
    end = len(data)
    while pos < end:
        header = data[pos]
        if header == LONG_ITEM:
            if pos + 3 > end:
                raise DescriptorError(f"truncated long item at byte {pos}")
            nxt = pos + 3 + data[pos + 1]
            if nxt > end:
                raise DescriptorError(f"truncated long item at byte {pos}")
            pos = nxt
            continue
        size = _DATA_SIZES[header & 0x03]
        if pos + 1 + size > end:
            raise DescriptorError(
                f"truncated item 0x{header:02X} at byte {pos}: {size} data bytes expected, "
                f"{end - pos - 1} left"
            )
        value = int.from_bytes(data[pos + 1 : pos + 1 + size], "little")
        yield _Item(pos, header & 0xFC, size, value)
        pos += 1 + size


def top_level_usage(data: bytes) -> tuple[int, int]:
    """(usage page, usage) of the first top-level collection, from the items before it;
    (0, 0) when the descriptor opens no collection or breaks off before one. Enough to
    name a device (`usb2rc list`) whose descriptor `parse_descriptor` might refuse."""
    page = usage = 0
    try:
        for item in _items(data):
            if item.tag == USAGE_PAGE:
                page = item.value
            elif item.tag == USAGE and item.size == 4:  # the 4-byte form carries its page
                page, usage = item.value >> 16, item.value & 0xFFFF
            elif item.tag == USAGE:
                usage = item.value
            elif item.tag == COLLECTION:
                return page, usage
    except DescriptorError:
        pass
    return 0, 0


def _signed(value: int, size: int) -> int:
    if size and value & (1 << (8 * size - 1)):
        return value - (1 << (8 * size))
    return value


@dataclass
class _Globals:
    usage_page: int = 0
    logical_min: tuple[int, int] = (0, 0)  # (raw value, data bytes)
    logical_max: tuple[int, int] = (0, 0)
    report_size: int = 0
    report_count: int = 0
    report_id: int = 0

    def copy(self) -> _Globals:
        return _Globals(
            self.usage_page,
            self.logical_min,
            self.logical_max,
            self.report_size,
            self.report_count,
            self.report_id,
        )

    def logical_range(self) -> tuple[int, int]:
        low = _signed(*self.logical_min)
        high = _signed(*self.logical_max) if low < 0 else self.logical_max[0]
        return low, high


@dataclass
class _UsageRun:
    """Usages first..last (same page); `size` is the data size of the item that gave them."""

    first: int
    last: int
    size: int

    def __len__(self) -> int:
        return self.last - self.first + 1


@dataclass
class _Locals:
    runs: list[_UsageRun] = field(default_factory=list)
    usage_min: tuple[int, int] | None = None  # (raw value, data bytes)
    delimiter_depth: int = 0
    delimiter_branch: int = 0


def _full_usage(value: int, size: int, page: int) -> int:
    return value if size == 4 else (page << 16) | (value & 0xFFFF)


class _Parser:
    """The HID 1.11 item state machine. One instance parses one descriptor."""

    def __init__(self) -> None:
        self.glob = _Globals()
        self.stack: list[_Globals] = []
        self.local = _Locals()
        self.depth = 0
        self.application: int | None = None
        self.bit_ends: dict[int, int] = {}  # report ID -> input bits so far
        self.inputs: list[InputField] = []
        self.occurrences: dict[int, int] = {}
        self.buttons: list[ButtonField] = []
        self.button_arrays: list[ButtonArray] = []
        self.owned_buttons: dict[int, set[int]] = {}  # report ID -> button numbers
        self.elements = 0

    # -- driver ------------------------------------------------------------------------------

    def parse(self, data: bytes) -> DeviceLayout:
        self.run(data)
        return self.finish(len(data))

    def run(self, data: bytes) -> None:
        for item in _items(data):
            kind = item.tag & 0x0C
            if kind == 0x00:
                self.main(item)
            elif kind == 0x04:
                self.global_item(item)
            elif kind == 0x08:
                self.local_item(item)
            # kind 0x0C: reserved item type, skipped

    def check_closed(self, end: int) -> None:
        if self.depth:
            raise DescriptorError(
                f"unbalanced collections: {self.depth} still open at the end (byte {end})"
            )

    def finish(self, end: int) -> DeviceLayout:
        self.check_closed(end)
        lengths = {rid: (bits + 7) // 8 for rid, bits in self.bit_ends.items() if bits}
        if not self.inputs and not self.buttons and not self.button_arrays:
            raise DescriptorError("no usable inputs in the descriptor")
        if 0 in lengths and len(lengths) > 1:
            raise DescriptorError("input items without a report ID beside numbered reports")
        button_count = max(
            [b.first_button + b.count - 1 for b in self.buttons]
            + [s[2] + s[1] - s[0] - 1 for a in self.button_arrays for s in a.segments]
            + [0]
        )
        return DeviceLayout(
            application=self.application or 0,
            uses_report_ids=0 not in lengths,
            inputs=tuple(self.inputs),
            button_count=button_count,
            input_report_lengths=lengths,
            buttons=tuple(_merge_button_fields(self.buttons)),
            button_arrays=tuple(self.button_arrays),
        )

    # -- global items ------------------------------------------------------------------------

    def global_item(self, item: _Item) -> None:
        tag, value, glob = item.tag, item.value, self.glob
        if tag == USAGE_PAGE:
            if value > 0xFFFF:
                raise DescriptorError(f"usage page 0x{value:X} too large at byte {item.offset}")
            glob.usage_page = value
        elif tag == LOGICAL_MIN:
            glob.logical_min = (value, item.size)
        elif tag == LOGICAL_MAX:
            glob.logical_max = (value, item.size)
        elif tag in (PHYSICAL_MIN, PHYSICAL_MAX, UNIT_EXPONENT, UNIT):
            pass
        elif tag == REPORT_SIZE:
            glob.report_size = self.limited(item, "Report Size", MAX_REPORT_SIZE)
        elif tag == REPORT_COUNT:
            glob.report_count = self.limited(item, "Report Count", MAX_REPORT_COUNT)
        elif tag == REPORT_ID:
            if not 1 <= value <= 255:
                raise DescriptorError(f"invalid Report ID {value} at byte {item.offset}")
            glob.report_id = value
        elif tag == PUSH:
            self.push(item)
        elif tag == POP:
            if not self.stack:
                raise DescriptorError(f"Pop without Push at byte {item.offset}")
            self.glob = self.stack.pop()
        else:
            raise DescriptorError(f"unknown global item 0x{item.tag:02X} at byte {item.offset}")

    @staticmethod
    def limited(item: _Item, what: str, limit: int) -> int:
        if item.value > limit:
            raise DescriptorError(
                f"{what} {item.value} at byte {item.offset} is larger than {limit}"
            )
        return item.value

    def push(self, item: _Item) -> None:
        if len(self.stack) >= MAX_PUSH_DEPTH:
            raise DescriptorError(f"Push nested deeper than {MAX_PUSH_DEPTH} at byte {item.offset}")
        self.stack.append(self.glob.copy())

    # -- local items -------------------------------------------------------------------------

    def local_item(self, item: _Item) -> None:
        local = self.local
        if item.tag == DELIMITER:
            self.delimiter(item)
        elif local.delimiter_branch > 1 and item.tag in (USAGE, USAGE_MIN, USAGE_MAX):
            pass  # only the first usage set of a delimited alternative counts (as hid-core)
        elif item.tag == USAGE:
            usage = _full_usage(item.value, item.size, self.glob.usage_page)
            local.runs.append(_UsageRun(usage, usage, item.size))
        elif item.tag == USAGE_MIN:
            local.usage_min = (item.value, item.size)
        elif item.tag == USAGE_MAX:
            self.usage_range(item)

    def usage_range(self, item: _Item) -> None:
        high = _full_usage(item.value, item.size, self.glob.usage_page)
        low_id = (self.local.usage_min or (0, 0))[0] & 0xFFFF
        if low_id <= high & 0xFFFF:
            self.local.runs.append(_UsageRun((high & ~0xFFFF) | low_id, high, item.size))
        self.local.usage_min = None

    def delimiter(self, item: _Item) -> None:
        local = self.local
        if item.value:
            if local.delimiter_depth:
                raise DescriptorError(f"nested Delimiter at byte {item.offset}")
            local.delimiter_depth += 1
            local.delimiter_branch += 1
        else:
            if not local.delimiter_depth:
                raise DescriptorError(f"Delimiter close without open at byte {item.offset}")
            local.delimiter_depth -= 1

    def concatenate_usage_page(self) -> None:
        """hid-core: a Usage Page set after usages (before the Main item) applies to them."""
        page = self.glob.usage_page
        for run in reversed(self.local.runs):
            if run.size > 2:
                continue
            if run.first >> 16 == page:
                break
            run.first = (page << 16) | (run.first & 0xFFFF)
            run.last = (page << 16) | (run.last & 0xFFFF)

    # -- main items --------------------------------------------------------------------------

    def main(self, item: _Item) -> None:
        self.concatenate_usage_page()
        if item.tag == INPUT:
            self.input(item)
        elif item.tag == COLLECTION:
            self.open_collection(item)
        elif item.tag == END_COLLECTION:
            self.close_collection(item)
        # Output, Feature and reserved main items carry nothing into input reports.
        self.local = _Locals()

    def close_collection(self, item: _Item) -> None:
        if not self.depth:
            raise DescriptorError(f"End Collection without Collection at byte {item.offset}")
        self.depth -= 1

    def open_collection(self, item: _Item) -> None:
        if self.depth == 0 and item.value == COLLECTION_APPLICATION and self.application is None:
            runs = self.local.runs
            self.application = runs[0].first if runs else 0
        self.depth += 1

    def reserve(self, ends: dict[int, int], item: _Item, kind: str) -> int:
        """The bit offset of a Main item's data in its report; the report grows by it."""
        glob = self.glob
        rid = glob.report_id
        start = ends.get(rid, 0)
        end = start + glob.report_size * glob.report_count
        if end > MAX_REPORT_BYTES * 8:
            raise DescriptorError(
                f"{kind} report {rid} longer than {MAX_REPORT_BYTES} bytes at byte {item.offset}"
            )
        ends[rid] = end
        return start

    def input(self, item: _Item) -> None:
        glob = self.glob
        size, count = glob.report_size, glob.report_count
        start = self.reserve(self.bit_ends, item, "input")
        if item.value & FLAG_CONSTANT or not self.local.runs or count == 0:
            return  # padding: advances the offset only
        if size == 0:
            raise DescriptorError(
                f"Report Size 0 with Report Count {count} on a data input at byte {item.offset}"
            )
        low, high = glob.logical_range()
        if high < low:
            raise DescriptorError(
                f"logical range {low}..{high} (maximum below minimum) at byte {item.offset}"
            )
        self.elements += count
        if self.elements > MAX_INPUT_ELEMENTS:
            raise DescriptorError(
                f"more than {MAX_INPUT_ELEMENTS} input values at byte {item.offset}"
            )
        if item.value & FLAG_VARIABLE:
            self.variable_input(start, low, high, bool(item.value & FLAG_NULL_STATE))
        else:
            self.array_input(start, low, high)

    def variable_input(self, start: int, low: int, high: int, has_null: bool) -> None:
        glob = self.glob
        size, rid = glob.report_size, glob.report_id
        owned = self.owned_buttons.setdefault(rid, set())
        for i, usage in enumerate(_usages_for(self.local.runs, glob.report_count)):
            offset = start + i * size
            if usage >> 16 == BUTTON_PAGE:
                number = usage & 0xFFFF
                if number and number not in owned:
                    owned.add(number)
                    self.buttons.append(ButtonField(rid, number, 1, offset, size))
                continue
            occurrence = self.occurrences.get(usage, 0)
            self.occurrences[usage] = occurrence + 1
            self.inputs.append(
                InputField(
                    index=len(self.inputs),
                    report_id=rid,
                    usage=usage,
                    bit_offset=offset,
                    bit_size=size,
                    logical_min=low,
                    logical_max=high,
                    has_null=has_null,
                    occurrence=occurrence,
                )
            )

    def array_input(self, start: int, low: int, high: int) -> None:
        segments = _button_segments(self.local.runs)
        if not segments:
            return  # arrays on other pages (keyboard keys, ...) are not read
        glob = self.glob
        self.button_arrays.append(
            ButtonArray(
                report_id=glob.report_id,
                bit_offset=start,
                bit_size=glob.report_size,
                count=glob.report_count,
                logical_min=low,
                logical_max=high,
                segments=segments,
            )
        )


def _usages_for(runs: list[_UsageRun], count: int) -> Iterator[int]:
    """The usage of each of `count` variable fields: in order, the last one repeating."""
    produced = 0
    last = 0
    for run in runs:
        for usage in range(run.first, min(run.last, run.first + count - produced - 1) + 1):
            yield usage
            produced += 1
            last = usage
        if produced >= count:
            return
    for _ in range(count - produced):
        yield last


def _button_segments(runs: list[_UsageRun]) -> tuple[tuple[int, int, int], ...]:
    """Array index ranges that name buttons: (first index, end index, first button)."""
    segments = []
    index = 0
    for run in runs:
        first_id = run.first & 0xFFFF
        if run.first >> 16 == BUTTON_PAGE:
            skip = 1 if first_id == 0 else 0  # Button 0 is "no button pressed"
            if len(run) > skip:
                segments.append((index + skip, index + len(run), first_id + skip))
        index += len(run)
    return tuple(segments)


def _merge_button_fields(fields: list[ButtonField]) -> list[ButtonField]:
    """Join 1-bit buttons that follow each other in bits and in numbers into one run."""
    merged: list[ButtonField] = []
    for f in fields:
        prev = merged[-1] if merged else None
        if (
            prev is not None
            and prev.report_id == f.report_id
            and prev.bit_size == 1
            and f.bit_size == 1
            and prev.bit_offset + prev.count == f.bit_offset
            and prev.first_button + prev.count == f.first_button
        ):
            merged[-1] = ButtonField(
                prev.report_id, prev.first_button, prev.count + f.count, prev.bit_offset
            )
        else:
            merged.append(f)
    return merged


def parse_descriptor(data: bytes) -> DeviceLayout:
    """Parse a HID report descriptor into the layout of its input reports.

    Raises DescriptorError (and nothing else) for a descriptor usb2rc cannot use. A layout is
    immutable, so the same descriptor bytes give the same (cached) layout: a replugged
    device or another of the same model costs no parse (nor a plan: `report_plans`)."""
    try:
        return _parse_cached(bytes(data))
    except DescriptorError:
        raise
    except Exception as exc:  # a bug here must not take the daemon down with another type
        raise DescriptorError(f"descriptor not understood: {exc!r}") from exc


@functools.lru_cache(maxsize=64)
def _parse_cached(data: bytes) -> DeviceLayout:
    return _Parser().parse(data)


# --------------------------------------------------------------------------------------------
# Output reports: a pass of their own, on request (the input path above never pays for it)


MAX_ARRAY_USAGES = 1 << 16  # usages an output array keeps (a selector cannot name more)


@dataclass(frozen=True)
class OutputField:
    """One Output main item: `count` values of `bit_size` bits side by side from
    `bit_offset` (from the first data byte, after the report-ID byte). `usages`: a
    variable item's usage of each value (the last one repeating, as for inputs); an
    array's the usages its values select (`logical_min` selects the first); a constant's
    none. Logical limits as for inputs (signed when the minimum is negative)."""

    report_id: int
    bit_offset: int
    bit_size: int
    count: int
    usages: tuple[int, ...]
    logical_min: int
    logical_max: int
    variable: bool
    constant: bool

    @property
    def usage_page(self) -> int:
        """The page of its first usage; 0 when it has none."""
        return self.usages[0] >> 16 if self.usages else 0

    def value_offset(self, index: int) -> int:
        """The bit offset of value `index` (0 .. count - 1)."""
        return self.bit_offset + index * self.bit_size


@dataclass(frozen=True)
class OutputLayout:
    """A device's output reports: their fields in descriptor order, and each report's
    length in data bytes (without the ID byte) per report ID (0: the device uses none)."""

    fields: tuple[OutputField, ...]
    report_lengths: dict[int, int]

    @property
    def uses_report_ids(self) -> bool:
        return 0 not in self.report_lengths


class _OutputParser(_Parser):
    """The same item state machine, for Output items only (Input items are skipped: their
    checks belong to `parse_descriptor`)."""

    def __init__(self) -> None:
        super().__init__()
        self.output_ends: dict[int, int] = {}  # report ID -> output bits so far
        self.outputs: list[OutputField] = []

    def main(self, item: _Item) -> None:
        self.concatenate_usage_page()
        if item.tag == OUTPUT:
            self.output(item)
        elif item.tag == COLLECTION:
            self.depth += 1
        elif item.tag == END_COLLECTION:
            self.close_collection(item)
        self.local = _Locals()

    def output(self, item: _Item) -> None:
        glob = self.glob
        size, count, rid = glob.report_size, glob.report_count, glob.report_id
        start = self.reserve(self.output_ends, item, "output")
        if count == 0 or size == 0:
            return
        constant = bool(item.value & FLAG_CONSTANT)
        variable = bool(item.value & FLAG_VARIABLE)
        low, high = glob.logical_range()
        runs = self.local.runs
        if constant or not runs:
            usages: tuple[int, ...] = ()
        elif variable:
            usages = tuple(_usages_for(runs, count))
        else:
            usages = tuple(_array_usages(runs))
        self.outputs.append(
            OutputField(rid, start, size, count, usages, low, high, variable, constant)
        )

    def output_layout(self, end: int) -> OutputLayout:
        self.check_closed(end)
        lengths = {rid: (bits + 7) // 8 for rid, bits in self.output_ends.items() if bits}
        if 0 in lengths and len(lengths) > 1:
            raise DescriptorError("output items without a report ID beside numbered reports")
        return OutputLayout(tuple(self.outputs), lengths)


def _array_usages(runs: list[_UsageRun]) -> Iterator[int]:
    """An array's selectable usages in order, at most MAX_ARRAY_USAGES."""
    left = MAX_ARRAY_USAGES
    for run in runs:
        take = min(len(run), left)
        yield from range(run.first, run.first + take)
        left -= take
        if not left:
            return


def parse_outputs(data: bytes) -> OutputLayout:
    """The output reports of a HID report descriptor (none: an empty layout). A separate
    pass over the items, only for a caller that drives outputs. Raises DescriptorError (and
    nothing else) for a descriptor it cannot read."""
    try:
        return _parse_outputs_cached(bytes(data))
    except DescriptorError:
        raise
    except Exception as exc:  # as parse_descriptor: one error type for a bad descriptor
        raise DescriptorError(f"descriptor not understood: {exc!r}") from exc


@functools.lru_cache(maxsize=64)
def _parse_outputs_cached(data: bytes) -> OutputLayout:
    parser = _OutputParser()
    parser.run(data)
    return parser.output_layout(len(data))


# --------------------------------------------------------------------------------------------
# Decoding: a straight-line function per report, generated once per device


_DecodeFn = Callable[[bytes, list[int]], int]


def _array_buttons(word: int, array: ButtonArray, shift: int) -> int:
    """Buttons pressed in a Button-page array (the rare path: a loop over its slots)."""
    size, mask = array.bit_size, (1 << array.bit_size) - 1
    sign = 1 << (size - 1) if array.logical_min < 0 else 0
    pressed = 0
    for slot in range(array.count):
        value = (word >> (shift + slot * size)) & mask
        if sign:
            value = (value ^ sign) - sign
        number = array.button_at(value)
        if number:
            pressed |= 1 << (number - 1)
    return pressed


def _value_expr(f: InputField, id_bits: int) -> str:
    """Python source of the expression that reads one field out of report `r` / int `v`."""
    offset = f.bit_offset + id_bits
    signed = f.is_signed and f.bit_size > 1
    sign = 1 << (f.bit_size - 1)
    if offset % 8 == 0 and f.bit_size == 8:
        raw = f"r[{offset // 8}]"
    else:
        raw = f"(v >> {offset} & {(1 << f.bit_size) - 1:#x})"
    return f"(({raw} ^ {sign:#x}) - {sign:#x})" if signed else raw


_STRUCT_CODES = {8: "B", 16: "H", 32: "I"}


def _struct_code(f: InputField, id_bits: int) -> str | None:
    """The struct format character of a byte-aligned 8/16/32-bit field, else None."""
    code = _STRUCT_CODES.get(f.bit_size)
    if code is None or (f.bit_offset + id_bits) % 8:
        return None
    return code.lower() if f.is_signed else code


def _runs(fields: list[InputField], id_bits: int) -> list[list[InputField]]:
    """Split fields into runs that one struct.unpack_from (or one bytes slice) can read:
    byte-aligned, same width and signedness, adjacent in bits and in index."""
    runs: list[list[InputField]] = []
    for f in fields:
        prev = runs[-1][-1] if runs else None
        code = _struct_code(f, id_bits)
        if (
            prev is not None
            and code is not None
            and code == _struct_code(prev, id_bits)
            and f.index == prev.index + 1
            and f.bit_offset == prev.bit_offset + prev.bit_size
        ):
            runs[-1].append(f)
        else:
            runs.append([f])
    return runs


def _run_lines(run: list[InputField], id_bits: int) -> list[str]:
    first = run[0]
    if len(run) == 1 or _struct_code(first, id_bits) is None:
        return [f"    vals[{f.index}] = {_value_expr(f, id_bits)}" for f in run]
    start = (first.bit_offset + id_bits) // 8
    target = f"vals[{first.index}:{first.index + len(run)}]"
    code = _struct_code(first, id_bits)
    if code == "B":
        return [f"    {target} = r[{start}:{start + len(run)}]"]
    return [f"    {target} = unpack_from('<{len(run)}{code}', r, {start})"]


def _button_expr(b: ButtonField, id_bits: int) -> str:
    offset = b.bit_offset + id_bits
    if b.bit_size != 1:
        bit, mask = 1 << (b.first_button - 1), (1 << b.bit_size) - 1
        return f"({bit:#x} if v >> {offset} & {mask:#x} else 0)"
    target = b.first_button - 1
    mask = ((1 << b.count) - 1) << target
    if offset >= target:
        return f"(v >> {offset - target} & {mask:#x})"
    return f"(v << {target - offset} & {mask:#x})"


_ScanFn = Callable[[Sequence[bytes], int, Callable[[int], None]], tuple["bytes | None", int]]


@dataclass(frozen=True)
class _ReportPlan:
    length: int  # bytes the report must have, ID byte included
    decode: _DecodeFn
    keep_buttons: int  # ~ the buttons this report owns
    source: str  # the generated code, for debugging
    # A device without report IDs: a batch's button masks in one loop (`ReportDecoder.
    # feed_batch`), the buttons' expression inline, no call per report but on a change.
    scan: _ScanFn


def _button_terms(layout: DeviceLayout, rid: int, arrays_name: str) -> list[str]:
    """The expressions (of a report's integer `v`) of the buttons report `rid` presses; its
    Button-page arrays are `{arrays_name}[i]` in the generated code's namespace."""
    id_bits = 8 if layout.uses_report_ids else 0
    buttons = [b for b in layout.buttons if b.report_id == rid]
    arrays = [a for a in layout.button_arrays if a.report_id == rid]
    terms = [_button_expr(b, id_bits) for b in buttons]
    terms += [
        f"_array_buttons(v, {arrays_name}[{i}], {a.bit_offset + id_bits})"
        for i, a in enumerate(arrays)
    ]
    return terms


def _owned_buttons(layout: DeviceLayout, rid: int) -> int:
    owned = 0
    for b in layout.buttons:
        owned |= b.mask if b.report_id == rid else 0
    for a in layout.button_arrays:
        owned |= a.mask if a.report_id == rid else 0
    return owned


def _compile_report(layout: DeviceLayout, rid: int) -> _ReportPlan:
    id_bits = 8 if layout.uses_report_ids else 0
    fields = [f for f in layout.inputs if f.report_id == rid]
    arrays = [a for a in layout.button_arrays if a.report_id == rid]
    owned = _owned_buttons(layout, rid)
    length = layout.input_report_lengths[rid] + id_bits // 8
    lines = ["def decode(r, vals):", "    v = int.from_bytes(r, 'little')"]
    for run in _runs(fields, id_bits):
        lines += _run_lines(run, id_bits)
    terms = _button_terms(layout, rid, "arrays")
    pressed = _pressed_lines(terms, "    ")
    lines += [*pressed, "    return b"]
    lines += _scan_lines(terms, length)
    source = "\n".join(lines) + "\n"
    namespace: dict[str, object] = {
        "_array_buttons": _array_buttons,
        "arrays": tuple(arrays),
        "unpack_from": struct.unpack_from,
        "keep": ~owned,
    }
    exec(compile(source, f"<usb2rc decode plan, report {rid}>", "exec"), namespace)
    decode: _DecodeFn = namespace["decode"]  # type: ignore[assignment]
    scan: _ScanFn = namespace["scan"]  # type: ignore[assignment]
    return _ReportPlan(length, decode, ~owned, source, scan)


def _pressed_lines(terms: list[str], indent: str) -> list[str]:
    """`b = ` the buttons a report presses (from its integer `v`)."""
    if len(terms) <= 8:
        return [f"{indent}b = {' | '.join(terms) or '0'}"]
    # one statement per term: a long `a | b | ...` would nest too deep to compile
    return [f"{indent}b = 0", *(f"{indent}b |= {t}" for t in terms)]


def _scan_lines(terms: list[str], length: int) -> list[str]:
    """`scan(reports, mask, on_buttons) -> (last valid report, refused)`: the mask
    after every report, `on_buttons(mask)` where it changed (a press within a batch)."""
    return [
        "def scan(reports, mask, on_buttons):",
        "    last = None",
        "    refused = 0",
        "    for r in reports:",
        f"        if len(r) < {length}:",
        "            refused += 1",
        "            continue",
        "        last = r",
        "        v = int.from_bytes(r, 'little')",
        *_pressed_lines(terms, "        "),
        "        b |= mask & keep",  # the other reports' buttons (a namespace constant)
        "        if b != mask:",
        "            mask = b",
        "            on_buttons(b)",
        "    return last, refused",
    ]


_IdScanFn = Callable[[Sequence[bytes], int, Callable[[int], None]], tuple[dict[int, int], int]]


def _compile_id_scan(layout: DeviceLayout) -> _IdScanFn:
    """`scan(reports, mask, on_buttons) -> ({report ID: index of its last valid report},
    refused)` for a device with report IDs: one branch per ID on the first byte, its length
    checked and its buttons' expression inline, `on_buttons(mask)` where the mask changed
    (a press within a batch), as `_scan_lines` does for a device without IDs."""
    lines = [
        "def scan(reports, mask, on_buttons):",
        "    last = {}",
        "    refused = 0",
        "    i = -1",
        "    for r in reports:",
        "        i += 1",
        "        rid = r[0] if r else -1",
    ]
    namespace: dict[str, object] = {"_array_buttons": _array_buttons}
    for n, (rid, data_length) in enumerate(sorted(layout.input_report_lengths.items())):
        arrays_name = f"arrays_{rid}"
        namespace[arrays_name] = tuple(a for a in layout.button_arrays if a.report_id == rid)
        namespace[f"keep_{rid}"] = ~_owned_buttons(layout, rid)
        lines += [
            f"        {'if' if n == 0 else 'elif'} rid == {rid}:",
            f"            if len(r) < {data_length + 1}:",
            "                refused += 1",
            "                continue",
            "            v = int.from_bytes(r, 'little')",
            *_pressed_lines(_button_terms(layout, rid, arrays_name), "            "),
            f"            b |= mask & keep_{rid}",
        ]
    lines += [
        "        else:",
        "            refused += 1",
        "            continue",
        "        last[rid] = i",
        "        if b != mask:",
        "            mask = b",
        "            on_buttons(b)",
        "    return last, refused",
    ]
    source = "\n".join(lines) + "\n"
    exec(compile(source, "<usb2rc decode plan, report IDs>", "exec"), namespace)
    scan: _IdScanFn = namespace["scan"]  # type: ignore[assignment]
    return scan


def _c_plan(layout: DeviceLayout) -> Plan | None:
    c_loops = speedups.compiled()
    if c_loops is None:
        return None
    if layout.button_arrays or any(f.bit_size > C_FIELD_BITS for f in layout.inputs):
        return None
    if any(b.bit_size != 1 and b.count != 1 for b in layout.buttons):
        return None  # the parser makes one field per wide button; the C drain knows no other
    if any(b.bit_size > C_BUTTON_BITS for b in layout.buttons):
        return None  # a button wider than the C drain reads at once
    tops = [b.first_button - 1 + (b.count if b.bit_size == 1 else 1) for b in layout.buttons]
    if max(tops, default=0) > C_BUTTON_BITS:
        return None
    id_bits = 8 if layout.uses_report_ids else 0
    every = (1 << C_BUTTON_BITS) - 1
    reports = []
    for rid, data_length in sorted(layout.input_report_lengths.items()):
        fields = [
            (f.index, f.bit_offset + id_bits, f.bit_size, f.is_signed)
            for f in layout.inputs
            if f.report_id == rid
        ]
        buttons = [
            (b.bit_offset + id_bits, b.bit_size, b.count, b.first_button)
            for b in layout.buttons
            if b.report_id == rid
        ]
        keep = ~_owned_buttons(layout, rid) & every
        reports.append((rid, data_length + id_bits // 8, keep, fields, buttons))
    plan: Plan = c_loops.Plan(layout.uses_report_ids, reports)
    return plan


def _ignore(_mask: int) -> None:
    """`on_buttons` for a caller that does not ask for the masks."""


class ReportDecoder:
    """Decodes one device's raw input reports into an InputState. Not thread-safe: one reader
    thread feeds it and takes its states."""

    def __init__(self, layout: DeviceLayout, compiled: bool = True) -> None:
        """`compiled`: drain batches in C where the layout allows and the C drain is built
        (False: the Python path, as tests/test_speedups.py compares them)."""
        self.layout = layout
        self.reports = 0
        self.bad_reports = 0
        self._plans = layout.report_plans
        self._plan = None if layout.uses_report_ids else self._plans[0]
        self._id_scan = layout.id_scan if layout.uses_report_ids else None
        self._c_plan = layout.c_plan if compiled else None
        initial = layout.initial_state()
        self._values = list(initial.values)
        self._buttons = 0
        self._state: InputState | None = initial

    def feed(self, report: bytes) -> bool:
        """Take one raw input report (ID byte first when the device uses IDs). False, and
        counted in bad_reports, for an unknown report ID or a too short report."""
        plan = self._plan
        if plan is None:
            plan = self._plans.get(report[0]) if report else None
        if plan is None or len(report) < plan.length:
            self.bad_reports += 1
            return False
        pressed = plan.decode(report, self._values)
        self._buttons = (self._buttons & plan.keep_buttons) | pressed
        self._state = None
        self.reports += 1
        return True

    @property
    def buttons(self) -> int:
        """The current button mask (HID button n -> bit n-1), without building a state."""
        return self._buttons

    def feed_batch(
        self, reports: Sequence[bytes], on_buttons: Callable[[int], None] | None = None
    ) -> tuple[int, int]:
        """Take `reports` in order: the same state and counters as `feed` on each, but only
        the last valid report of each report ID is decoded. A report sets every field and
        every button its ID owns, so an earlier one of the same ID cannot show in the state;
        the survivors are decoded in the order of their last occurrence, so a button two IDs
        share ends as the latest report says. A reader drains ~20 reports a tick from a
        1 kHz device: this decodes one. Returns (accepted, refused).

        `on_buttons(mask)`: called with the button mask `feed` would have left after each
        accepted report that changed it, in order (its button bits only are computed, not
        its values), for a caller that must see every press, even one released within the
        batch."""
        if self._c_plan is not None:
            return self._c_drain(self._c_plan, reports, on_buttons)
        single = self._plan
        refused = 0
        if single is not None:
            if on_buttons is not None:
                last, refused = single.scan(reports, self._buttons, on_buttons)
            else:
                need = single.length
                last = None
                for report in reports:
                    if len(report) < need:
                        refused += 1
                    else:
                        last = report
            survivors = [last] if last is not None else []
        else:
            assert self._id_scan is not None  # a layout with report IDs
            last_of, refused = self._id_scan(reports, self._buttons, on_buttons or _ignore)
            # in the order of each ID's last occurrence
            survivors = [reports[i] for i in sorted(last_of.values())]
        for report in survivors:
            self.feed(report)
        accepted = len(reports) - refused
        self.reports += accepted - len(survivors)
        self.bad_reports += refused
        return accepted, refused

    def feed_presses(self, reports: list[bytes]) -> tuple[int, int, list[int]]:
        """`feed_batch`, and the buttons each accepted report pressed (its bits that were
        up before it), for every report that pressed one, in order: a pulled reader's
        press log (no tap lost, even one released within the batch). Returns (accepted,
        refused, pressed)."""
        if self._c_plan is not None:
            accepted, refused, mask, pressed = self._c_plan.drain(
                reports, self._values, self._buttons, True
            )
            self._took(accepted, refused, mask)
            return accepted, refused, pressed
        before = self._buttons
        masks: list[int] = []
        accepted, refused = self.feed_batch(reports, masks.append)
        pressed = []
        for mask in masks:
            if rising := mask & ~before:
                pressed.append(rising)
            before = mask
        return accepted, refused, pressed

    def _took(self, accepted: int, refused: int, mask: int) -> None:
        """The C drain's counts and mask (its values are already in `_values`)."""
        if accepted:
            self._buttons = mask
            self._state = None
        self.reports += accepted
        self.bad_reports += refused

    def _c_drain(
        self,
        plan: Plan,
        reports: Sequence[bytes],
        on_buttons: Callable[[int], None] | None,
    ) -> tuple[int, int]:
        """`feed_batch` in one C call: the same values, masks and counts."""
        batch = reports if isinstance(reports, list) else list(reports)
        accepted, refused, mask, changes = plan.drain(batch, self._values, self._buttons, False)
        if on_buttons is not None:
            for changed in changes:
                on_buttons(changed)
        self._took(accepted, refused, mask)
        return accepted, refused

    def state(self) -> InputState:
        """The current state merged over all report IDs."""
        state = self._state
        if state is None:
            state = self._state = InputState(tuple(self._values), self._buttons)
        return state
