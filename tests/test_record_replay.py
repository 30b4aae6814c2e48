"""`usb2rc record` of a replayed device, replayed again: the daemon sends the same frames.

A hand-packed T.16000M recording is recorded with `usb2rc record --replay DIR stick`; the
original and the copy then play side by side in one daemon (Node-IDs 0 and 1 by port path)
and the sequence of distinct frames each node sends must be the same, and what the default
layout makes of the states.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from daemon_harness import (
    ROOT,
    StickState,
    data_frames,
    expected_frame,
    install,
    recording,
    run_daemon,
)

from usb2rc.hid.recording import read_recording

# Each state is held 0.3 s (15 ticks at 50 Hz); the first differs from the device's state
# before its first report, so the sequence has a clear start, and rests near the centre
# (the neutral guard lets the node go live on it).
STATES = [
    StickState(x=8300, y=8100, buttons=0x0010),
    StickState(x=0, y=16383, rz=0, slider=255, buttons=0x0001),
    StickState(x=16383, y=0, rz=255, slider=0, buttons=0x8000, hat=0),
    StickState(x=4000, y=12000, rz=7, slider=99, buttons=0x0101, hat=5),
    StickState(x=16383, y=16383, rz=200, slider=10, buttons=0xFFFF, hat=2),
]
HOLD_S = 0.3
WAIT_S = 20.0


def record(source_dir: Path, stem: str, out: Path, seconds: float) -> subprocess.CompletedProcess:
    argv = ["record", "--replay", str(source_dir), stem, "--seconds", str(seconds)]
    with out.open("w") as stdout:
        return subprocess.run(
            [sys.executable, "-m", "usb2rc", *argv],
            stdout=stdout,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            timeout=60,
        )


def distinct(frames: list) -> list[tuple]:
    """Consecutive equal frames collapsed, from the first one that shows STATES[0] on."""
    seen: list[tuple] = []
    for f in frames:
        state = (f.axes, f.group1, f.group2)
        if not seen or seen[-1] != state:
            seen.append(state)
    first = expected_frame(STATES[0])
    return seen[seen.index(first) :] if first in seen else seen


def test_record_then_replay_gives_the_same_frames(tmp_path, line):
    source = tmp_path / "source"
    source.mkdir()
    original = recording(STATES, hold_s=HOLD_S)
    install(source / "stick.hid", original)

    copy = tmp_path / "out.hid"
    done = record(source, "stick", copy, seconds=len(STATES) * HOLD_S + 1.0)
    assert done.returncode == 0, done.stderr

    # the copy is a hid-recorder file with the device's descriptor, name, ids and reports
    before, after = read_recording(source / "stick.hid"), read_recording(copy)
    assert after.descriptor == before.descriptor
    assert (after.name, after.vid, after.pid) == (before.name, before.vid, before.pid)
    assert [e.report for e in after.events] == [e.report for e in before.events]
    times = [e.time_s for e in after.events]
    assert times == sorted(times)

    replay = tmp_path / "replay"
    replay.mkdir()
    install(replay / "a-original.hid", original)  # port path replay-a-original: Node-ID 0
    install(replay / "b-recorded.hid", copy.read_text())  # replay-b-recorded: Node-ID 1
    daemon = run_daemon(tmp_path, line.path, replay)
    try:
        final = expected_frame(STATES[-1])

        def both_final(frames: list) -> bool:
            return all(
                final in [(f.axes, f.group1, f.group2) for f in data_frames(frames, node)]
                for node in (0, 1)
            )

        line.wait_for(both_final, WAIT_S)
        frames = line.frames()
    finally:
        assert daemon.stop() == 0
    wanted = [expected_frame(s) for s in STATES]
    assert distinct(data_frames(frames, 0)) == wanted
    assert distinct(data_frames(frames, 1)) == wanted


def test_record_names_the_devices_when_none_matches(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    install(source / "stick.hid", recording(STATES[:1]))
    done = record(source, "nosuch", tmp_path / "out.hid", seconds=0.1)
    assert done.returncode == 1
    assert "no device matches 'nosuch'" in done.stderr and "044f:b10a" in done.stderr
