"""MAVLink telemetry (`MavlinkSession.telemetry`): messages packed by real pymavlink as
ArduPilot and PX4 send them (HEARTBEAT, SYS_STATUS, BATTERY_STATUS) become the right
`MavlinkTelemetry`, from the vehicle only: usb2rc's own GCS heartbeat echoed back, another
ground station, a camera or a second vehicle are not it. The expected mode names are the
autopilots' own (ArduCopter's mode 5 is LOITER; PX4's main mode 3 is POSCTL)."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.feedback.model import MavlinkTelemetry
from usb2rc.nodes.table import NodeSnapshot
from usb2rc.protocols.mavlink.session import (
    MavlinkChannels,
    MavlinkEngine,
    MavlinkSession,
    heartbeat_bytes,
    max_message_bytes,
)
from usb2rc.protocols.mavlink.telemetry import VEHICLE_LOST_S

ARMED = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
DISARMED = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
ARDUPILOT = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
PX4 = mavlink2.MAV_AUTOPILOT_PX4
NO_CELL = 65535


def session(**options: Any) -> MavlinkSession:
    tick_bytes = heartbeat_bytes() + max_message_bytes("rc_channels_override")
    engine = MavlinkEngine(MavlinkOptions(**options))
    line = MavlinkSession("mavlink", MavlinkChannels([]), engine, tick_bytes, 50.0)
    line.line_opened()
    return line


def sender(system: int = 1, component: int = 1) -> Any:
    return mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)


def packed(mav: Any, message: Any) -> bytes:
    """A message as pymavlink puts it on the wire."""
    data: bytes = message.pack(mav)
    return data


def heartbeat(
    mav: Any,
    autopilot: int = ARDUPILOT,
    vehicle_type: int = mavlink2.MAV_TYPE_QUADROTOR,
    base_mode: int = DISARMED,
    custom_mode: int = 0,
    state: int = mavlink2.MAV_STATE_STANDBY,
) -> bytes:
    return packed(mav, mav.heartbeat_encode(vehicle_type, autopilot, base_mode, custom_mode, state))


def sys_status(mav: Any, voltage_mv: int, remaining: int) -> bytes:
    message = mav.sys_status_encode(0, 0, 0, 500, voltage_mv, 1200, remaining, 0, 0, 0, 0, 0, 0)
    return packed(mav, message)


def battery_status(
    mav: Any, cells: list[int], remaining: int, battery_id: int = 0, ext: list[int] | None = None
) -> bytes:
    voltages = cells + [NO_CELL] * (10 - len(cells))
    message = mav.battery_status_encode(
        battery_id, 0, 0, 2500, voltages, 1000, 100, -1, remaining, voltages_ext=ext or [0] * 4
    )
    return packed(mav, message)


def px4_mode(main: int, sub: int = 0) -> int:
    return main << 16 | sub << 24  # px4_custom_mode: main mode in byte 2, sub mode in byte 3


def test_an_arducopter_heartbeat_gives_armed_and_its_mode_by_name() -> None:
    line = session()
    assert line.telemetry is None  # nothing heard yet
    line.received(heartbeat(sender(), base_mode=ARMED, custom_mode=5), now=4.0)
    assert line.telemetry == MavlinkTelemetry(armed=True, mode="LOITER", failsafe=False, at=4.0)
    line.received(heartbeat(sender(), custom_mode=6), now=5.0)  # disarmed, RTL
    assert line.telemetry == MavlinkTelemetry(armed=False, mode="RTL", failsafe=False, at=5.0)


def test_an_arduplane_names_its_modes_by_its_own_mapping() -> None:
    line = session()
    line.received(heartbeat(sender(), vehicle_type=mavlink2.MAV_TYPE_FIXED_WING, custom_mode=10), 1)
    assert line.telemetry is not None and line.telemetry.mode == "AUTO"  # Copter's 10 is not


def test_an_arducopter_in_failsafe_says_critical() -> None:
    line = session()
    critical = mavlink2.MAV_STATE_CRITICAL
    line.received(heartbeat(sender(), base_mode=ARMED, custom_mode=6, state=critical), now=2.0)
    assert line.telemetry == MavlinkTelemetry(armed=True, mode="RTL", failsafe=True, at=2.0)


def test_px4_heartbeats_give_its_main_and_sub_modes_and_its_failsafe() -> None:
    line = session()
    line.received(heartbeat(sender(), PX4, base_mode=ARMED, custom_mode=px4_mode(3)), now=1.0)
    assert line.telemetry == MavlinkTelemetry(armed=True, mode="POSCTL", failsafe=False, at=1.0)
    state = mavlink2.MAV_STATE_CRITICAL  # armed with a failsafe active
    line.received(
        heartbeat(sender(), PX4, base_mode=ARMED, custom_mode=px4_mode(4, 5), state=state), 2.0
    )
    assert line.telemetry == MavlinkTelemetry(armed=True, mode="RTL", failsafe=True, at=2.0)
    state = mavlink2.MAV_STATE_FLIGHT_TERMINATION  # the pilot's kill switch, too
    line.received(
        heartbeat(sender(), PX4, base_mode=ARMED, custom_mode=px4_mode(3), state=state), 3.0
    )
    assert line.telemetry is not None and line.telemetry.failsafe is False


def test_an_autopilot_without_a_mode_mapping_has_no_mode() -> None:
    line = session()
    line.received(heartbeat(sender(), mavlink2.MAV_AUTOPILOT_GENERIC, base_mode=ARMED), now=1.0)
    assert line.telemetry == MavlinkTelemetry(armed=True, mode=None, failsafe=False, at=1.0)


def test_sys_status_gives_the_battery_and_says_what_is_unknown() -> None:
    line = session()
    vehicle = sender()
    line.received(heartbeat(vehicle) + sys_status(vehicle, 12600, 80), now=1.0)
    assert line.telemetry is not None
    assert (line.telemetry.battery_v, line.telemetry.battery_remaining) == (12.6, 80)
    line.received(sys_status(vehicle, NO_CELL, -1), now=2.0)
    assert line.telemetry == MavlinkTelemetry(False, "STABILIZE", None, None, False, 2.0)


def test_battery_status_gives_the_primary_batterys_cells_summed() -> None:
    line = session()
    vehicle = sender()
    line.received(heartbeat(vehicle), now=1.0)
    line.received(battery_status(vehicle, [4200, 4150, 4100], 64), now=2.0)
    assert line.telemetry is not None
    assert (line.telemetry.battery_v, line.telemetry.battery_remaining) == (12.45, 64)
    line.received(battery_status(vehicle, [3000], 10, battery_id=1), now=3.0)  # not the primary
    assert line.telemetry.at == 2.0
    twelve_cells = [4000] * 10
    line.received(battery_status(vehicle, twelve_cells, -1, ext=[3900, 3900, 0, 0]), now=4.0)
    assert line.telemetry is not None
    assert (line.telemetry.battery_v, line.telemetry.battery_remaining) == (47.8, None)
    stats = line.stats(4.0)
    assert stats["vehicle_battery_status"] == 2 and stats["vehicle"] == "1/1"


def test_our_own_gcs_heartbeat_echoed_back_is_not_the_vehicle() -> None:
    line = session()
    out = line.tick(0.0, NodeSnapshot(period=0, at=0.0, nodes=()))
    assert out != b"" and line.engine.heartbeats == 1  # what usb2rc sent: its GCS heartbeat
    line.received(out, now=0.1)
    assert line.telemetry is None
    assert line.stats(0.1)["far_end_heartbeats"] == 1  # heard, and not taken for the vehicle


def test_other_ground_stations_cameras_and_their_reports_are_not_the_vehicle() -> None:
    line = session(target_system=0, target_component=0)  # any system, any component
    gcs, camera = sender(255, 190), sender(1, mavlink2.MAV_COMP_ID_CAMERA)
    gcs_beat = heartbeat(gcs, mavlink2.MAV_AUTOPILOT_INVALID, mavlink2.MAV_TYPE_GCS)
    camera_beat = heartbeat(camera, mavlink2.MAV_AUTOPILOT_INVALID, mavlink2.MAV_TYPE_CAMERA)
    line.received(gcs_beat + camera_beat + sys_status(gcs, 11000, 5), now=1.0)
    assert line.telemetry is None
    line.received(heartbeat(sender(), base_mode=ARMED) + sys_status(camera, 9000, 1), now=2.0)
    assert line.telemetry is not None and line.telemetry.battery_v is None


def test_a_vehicle_outside_the_target_system_is_not_the_vehicle() -> None:
    line = session(target_system=1)
    line.received(heartbeat(sender(system=2), base_mode=ARMED), now=1.0)
    assert line.telemetry is None


def test_a_second_vehicle_is_ignored_until_the_first_has_been_silent() -> None:
    line = session(target_system=0, target_component=0)
    first, second = sender(1), sender(2)
    line.received(heartbeat(first, custom_mode=5), now=1.0)
    line.received(heartbeat(second, base_mode=ARMED) + sys_status(second, 16000, 90), now=2.0)
    assert line.telemetry == MavlinkTelemetry(False, "LOITER", None, None, False, at=1.0)
    assert line.stats(2.0)["other_vehicle_heartbeats"] == 1
    line.received(heartbeat(second, base_mode=ARMED), now=1.0 + VEHICLE_LOST_S)
    assert line.telemetry is not None and line.telemetry.armed is True
    assert line.stats(5.0)["vehicle"] == "2/1"


def test_the_mode_maps_load_no_dialect_but_common_and_leave_the_environment_as_it_was() -> None:
    """pymavlink's mavutil, imported for its mode maps, would load the `all` dialect (9 MB
    of RSS on a Pi) and curses: in a fresh process, after `mode_maps()`, only `common` is
    loaded (and v10's empty package), no curses, the names still come out, MAVLINK20 /
    MAVLINK_DIALECT are unset again, and `sys.modules` holds no block left behind (curses
    imports after it)."""
    import subprocess
    import sys

    code = (
        "import os, sys\n"
        "from usb2rc.protocols.mavlink.actions import mode_maps\n"
        "m = mode_maps()\n"
        "dialects = sorted(n for n in sys.modules if n.startswith('pymavlink.dialects.v'))\n"
        "print(dialects, m.mavlink.__name__, os.environ.get('MAVLINK20'),"
        " os.environ.get('MAVLINK_DIALECT'), m.mode_mapping_acm[5])\n"
        "print(sorted(n for n in sys.modules if 'curses' in n), None in sys.modules.values())\n"
        "import curses.ascii\n"
        "print(curses.ascii.isprint('a'))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    ).stdout.strip()
    assert out.splitlines() == [
        "['pymavlink.dialects.v10', 'pymavlink.dialects.v20', 'pymavlink.dialects.v20.common'] "
        "pymavlink.dialects.v20.common None None LOITER",
        "[] False",
        "True",
    ]
