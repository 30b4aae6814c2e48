"""The values feedback passes between its stages, all immutable.

- Telemetry, as each line session publishes it (one value replaced whole by the session's
  thread, read by the feedback worker without a lock): `Downlink` (a C2-16B `>` frame from
  the far end, per Node-ID), `CrsfTelemetry`, `MavlinkTelemetry`.
- `OutputState`: what one device should show now (indicators, analog outputs, text lines),
  the feedback engine's result per device.
- `Capabilities`: what a device can show, from its descriptor or its vendor format.
- `OutputWrite`: one write to a device, a HID output report (through hidapi) or a USB
  control transfer (through pyusb, for vendor formats the descriptor cannot say).
- `OutputDriver`: turns an `OutputState` into the writes that show it.
"""

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
INDICATOR_BITS = 64  # a downlink frame's two button groups, group 1's bit 0 first


class Downlink(NamedTuple):
    """A valid C2-16B data frame with status `>` from the far end, for Node-ID `node_id`:
    its 64 group bits (bit k = group 1's bit k for k < 32, group 2's bit k-32 above) and its
    10 signed 16-bit axes, and when it was received (the session's clock)."""

    node_id: int
    indicators: int
    axes: tuple[int, ...]
    at: float


class CrsfTelemetry(NamedTuple):
    """What a CRSF module (or receiver, through it) reported last; None: not heard yet."""

    link_quality: int | None = None  # uplink LQ, %
    rssi_dbm: int | None = None  # uplink RSSI of the better antenna, dBm (negative)
    snr_db: int | None = None  # uplink SNR, dB
    battery_v: float | None = None
    battery_remaining: int | None = None  # %
    flight_mode: str | None = None
    at: float = 0.0  # when the newest of these came (the session's clock)


class MavlinkTelemetry(NamedTuple):
    """What the vehicle said last; None: not heard yet."""

    armed: bool | None = None
    mode: str | None = None  # by name, as pymavlink's mode mapping gives it
    battery_v: float | None = None
    battery_remaining: int | None = None  # %
    failsafe: bool | None = None  # the vehicle's own RC or GCS failsafe is on
    at: float = 0.0


# What a line session publishes (`session.telemetry`): C2-16B the newest downlink frame per
# Node-ID (sorted by Node-ID), CRSF and MAVLink their telemetry; None: nothing heard.
Telemetry = tuple[Downlink, ...] | CrsfTelemetry | MavlinkTelemetry | None


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
