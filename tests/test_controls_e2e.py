"""The pilot's day with controls, black-box: a real daemon subprocess on replayed devices.

- MAVLink actions against a vehicle stand-in built on pymavlink (UDP on 127.0.0.1): it
  answers usb2rc's HEARTBEAT with its own (ArduPilot Copter or PX4) and each COMMAND_LONG
  with a COMMAND_ACK, and decodes what usb2rc sends: arm after its hold, a mode by name,
  no repeat on a held button, nothing while a node the output reads is in failsafe.
- Switches on a SUMD pty read by its decoder: a toggle flips once per press, a 3-position
  steps switch, the failsafe values on an unplug, and the positions kept across a replug
  and a SIGHUP reload.
"""

from __future__ import annotations

import os
import select
import signal
import time
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import (
    RELEASED,
    PtyLine,
    StickState,
    UdpLine,
    channels,
    install,
    of_type,
    run_daemon,
    timed_recording,
    wait_until,
)
from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.protocols.sumd import codec as sumd

ARDUCOPTER = (mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink2.MAV_TYPE_QUADROTOR)
PX4 = (mavlink2.MAV_AUTOPILOT_PX4, mavlink2.MAV_TYPE_QUADROTOR)


class Vehicle(UdpLine):
    """The vehicle's end of usb2rc's `udpout`: answers each GCS HEARTBEAT with its own and
    each COMMAND_LONG with COMMAND_ACK (MAV_RESULT_ACCEPTED), from the same socket."""

    def __init__(self, autopilot: int, vehicle_type: int) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.kind = (vehicle_type, autopilot)
        super().__init__()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not select.select([self.sock], [], [], 0.05)[0]:
                continue
            data, peer = self.sock.recvfrom(65535)
            messages = self.decoder.feed(data)
            for message in messages:
                self._answer(message, peer)
            with self._cond:
                self._received(time.monotonic(), data, messages)
                self._cond.notify_all()

    def _answer(self, message: Any, peer: Any) -> None:
        if message.get_type() == "HEARTBEAT":
            reply = self.mav.heartbeat_encode(*self.kind, 0, 0, mavlink2.MAV_STATE_STANDBY)
        elif message.get_type() == "COMMAND_LONG":
            reply = self.mav.command_ack_encode(message.command, mavlink2.MAV_RESULT_ACCEPTED)
        else:
            return
        self.sock.sendto(reply.pack(self.mav), peer)

    def commands(self) -> list[Any]:
        return of_type(self.frames(), "COMMAND_LONG")


def presses(*spans: tuple[float, float, int], until: float) -> str:
    """A T.16000M at rest whose HID button k is held over each (down, up, k), reporting
    every 50 ms until `until` s."""
    events = []
    for i in range(int(until / 0.05) + 1):
        at = i * 0.05
        held = sum(1 << (k - 1) for down, up, k in spans if down <= at < up)
        events.append((at, StickState(buttons=held)))
    return timed_recording(events)


ACTIONS = """
outputs:
  - protocol: mavlink
    port: {url}
    channels: [node0.x, node0.y, node1.x]
    actions:
      - {{button: node0.button2, do: arm}}
      - {{button: node0.button6, do: {{mode: {mode}}}}}
      - {{button: node0.button7, do: rtl}}
  - protocol: sumd
    port: {pty}
    channels: [node0.button6, node0.button7]
"""


@pytest.mark.slow  # a long journey: the fast suite keeps shorter ones of its kind
def test_actions_arm_with_hold_mode_by_name_once_and_nothing_in_failsafe(
    tmp_path: Path, replay_dir: Path
) -> None:
    """ArduPilot Copter (buttons pressed from 1.5 s on, once the stick is live even on a
    loaded machine): arm after button 2 was held 1 s; LOITER once though button 6 is
    held 2 s; then node 1 (a channel of the output) unplugs, and button 7 (rtl), pressed
    while it is in failsafe, sends nothing."""
    vehicle, line = Vehicle(*ARDUCOPTER), PtyLine("sumd")
    config = tmp_path / "actions.yaml"
    config.write_text(ACTIONS.format(url=vehicle.url, pty=line.path, mode="LOITER"))
    install(
        replay_dir / "a-stick.hid", presses((1.5, 3.1, 2), (3.5, 5.5, 6), (8.0, 8.6, 7), until=10.0)
    )
    install(replay_dir / "b-pedals.hid", presses(until=0.1))  # node 1, at rest
    daemon = run_daemon(tmp_path, vehicle.url, replay_dir, "--config", str(config))
    try:
        arm = vehicle.wait_for(lambda ms: of_type(ms, "COMMAND_LONG"))[0]
        assert (arm.command, arm.param1) == (mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        mode = vehicle.wait_for(lambda ms: of_type(ms, "COMMAND_LONG")[1:])[0]
        assert mode.command == mavlink2.MAV_CMD_DO_SET_MODE
        assert (mode.param1, mode.param2) == (1.0, 5.0)  # custom mode: Copter LOITER
        os.unlink(replay_dir / "b-pedals.hid")  # node 1 fails: the output is in failsafe
        vehicle.wait_for(lambda ms: channels(of_type(ms, "RC_CHANNELS_OVERRIDE")[-1]) == RELEASED)
        pressed = sumd.button_to_sumd(True)
        # button 6 released, then button 7 pressed and released (node 0 stays live: SUMD)
        line.wait_for(lambda fs: [f for f in fs if f.channels[1] == pressed], timeout=15)
        line.wait_for(lambda fs: fs[-1].channels[1] != pressed)
        assert [m.command for m in vehicle.commands()] == [
            mavlink2.MAV_CMD_COMPONENT_ARM_DISARM,
            mavlink2.MAV_CMD_DO_SET_MODE,
        ]  # each once (acked: no retry), and no rtl in failsafe
        assert "MAV_RESULT_ACCEPTED" in daemon.log()
    finally:
        daemon.stop()
        vehicle.close()
        line.close()


def test_a_px4_mode_by_name(tmp_path: Path, replay_dir: Path) -> None:
    """PX4: POSCTL is DO_SET_MODE with base mode 81, main mode 3 (pymavlink's PX4 table)."""
    vehicle, line = Vehicle(*PX4), PtyLine("sumd")
    config = tmp_path / "actions.yaml"
    config.write_text(ACTIONS.format(url=vehicle.url, pty=line.path, mode="POSCTL"))
    install(replay_dir / "a-stick.hid", presses((1.0, 2.0, 6), until=2.5))
    install(replay_dir / "b-pedals.hid", presses(until=0.1))
    daemon = run_daemon(tmp_path, vehicle.url, replay_dir, "--config", str(config))
    try:
        mode = vehicle.wait_for(lambda ms: of_type(ms, "COMMAND_LONG"))[0]
        assert mode.command == mavlink2.MAV_CMD_DO_SET_MODE
        assert (mode.param1, mode.param2, mode.param3) == (81.0, 3.0, 0.0)
    finally:
        daemon.stop()
        vehicle.close()
        line.close()


SWITCHES = """
switches:
  gear: {{toggle: node0.button3, failsafe: 0}}
  mode: {{steps: [node0.button4, node0.button5], positions: 3}}
outputs:
  - protocol: sumd
    port: {pty}
    rate_hz: {rate}
    channels: [node0.x, switch.gear, switch.mode]
"""
LOW, MID, HIGH = (sumd.axis_to_sumd(v) for v in (-32768, 0, 32767))


def switch_values(frames: list[Any]) -> list[tuple[bool, int, int]]:
    """(failsafe, gear, mode) of each SUMD frame, runs of the same collapsed."""
    runs: list[tuple[bool, int, int]] = []
    for frame in frames:
        now = (frame.failsafe, frame.channels[1], frame.channels[2])
        if not runs or runs[-1] != now:
            runs.append(now)
    return runs


def test_switches_on_sumd_flip_step_failsafe_and_survive_a_replug_and_a_reload(
    tmp_path: Path, replay_dir: Path
) -> None:
    """One press flips the toggle (and only once), two presses step the 3-position switch
    to the top; an unplug sends the failsafe values (gear's failsafe 0, mode held); the
    replugged stick and a SIGHUP reload find both where the pilot left them."""
    line = PtyLine("sumd")
    config = tmp_path / "switches.yaml"
    config.write_text(SWITCHES.format(pty=line.path, rate=100))
    stick = replay_dir / "a-stick.hid"
    install(stick, presses((1.5, 1.7, 3), (2.0, 2.2, 5), (2.5, 2.7, 5), until=3.0))
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        line.wait_for(lambda fs: (False, HIGH, HIGH) in switch_values(fs))
        assert switch_values(line.frames())[-3:] == [
            (False, HIGH, LOW),
            (False, HIGH, MID),
            (False, HIGH, HIGH),
        ]  # the toggle flipped once; the steps went up one a press
        assert (False, LOW, LOW) in switch_values(line.frames())  # it started low
        os.unlink(stick)
        line.wait_for(lambda fs: switch_values(fs)[-1] == (True, LOW, HIGH))
        install(stick, presses(until=0.5))  # replugged, at rest, no presses
        line.wait_for(lambda fs: switch_values(fs)[-1] == (False, HIGH, HIGH))
        config.write_text(SWITCHES.format(pty=line.path, rate=100) + "defaults: true\n")
        reloaded_at = len(daemon.log())
        daemon.signal(signal.SIGHUP)
        wait_until(lambda: "reloaded" in daemon.log()[reloaded_at:], "the reload")
        seen = len(line.frames())
        line.wait_for(lambda fs: len(fs) > seen + 20)
        assert set(switch_values(line.frames()[seen:])) == {(False, HIGH, HIGH)}
    finally:
        daemon.stop()
        line.close()
