"""The daemon's log when a device is plugged names the channels that read an axis slot no
device of its node feeds (issue 39's point 7, as `check --replay DIR` does before): a CRSF
output reading node0.z on a T.16000M, which has no Z."""

from __future__ import annotations

from pathlib import Path

from daemon_harness import DaemonProcess, PtyLine, StickState, install, recording, wait_until

CONFIG = """outputs:
  - protocol: crsf
    port: {pty}
    channels: [node0.x, node0.y, node0.z, node0.rz]
"""


def test_a_plugged_stick_without_z_gets_a_warning_for_the_channel_reading_z(
    tmp_path: Path, replay_dir: Path
) -> None:
    line = PtyLine("crsf")
    config = tmp_path / "crsf.yaml"
    config.write_text(CONFIG.format(pty=line.path))
    daemon = DaemonProcess(
        ["--replay", str(replay_dir), "--config", str(config), "--status-socket", "off"],
        tmp_path / "daemon.log",
    )
    try:
        wait_until(
            lambda: "waiting for one to be plugged" in daemon.log(), "the daemon's start", 30
        )
        assert "reads axis z" not in daemon.log()  # nothing plugged: nothing to say yet
        install(replay_dir / "stick.hid", recording([StickState()] * 5))
        warning = "node0.z reads axis z of node 0, which no device of node 0 feeds"
        wait_until(lambda: warning in daemon.log(), "the warning at the plug", 30)
        text = daemon.log()
        assert "crsf.yaml:4: outputs[0].channels[2]" in text
        assert "Thrustmaster T.16000M (044f:b10a) has axes x, y, slider, rz" in text
        assert text.count(warning) == 1  # once per plug
        assert "node0.x reads" not in text and "node0.rz reads" not in text
    finally:
        daemon.stop()
        line.close()
