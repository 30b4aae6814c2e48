"""The daemon with MAVLink outputs (UDP and a pty) over two replayed devices; the far ends
parse the stream with pymavlink, as an autopilot or a GCS would, and check the values
against the replayed reports (docs/ICD.md, "MAVLink output"): the scaling is recomputed
here from the recordings, not taken from usb2rc. An unplug shows the failsafe (override:
every channel released, then silence but heartbeats; manual_control: silence but
heartbeats), a replug brings the values back."""

from __future__ import annotations

import os
import signal
import socket
import time
from fractions import Fraction
from typing import Any

from daemon_harness import (
    RELEASED,
    PtyLine,
    StickState,
    UdpLine,
    channels,
    install,
    of_type,
    pwm_of_int16,
    recording,
    run_daemon,
    scale,
)


def pwm(raw: int, lo: int, hi: int) -> int:
    """A raw HID value onto 1000..2000 µs: the ICD's int16 scaling, then linear onto µs."""
    return pwm_of_int16(scale(raw, lo, hi))


def manual(raw: int, lo: int, hi: int) -> int:
    """A raw HID value onto MANUAL_CONTROL's -1000..1000 (each half on its own)."""
    v = scale(raw, lo, hi)
    return round(Fraction(v * 1000, 32768 if v < 0 else 32767))


CONFIG = """
outputs:
  - protocol: mavlink
    port: {udp}
    channels: [node0.x, node1.y, node1.slider, node0.rz, node0.button1, node1.button2]
  - protocol: mavlink
    port: {pty}
    message: manual_control
    target_system: 7
    channels: [node0.y, node0.x, node1.slider, node0.rz, node0.button1, node1.button2]
"""

CENTRED = StickState()  # plugged at rest first: the neutral guard (docs/ICD.md)
STICK = StickState(x=0, y=12000, rz=255, slider=0, buttons=0b01)
THROTTLE = StickState(x=16383, y=4000, rz=0, slider=200, buttons=0b10)


def test_udp_and_pty_mavlink_outputs_two_devices_unplug_and_replug(tmp_path, replay_dir):
    udp, pty = UdpLine(), PtyLine("mavlink")
    config = tmp_path / "mavlink.yaml"
    config.write_text(CONFIG.format(udp=udp.url, pty=pty.path))
    stick, throttle = replay_dir / "a-stick.hid", replay_dir / "b-throttle.hid"
    install(stick, recording([CENTRED, STICK]))  # node 0 (port-path order)
    install(throttle, recording([CENTRED, THROTTLE]))  # node 1
    override = [
        pwm(STICK.x, 0, 16383),
        pwm(THROTTLE.y, 0, 16383),
        pwm(THROTTLE.slider, 0, 255),
        pwm(STICK.rz, 0, 255),
        2000,  # node 0 button 1 pressed
        2000,  # node 1 button 2 pressed
    ] + [65535] * 12  # not configured: ignored
    axes = (
        manual(STICK.y, 0, 16383),
        manual(STICK.x, 0, 16383),
        round(Fraction(scale(THROTTLE.slider, 0, 255) + 32768, 65535) * 1000),  # z: 0..1000
        manual(STICK.rz, 0, 255),
    )
    daemon = run_daemon(tmp_path, udp.url, replay_dir, "--config", str(config))
    try:
        live = udp.wait_for(
            lambda ms: [m for m in of_type(ms, "RC_CHANNELS_OVERRIDE") if channels(m) == override]
        )[-1]
        assert (live.target_system, live.target_component) == (1, 1)
        assert (live.get_srcSystem(), live.get_srcComponent()) == (255, 190)
        beat = of_type(udp.frames(), "HEARTBEAT")[0]
        assert (beat.type, beat.autopilot) == (6, 8)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID

        def manual_live(ms: list[Any]) -> list[Any]:
            return [
                m
                for m in of_type(ms, "MANUAL_CONTROL")
                if (m.x, m.y, m.z, m.r) == axes and m.buttons == 0b11
            ]

        assert pty.wait_for(manual_live)[-1].target == 7

        os.unlink(stick)  # node 0 fails: both messages stop carrying values
        udp.wait_for(lambda ms: channels(of_type(ms, "RC_CHANNELS_OVERRIDE")[-1]) == RELEASED)
        unplugged_at = len(pty.frames())
        # the release goes on for 1 s, then only heartbeats (at least two: 1 Hz)
        udp.wait_for(lambda ms: len(of_type(ms[-3:], "HEARTBEAT")) == 3, timeout=10)
        pty.wait_for(lambda ms: len(of_type(ms[unplugged_at:], "HEARTBEAT")) >= 2)
        after = [m.get_type() for m in pty.frames()[unplugged_at:]]
        first = after.index("HEARTBEAT")
        second = after.index("HEARTBEAT", first + 1)
        assert "MANUAL_CONTROL" not in after[first:second]  # a whole second without one
        assert udp.decoder.bad == 0 and pty.decoder.bad == 0

        install(stick, recording([CENTRED, STICK]))  # replug: values again
        seen = len(udp.frames())
        udp.wait_for(
            lambda ms: any(
                channels(m) == override for m in of_type(ms[seen:], "RC_CHANNELS_OVERRIDE")
            )
        )
        seen = len(pty.frames())
        pty.wait_for(lambda ms: manual_live(ms[seen:]))
    finally:
        assert daemon.stop() == 0
        udp.close()
        pty.close()


def test_udpin_answers_the_vehicle_that_called_and_counts_its_heartbeats(tmp_path, replay_dir):
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    url = f"udpin:127.0.0.1:{port}"
    config = tmp_path / "udpin.yaml"
    config.write_text(f"outputs:\n  - protocol: mavlink\n    port: {url}\n")
    vehicle = UdpLine()  # the autopilot: it calls first, then listens on the same socket
    daemon = run_daemon(tmp_path, url, replay_dir, "--config", str(config))
    try:
        from pymavlink.dialects.v20 import common

        mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
        beat = mav.heartbeat_encode(
            common.MAV_TYPE_QUADROTOR, common.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4
        ).pack(mav)
        deadline = time.monotonic() + 10
        while not of_type(vehicle.frames(), "HEARTBEAT"):  # the daemon binds first
            assert time.monotonic() < deadline, "no answer to the vehicle's heartbeats"
            vehicle.sock.sendto(beat, ("127.0.0.1", port))
            time.sleep(0.1)
        # Plugged once the link is up (the node step arms the stick at rest whether or not
        # the output ticks: docs/ICD.md, "Neutral guard"; tests/test_node_step.py).
        install(replay_dir / "stick.hid", recording([CENTRED, STICK]))
        x = pwm(STICK.x, 0, 16383)  # the default list: node 0's x, y, z, rz, ...
        vehicle.wait_for(lambda ms: channels(of_type(ms, "RC_CHANNELS_OVERRIDE")[-1])[0] == x)
        daemon.signal(signal.SIGUSR1)
        deadline = time.monotonic() + 10
        while "far end: messages" not in daemon.log():
            assert time.monotonic() < deadline, daemon.log()
            time.sleep(0.05)
        assert "(last from 1/1)" in daemon.log()
    finally:
        assert daemon.stop() == 0
        vehicle.close()
