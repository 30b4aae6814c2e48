"""MAVLink button actions (usb2rc.protocols.mavlink.actions, in the MAVLink session;
docs/CONFIG.md "MAVLink actions"): hold, edge, no vehicle, failsafe, retries and acks, and
mode names for ArduPilot Copter and PX4, decoded with pymavlink."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.config.controls_model import ActionConfig
from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.configfile import ChannelRef, load_config_text
from usb2rc.protocols.mavlink.actions import TRIES
from usb2rc.protocols.mavlink.session import ControlValues, MavlinkEngine, stats_record

BUTTON = ChannelRef(0, "button", 2, "node0.button2")
COPTER = (mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink2.MAV_TYPE_QUADROTOR)
PX4 = (mavlink2.MAV_AUTOPILOT_PX4, mavlink2.MAV_TYPE_QUADROTOR)


class Vehicle:
    """A vehicle stand-in: packs its HEARTBEAT and COMMAND_ACKs, decodes what it gets."""

    def __init__(self, autopilot: int, vehicle_type: int) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.autopilot, self.vehicle_type = autopilot, vehicle_type
        self.parser = mavlink2.MAVLink(None)

    def heartbeat(self) -> bytes:
        message = self.mav.heartbeat_encode(self.vehicle_type, self.autopilot, 0, 0, 4)
        return bytes(message.pack(self.mav))

    def ack(self, command: int, result: int = mavlink2.MAV_RESULT_ACCEPTED) -> bytes:
        return bytes(self.mav.command_ack_encode(command, result).pack(self.mav))

    def commands(self, data: list[bytes]) -> list[Any]:
        messages = [m for chunk in data for m in self.parser.parse_buffer(chunk) or []]
        return [m for m in messages if m.get_type() == "COMMAND_LONG"]


def session(*actions: ActionConfig) -> MavlinkEngine:
    line = MavlinkEngine(MavlinkOptions(), actions=actions)
    line.line_opened()
    return line


def values(*triggers: bool, failsafe: bool = False) -> ControlValues:
    return ControlValues(failsafe, channels=(1500,), triggers=triggers)


def run(line: MavlinkEngine, ticks: list[tuple[float, ControlValues]]) -> list[bytes]:
    sent: list[bytes] = []
    for now, tick_values in ticks:
        sent += line.tick(now, tick_values)
    return sent


def test_arm_needs_its_hold_and_a_held_button_sends_once() -> None:
    vehicle = Vehicle(*COPTER)
    line = session(ActionConfig("arm", BUTTON, hold=1.0))
    line.received(vehicle.heartbeat())
    early = run(line, [(0.0, values(True)), (0.5, values(True)), (0.9, values(False))])
    assert vehicle.commands(early) == []  # released before the hold: nothing
    sent = run(line, [(1.0 + t / 10, values(True)) for t in range(10)])
    assert vehicle.commands(sent) == []  # 0.9 s held
    (arm,) = vehicle.commands(run(line, [(2.0, values(True))]))  # 1 s held
    assert (arm.command, arm.param1, arm.confirmation) == (400, 1.0, 0)
    assert (arm.target_system, arm.target_component) == (1, 1)
    line.received(vehicle.ack(400))
    still_held = [(2.0 + t / 10, values(True)) for t in range(1, 60)]
    assert vehicle.commands(run(line, still_held)) == []  # acked: no retry, no repeat
    assert line.actions is not None
    assert line.actions.record()["actions_acked"] == 1
    assert line.actions.record()["actions_last"].endswith("MAV_RESULT_ACCEPTED")


def test_retried_until_three_tries_without_an_ack() -> None:
    vehicle = Vehicle(*COPTER)
    line = session(ActionConfig("rtl", BUTTON))
    line.received(vehicle.heartbeat())
    sent = run(line, [(t * 0.25, values(t < 2)) for t in range(40)])
    commands = vehicle.commands(sent)
    assert [c.confirmation for c in commands] == list(range(TRIES))
    assert {c.command for c in commands} == {mavlink2.MAV_CMD_DO_SET_MODE}
    assert line.actions is not None and line.actions.stats.unanswered == 1


def test_nothing_before_the_vehicle_heartbeat_nor_in_failsafe() -> None:
    vehicle = Vehicle(*COPTER)
    line = session(ActionConfig("land", BUTTON))
    assert vehicle.commands(run(line, [(0.0, values(True))])) == []
    line.received(vehicle.heartbeat())
    assert vehicle.commands(run(line, [(0.1, values(True))])) == []  # held since: refused
    failsafe = [(0.2, values(False)), (0.3, values(True, failsafe=True)), (0.4, values(True))]
    assert vehicle.commands(run(line, failsafe)) == []  # held through it: not after it either
    assert len(vehicle.commands(run(line, [(0.5, values(False)), (0.6, values(True))]))) == 1
    assert line.actions is not None and line.actions.stats.refused == 1


@pytest.mark.parametrize(
    ("vehicle", "mode", "params"),
    [
        (COPTER, "LOITER", (1.0, 5.0, 0.0)),  # custom mode enabled, Copter LOITER = 5
        (COPTER, "ALT_HOLD", (1.0, 2.0, 0.0)),
        (PX4, "LOITER", (29.0, 4.0, 3.0)),  # PX4 AUTO.LOITER: main 4, sub 3
        (PX4, "POSCTL", (81.0, 3.0, 0.0)),
    ],
)
def test_a_mode_by_name(vehicle: tuple[int, int], mode: str, params: tuple[float, ...]) -> None:
    stand_in = Vehicle(*vehicle)
    line = session(ActionConfig("mode", BUTTON, mode=mode))
    line.received(stand_in.heartbeat())
    (command,) = stand_in.commands(run(line, [(0.0, values(True))]))
    assert command.command == mavlink2.MAV_CMD_DO_SET_MODE
    assert (command.param1, command.param2, command.param3) == params


def test_a_mode_the_vehicle_lacks_is_refused() -> None:
    stand_in = Vehicle(*PX4)
    line = session(ActionConfig("mode", BUTTON, mode="ALT_HOLD"))
    line.received(stand_in.heartbeat())
    assert stand_in.commands(run(line, [(0.0, values(True))])) == []
    assert line.actions is not None and "unknown" in line.actions.stats.last


def test_actions_in_the_config() -> None:
    config = load_config_text(
        """
switches:
  mode: {steps: [node0.button4, node0.button5], positions: 3}
outputs:
  - protocol: mavlink
    port: udpout:127.0.0.1:14550
    actions:
      - {button: node0.button2, do: arm}
      - {switch: mode, position: 2, do: {mode: LOITER}}
      - {button: node0.button7, do: {command_long: {command: 183, params: [9, 1500]}}}
"""
    )
    arm, mode, servo = config.outputs[0].option("actions")
    assert (arm.kind, arm.hold) == ("arm", 1.0)
    assert (mode.switch, mode.position, mode.mode, mode.hold) == ("mode", 2, "LOITER", 0.0)
    assert (servo.command, servo.params) == (183, (9.0, 1500.0))


def test_the_stats_line_shows_the_actions_and_the_last_result() -> None:
    from usb2rc.runtime.stats_text import output_line

    vehicle = Vehicle(*COPTER)
    line = session(ActionConfig("mode", BUTTON, mode="LOITER"))
    line.received(vehicle.heartbeat())
    run(line, [(0.0, values(True))])
    line.received(vehicle.ack(mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_RESULT_DENIED))
    record = {"name": "output 1", "url": "udpout:x", **stats_record(line)}
    text = output_line(record)
    assert "actions: fired 1, commands sent 1, acked 1, unanswered 0, refused 0" in text
    assert text.endswith("last: node0.button2: mode LOITER: MAV_RESULT_DENIED")


def test_mavutil_is_imported_only_for_an_output_that_names_a_mode() -> None:
    """pymavlink's mavutil (about 9 MB of RSS) is loaded for the mode maps only: never for a
    MAVLink output whose actions name no mode, and for one that does when it is built, not
    at the first press (that would be an import inside a tick)."""
    script = """
import sys
from usb2rc.config.controls_model import ActionConfig
from usb2rc.configfile import ChannelRef
from usb2rc.protocols.mavlink.actions import ActionRunner
import usb2rc.protocols.mavlink.session, usb2rc.wiring
button = ChannelRef(0, "button", 1, "node0.button1")
ActionRunner([ActionConfig("arm", button), ActionConfig("command_long", button)], None, (1, 1))
print("pymavlink.mavutil" in sys.modules)
ActionRunner([ActionConfig("rtl", button)], None, (1, 1))
print("pymavlink.mavutil" in sys.modules)
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=60
    ).stdout.split()
    assert out == ["False", "True"]
