"""What the line sessions publish of what their far ends said, for feedback (all immutable,
each replaced whole by its session's thread and read by the feedback worker without a lock):
`Downlink` (a C2-16B `>` frame from the far end, per Node-ID), `CrsfTelemetry`,
`MavlinkTelemetry`; `Telemetry` is any of them. What a device shows is `hid.outputs`'."""

from __future__ import annotations

from typing import NamedTuple

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
