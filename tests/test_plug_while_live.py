"""Plugging five devices while a stick is live: the stick's frames go on, in every tick.

The daemon runs as a subprocess on a pty with a 1 kHz stick; five more devices (real
descriptors) are plugged one after another, each once the last one's connect sequence is on
the line. No timing is asserted (bench/bench_daemon.py measures the intervals): only that
the stick stays live, its message codes run on without a hole, every tick that carried
another node carried the stick too, and each device's connect sequence comes in plug order.
If this test's own reader fell behind and the daemon left bytes out (its stats say so), the
hole and tick checks are skipped: a full pty drops frames by design.
"""

from __future__ import annotations

import itertools
import re
import signal
import time
from pathlib import Path

import pytest
from daemon_harness import (
    DaemonProcess,
    PtyLine,
    StickState,
    data_frames,
    install,
    real_device_recordings,
    recording,
    run_daemon,
    service_frames,
)

from usb2rc.protocols.c2_16b import codec as c2_16b

pytestmark = pytest.mark.slow

PLUGGED = 5
# Room for every node and connect sequence in each tick: no round-robin deferral.
CONFIG = "outputs:\n  - protocol: c2-16b\n    baudrate: 921600\n"
LOSSES = re.compile(r"queue-full skips (\d+), write timeouts (\d+), short writes (\d+)")


def connected_nodes(frames: list[object]) -> list[int]:
    return [
        f.node_id
        for f in service_frames(frames)  # type: ignore[arg-type]
        if f.service is c2_16b.Service.CONNECTED and f.node_id != 0
    ]


def wait_for_log(daemon: DaemonProcess, text: str, timeout: float = 20.0) -> str:
    deadline = time.monotonic() + timeout
    while text not in (log := daemon.log()) and time.monotonic() < deadline:
        time.sleep(0.05)
    return log


def line_dropped(log: str) -> bool:
    """Did the daemon leave bytes out because the pty was full (a loaded test machine)?"""
    found = LOSSES.search(log)
    assert found, "no stats line in the log"
    return any(int(n) for n in found.groups())


def test_stick_keeps_every_tick_while_five_devices_are_plugged(tmp_path: Path) -> None:
    replay_dir = tmp_path / "replay"
    replay_dir.mkdir()
    # from the centre (the neutral guard lets it go live), then every report different
    stick = [StickState(x=(8192 + i) % 16384, y=(8192 + 3 * i) % 16384) for i in range(2000)]
    install(replay_dir / "stick.hid", recording(stick, hold_s=0.001))
    config = tmp_path / "usb2rc.yaml"
    config.write_text(CONFIG)
    line = PtyLine()
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--replay-loop", "--config", str(config))
    try:
        line.wait_for(lambda fr: any(f.status == c2_16b.LIVE for f in data_frames(fr, 0)), 20)
        for k, text in enumerate(real_device_recordings(PLUGGED, 2.0, 250)):
            install(replay_dir / f"dev{k}.hid", text)
            line.wait_for(lambda f, k=k: len(connected_nodes(f)) > k, timeout=20)
        line.wait_for(lambda f: all(data_frames(f, n) for n in range(1, PLUGGED + 1)), 20)
        count = len(data_frames(line.frames(), 0))
        line.wait_for(lambda f: len(data_frames(f, 0)) >= count + 10, timeout=20)
        daemon.signal(signal.SIGUSR1)
        log = wait_for_log(daemon, "stats: output1")
    finally:
        assert daemon.stop() == 0, daemon.log()[-2000:]
        line.close()
    frames = line.frames()
    assert connected_nodes(frames) == list(range(1, PLUGGED + 1)), "plug order, once each"
    ours = data_frames(frames, 0)
    # SIGTERM ends the stream with `!` (docs/ICD.md, "Stop"): the rules below hold before it
    assert ours[-1].status == c2_16b.FAILSAFE, "the stop's failsafe is the stick's last frame"
    while ours[-1].status == c2_16b.FAILSAFE:
        ours.pop()
    live = next(i for i, f in enumerate(ours) if f.status == c2_16b.LIVE)  # `!` until then
    assert all(f.status == c2_16b.LIVE for f in ours[live:]), "the stick never left live"
    if line_dropped(log):
        return  # this test's reader fell behind and the pty filled: frames left out on purpose
    holes = [(a.code, b.code) for a, b in itertools.pairwise(ours) if b.code != (a.code + 1) % 256]
    assert holes == [], "a stick frame lost or sent twice"
    data = data_frames(frames)
    for node in range(1, PLUGGED + 1):
        at = [i for i, f in enumerate(data) if f.node_id == node]
        for a, b in itertools.pairwise(at):
            sticks = sum(1 for f in data[a + 1 : b] if f.node_id == 0)
            assert sticks == 1, f"a tick carried node {node} without the stick (or twice)"
