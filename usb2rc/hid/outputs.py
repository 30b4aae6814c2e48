"""What a device's outputs are, as every stage sees them (all immutable): what a device can
show (`Capabilities`), what it should show (`OutputState`), the writes that show it
(`OutputWrite`: a HID output report through hidapi, or a USB control transfer through pyusb
for a vendor format the descriptor cannot say), and the driver that turns one into the other
(`OutputDriver`: built from the device's descriptor, `feedback.hid_outputs`, or a vendor
format, `feedback.vendor`). The device's reader writes them (`hid.reader.post_output`)."""

from __future__ import annotations

from typing import NamedTuple, Protocol

# The analog outputs a device may have, in the order a downlink frame's axes 1..8 drive
# them by default (docs/ICD.md "Downlink"). Each is 0.0 (rest) .. 1.0 (full), but the
# forces, which are -1.0 .. 1.0.
ANALOG_NAMES = (
    "rumble_strong",
    "rumble_weak",
    "force_x",
    "force_y",
    "brightness",
    "red",
    "green",
    "blue",
)
SIGNED_ANALOG = frozenset({"force_x", "force_y"})
# An analog output no source sets: brightness is full, so that a far end that sends zeros
# (or nothing) does not dim a display or a lightbar; everything else is off.
UNSET_VALUES = {"brightness": 1.0}


class OutputState(NamedTuple):
    """What one device should show. `indicators`: bit k on = indicator k lit. `analog`:
    (name, value) pairs from ANALOG_NAMES, absent = rest. `texts`: display lines."""

    indicators: int = 0
    analog: tuple[tuple[str, float], ...] = ()
    texts: tuple[str, ...] = ()

    def value(self, name: str) -> float:
        """An analog output's value; absent: its rest (UNSET_VALUES, else 0)."""
        return dict(self.analog).get(name, UNSET_VALUES.get(name, 0.0))


REST = OutputState()


class Capabilities(NamedTuple):
    """What a device can show: how many indicators (in their documented order), which
    analog outputs, how many text lines of how many characters."""

    indicators: int = 0
    indicator_names: tuple[str, ...] = ()  # one per indicator, e.g. "LED Num Lock", "fire"
    analog: tuple[str, ...] = ()
    text_lines: int = 0
    text_width: int = 0

    @property
    def any(self) -> bool:
        return bool(self.indicators or self.analog or self.text_lines)


class HidReport(NamedTuple):
    """An output report as hidapi's write() takes it: the report ID first (0 when the
    device has none)."""

    data: bytes


class UsbControl(NamedTuple):
    """A USB control transfer out (pyusb's `ctrl_transfer`)."""

    request_type: int  # bmRequestType
    request: int  # bRequest
    w_value: int
    w_index: int
    data: bytes = b""


OutputWrite = HidReport | UsbControl


class OutputDriver(Protocol):
    """A device's outputs: what it can show, and the writes that show a state. `writes`
    may return only what changed since `before` (None: everything, e.g. after a plug)."""

    @property
    def capabilities(self) -> Capabilities: ...

    def writes(self, state: OutputState, before: OutputState | None) -> tuple[OutputWrite, ...]: ...
