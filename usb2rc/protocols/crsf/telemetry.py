"""CRSF telemetry as a line hears it, sans-IO: what the transmitter module reports (its link
statistics, and the receiver's and flight controller's sensors it passes on), folded into one
`usb2rc.feedback.model.CrsfTelemetry`.

The frames read (fields big-endian, as all of CRSF's; the layouts ExpressLRS's and
Betaflight's CRSF telemetry send):

- LINK_STATISTICS (0x14), `codec.LinkStatistics`: link quality = the uplink's (%); RSSI =
  the better uplink antenna's, as negative dBm (the wire carries -dBm as a positive byte; 0
  is no reading: a receiver without diversity may leave antenna 2 at 0, both 0 is unknown);
  SNR = the uplink's (dB).
- BATTERY_SENSOR (0x08): voltage uint16 in 0.1 V, current uint16 in 0.1 A, used capacity
  uint24 in mAh, remaining uint8 in %.
- FLIGHT_MODE (0x21): the flight controller's mode as a NUL-terminated string (all of the
  payload when it has no NUL); a character that is not printable reads as `?`.

The codec keeps the last two as `OtherFrame`s (as it does device info): `battery_of` and
`flight_mode_of` read them. A frame too short for its type is counted (`malformed`) and
ignored; a frame whose CRC failed never comes here (the decoder counts it).

`CrsfReports.take(frame, now)` folds each frame in: `value` is then one immutable
`CrsfTelemetry`, replaced whole (another thread reads it without a lock), its `at` the time
of the newest report.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from usb2rc.feedback.model import CrsfTelemetry
from usb2rc.protocols.crsf import codec

TYPE_BATTERY_SENSOR = 0x08
TYPE_FLIGHT_MODE = 0x21

_BATTERY = struct.Struct(">HHBHB")  # voltage, current, capacity (high byte, low 16 bits), %
DECI = 10  # voltage and current come in tenths


@dataclass(frozen=True, slots=True)
class BatterySensor:
    """A BATTERY_SENSOR frame's fields."""

    voltage_v: float
    current_a: float
    capacity_mah: int  # used so far
    remaining: int  # %


def battery_of(frame: codec.OtherFrame) -> BatterySensor | None:
    """The battery a BATTERY_SENSOR frame reports (None: too short)."""
    if len(frame.payload) < _BATTERY.size:
        return None
    voltage, current, capacity_high, capacity_low, remaining = _BATTERY.unpack_from(frame.payload)
    capacity = capacity_high << 16 | capacity_low
    return BatterySensor(voltage / DECI, current / DECI, capacity, remaining)


def flight_mode_of(frame: codec.OtherFrame) -> str:
    """A FLIGHT_MODE frame's text, up to its NUL."""
    text = frame.payload.split(b"\0", 1)[0].decode("utf-8", "replace")
    return "".join(char if char.isprintable() else "?" for char in text)


def encode_battery(
    voltage_dv: int,
    current_da: int,
    capacity_mah: int,
    remaining: int,
    address: int = codec.ADDRESS_RADIO,
) -> bytes:
    """A BATTERY_SENSOR frame (voltage and current in tenths), as a module passes it to the
    handset. Raises ValueError (struct.error's) when a field does not fit."""
    if not 0 <= capacity_mah <= 0xFFFFFF:
        raise ValueError(f"capacity must fit 24 bits, got {capacity_mah!r}")
    try:
        payload = _BATTERY.pack(
            voltage_dv, current_da, capacity_mah >> 16, capacity_mah & 0xFFFF, remaining
        )
    except struct.error as error:
        raise ValueError(f"battery sensor field out of range: {error}") from None
    return codec.encode_frame(address, TYPE_BATTERY_SENSOR, payload)


def encode_flight_mode(text: str, address: int = codec.ADDRESS_RADIO) -> bytes:
    """A FLIGHT_MODE frame: `text` (UTF-8) and its NUL."""
    return codec.encode_frame(address, TYPE_FLIGHT_MODE, text.encode("utf-8") + b"\0")


def better_rssi_dbm(link: codec.LinkStatistics) -> int | None:
    """The better uplink antenna's RSSI as negative dBm (None: neither has a reading)."""
    readings = [rssi for rssi in (link.uplink_rssi_1, link.uplink_rssi_2) if rssi > 0]
    return -min(readings) if readings else None


class CrsfReports:
    """The telemetry a CRSF line heard, one value (see the module docstring)."""

    def __init__(self) -> None:
        # Written by the line's thread only (`take`), read by the feedback worker.
        self.value: CrsfTelemetry | None = None
        self.link_statistics = 0
        self.battery = 0
        self.flight_mode = 0
        self.malformed = 0  # a battery frame too short for its fields

    def take(self, frame: codec.CrsfFrame, now: float) -> None:
        """One decoded frame from the line, received at `now` (other kinds are not telemetry)."""
        if isinstance(frame, codec.LinkStatistics):
            self.link_statistics += 1
            self._update(
                now,
                link_quality=frame.uplink_link_quality,
                rssi_dbm=better_rssi_dbm(frame),
                snr_db=frame.uplink_snr,
            )
        elif isinstance(frame, codec.OtherFrame) and frame.type == TYPE_BATTERY_SENSOR:
            battery = battery_of(frame)
            if battery is None:
                self.malformed += 1
                return
            self.battery += 1
            self._update(now, battery_v=battery.voltage_v, battery_remaining=battery.remaining)
        elif isinstance(frame, codec.OtherFrame) and frame.type == TYPE_FLIGHT_MODE:
            self.flight_mode += 1
            self._update(now, flight_mode=flight_mode_of(frame))

    def _update(self, now: float, **fields: Any) -> None:
        before = CrsfTelemetry() if self.value is None else self.value
        self.value = before._replace(at=now, **fields)

    def record(self) -> dict[str, int]:
        """The counts, for the stats record."""
        return {
            "module_rx_link_statistics": self.link_statistics,
            "module_rx_battery": self.battery,
            "module_rx_flight_mode": self.flight_mode,
            "module_rx_malformed": self.malformed,
        }
