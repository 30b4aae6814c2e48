"""An idle daemon (C2-16B, no device) sleeps until something happens, and whatever happens
is answered as before: the far end's poll, a device plugged, an unplug (docs/DESIGN.md
"feedback/ ..." and lines/driver.py `DriverThread._doze`). Black-box: the real daemon on a
pty, a replay folder for the plugs."""

from __future__ import annotations

from pathlib import Path

from daemon_harness import (
    PtyLine,
    StickState,
    data_frames,
    install,
    recording,
    run_daemon,
    services,
    stats_until,
)

from usb2rc.protocols.c2_16b import codec as c2_16b

LIVE = c2_16b.LIVE


def test_an_idle_daemon_answers_a_poll_and_wakes_for_a_plug(
    tmp_path: Path, replay_dir: Path, line: PtyLine
) -> None:
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda f: any(isinstance(x, c2_16b.ServiceFrame) for x in f))
        # asleep now (no node): the stats say the drivers' thread dozed
        stats_until(daemon, r"asleep \(nothing to send\) [1-9]")
        line.send(c2_16b.poll_request(5))
        line.wait_for(lambda f: "disconnected" in services(f, 5))
        stick = StickState(x=3000)
        install(replay_dir / "stick.hid", recording([StickState(), stick], hold_s=30.0))
        line.wait_for(lambda f: (own := data_frames(f, 0)) and own[-1].status == LIVE)
        frames_before = len(data_frames(line.frames(), 0))
        line.wait_for(lambda f: len(data_frames(f, 0)) >= frames_before + 50)
        (replay_dir / "stick.hid").unlink()
        line.wait_for(lambda f: "disconnected" in services(f, 0))
    finally:
        assert daemon.stop() == 0, daemon.log()[-3000:]
