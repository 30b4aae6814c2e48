"""The vehicle's state as a MAVLink output hears it, sans-IO: what the autopilot says, folded
into one `usb2rc.feedback.model.MavlinkTelemetry`. pymavlink parses every message
(`codec.MavlinkDecoder`) and names every mode; nothing here reads bytes.

The vehicle is the autopilot component: a HEARTBEAT whose type is not MAV_TYPE_GCS and whose
autopilot is not MAV_AUTOPILOT_INVALID (what ground stations, usb2rc's own heartbeats echoed
back, cameras, gimbals and companion computers send), from the output's `target_system` and
`target_component` (0: any). The first such sender is the vehicle until it has been silent
for VEHICLE_LOST_S; meanwhile another's messages are ignored and counted, so one vehicle's
battery is never shown beside another's armed state.

What is read, from the vehicle only:
- HEARTBEAT: armed = base_mode's MAV_MODE_FLAG_SAFETY_ARMED; the mode by name, by pymavlink's
  own mapping (`mavutil.mode_string_v10`: ArduPilot's custom mode by vehicle type, PX4's main
  and sub mode); an autopilot that is neither has no mapping: mode None. The failsafe: see
  below.
- SYS_STATUS: voltage_battery (mV; UINT16_MAX: not sent) in V, battery_remaining (%; -1:
  unknown).
- BATTERY_STATUS of battery 0 (the primary): the sum of its cells' voltages (mV; UINT16_MAX
  in `voltages`, 0 or UINT16_MAX in `voltages_ext`: no such cell; a battery whose cells are
  not measured gives its whole voltage in cell 0, so the sum is it), battery_remaining.
  The newer of SYS_STATUS and BATTERY_STATUS gives the battery.

Decision, the failsafe: `failsafe` is True while the vehicle's HEARTBEAT system_status is
MAV_STATE_CRITICAL or MAV_STATE_EMERGENCY. It is what both autopilots report, in the one
message both send: ArduPilot's Copter, Plane and Rover give MAV_STATE_CRITICAL while any of
their failsafes is triggered (radio, GCS, battery, EKF...), Plane MAV_STATE_EMERGENCY once
crashed; PX4 gives MAV_STATE_CRITICAL while armed with a failsafe active and
MAV_STATE_EMERGENCY landing after an engine failure. So it covers every failsafe, not only
the RC and GCS ones (neither autopilot says which in a message both send), and on PX4 only
while armed. MAV_STATE_FLIGHT_TERMINATION does not count: PX4 also reports it for the
pilot's own kill switch.

`VehicleTelemetry.take(message, now)` folds each message in: `value` is one immutable
`MavlinkTelemetry`, replaced whole (another thread reads it without a lock), its `at` the
time of the vehicle's newest message read.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.feedback.model import MavlinkTelemetry
from usb2rc.protocols.mavlink.actions import mode_maps

VEHICLE_LOST_S = 3.0  # a vehicle silent this long may be replaced by another
FAILSAFE_STATES = frozenset({mavlink2.MAV_STATE_CRITICAL, mavlink2.MAV_STATE_EMERGENCY})
MAPPED_AUTOPILOTS = frozenset({mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink2.MAV_AUTOPILOT_PX4})
NO_CELL = 0xFFFF  # UINT16_MAX: a cell or voltage not sent
UNKNOWN_REMAINING = -1
PRIMARY_BATTERY = 0
MV_PER_V = 1000


def is_vehicle_heartbeat(message: Any) -> bool:
    """A HEARTBEAT from an autopilot, not from a ground station or another component."""
    return bool(
        message.get_type() == "HEARTBEAT"
        and message.type != mavlink2.MAV_TYPE_GCS
        and message.autopilot != mavlink2.MAV_AUTOPILOT_INVALID
    )


def mode_name(heartbeat: Any) -> str | None:
    """The vehicle's mode by pymavlink's name for it (None: an autopilot without a mapping)."""
    if heartbeat.autopilot not in MAPPED_AUTOPILOTS:
        return None
    name: str = mode_maps().mode_string_v10(heartbeat)
    return name


def battery_status_volts(message: Any) -> float | None:
    """BATTERY_STATUS's voltage: the sum of the cells it sends (None: none)."""
    cells = [mv for mv in message.voltages if mv != NO_CELL]
    cells += [mv for mv in getattr(message, "voltages_ext", ()) if mv not in (0, NO_CELL)]
    return sum(cells) / MV_PER_V if cells else None


class VehicleTelemetry:
    """What the vehicle said last, one value (see the module docstring)."""

    def __init__(self, target_system: int = 0, target_component: int = 0) -> None:
        self.target = (target_system, target_component)
        # Written by the line's thread only (`take`), read by the feedback worker.
        self.value: MavlinkTelemetry | None = None
        self.vehicle: tuple[int, int] | None = None  # (system, component)
        self.heartbeats = 0  # the vehicle's
        self.sys_status = 0
        self.battery_status = 0
        self.others = 0  # another vehicle's heartbeats, while this one is heard
        self._heard_at = 0.0  # the vehicle's last heartbeat
        mode_maps()  # pymavlink's mode maps, loaded now: never on the line's thread's read

    def take(self, message: Any, now: float) -> None:
        """One message from the far end, received at `now`."""
        kind = message.get_type()
        if kind == "HEARTBEAT":
            if is_vehicle_heartbeat(message) and self._adopt(message, now):
                self._heartbeat(message, now)
            return
        if (message.get_srcSystem(), message.get_srcComponent()) != self.vehicle:
            return  # not the vehicle's: another vehicle's, a camera's, a ground station's
        if kind == "SYS_STATUS":
            self.sys_status += 1
            voltage = message.voltage_battery
            self._battery(now, None if voltage == NO_CELL else voltage / MV_PER_V, message)
        elif kind == "BATTERY_STATUS" and message.id == PRIMARY_BATTERY:
            self.battery_status += 1
            self._battery(now, battery_status_volts(message), message)

    def _battery(self, now: float, volts: float | None, message: Any) -> None:
        percent = message.battery_remaining
        known = None if percent == UNKNOWN_REMAINING else percent
        self._update(now, battery_v=volts, battery_remaining=known)

    def _adopt(self, heartbeat: Any, now: float) -> bool:
        """Whether this vehicle heartbeat is the vehicle's: from the target, and the vehicle
        heard before, or none heard for VEHICLE_LOST_S (it becomes the vehicle)."""
        sender = (heartbeat.get_srcSystem(), heartbeat.get_srcComponent())
        if any(wanted not in (0, got) for wanted, got in zip(self.target, sender, strict=True)):
            return False
        if self.vehicle not in (None, sender) and now - self._heard_at < VEHICLE_LOST_S:
            self.others += 1
            return False
        self.vehicle, self._heard_at = sender, now
        return True

    def _heartbeat(self, heartbeat: Any, now: float) -> None:
        self.heartbeats += 1
        self._update(
            now,
            armed=bool(heartbeat.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED),
            mode=mode_name(heartbeat),
            failsafe=heartbeat.system_status in FAILSAFE_STATES,
        )

    def _update(self, now: float, **fields: Any) -> None:
        before = MavlinkTelemetry() if self.value is None else self.value
        self.value = before._replace(at=now, **fields)

    def record(self) -> dict[str, Any]:
        """The counts, for the stats record."""
        record: dict[str, Any] = {
            "vehicle_heartbeats": self.heartbeats,
            "vehicle_sys_status": self.sys_status,
            "vehicle_battery_status": self.battery_status,
            "other_vehicle_heartbeats": self.others,
        }
        if self.vehicle is not None:
            record["vehicle"] = "{}/{}".format(*self.vehicle)
        return record
