"""End to end: `&` handover and `%` low battery frames from replayed devices, read off a pty
(docs/ICD.md, "Handover", "Low battery", "Status priority")."""

from __future__ import annotations

import itertools
from pathlib import Path

from daemon_harness import StickState, data_frames, install, recording, run_daemon, scale
from test_status_inputs import PAD_DESCRIPTOR, pad_report

from usb2rc.hid.recording import RecordedEvent, Recording, format_recording
from usb2rc.protocols.c2_16b import codec as c2_16b

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE
HANDOVER, LOW_BATTERY = c2_16b.HANDOVER, c2_16b.LOW_BATTERY
BUTTON5 = 1 << 4
LOW_SLIDER = 20  # raw 0..255: below 10 % (25.5)

STICK_CONFIG = """
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    node_id: 4
    handover: {button: 5, destination: 7}
    low_battery: {usage: Slider, below: 10}
"""
BURST_CONFIG = """
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    node_id: 4
    handover: {button: 1, destination: 3, frames: 4}
"""


def runs(statuses: list[int]) -> list[tuple[int, int]]:
    """(status, how many in a row) for each run of equal statuses."""
    return [(status, len(list(group))) for status, group in itertools.groupby(statuses)]


def kinds(frames: list[c2_16b.DataFrame]) -> list[int]:
    """The statuses in the order they come, each run of equal ones counted once."""
    return [status for status, _ in runs([f.status for f in frames])]


def test_handover_while_held_and_low_battery_from_an_axis(tmp_path: Path, line, replay_dir):
    config = tmp_path / "stick.yaml"
    config.write_text(STICK_CONFIG)
    states = [
        StickState(),
        StickState(buttons=BUTTON5),  # `&` while held
        StickState(),
        StickState(slider=LOW_SLIDER),  # `%` while the "battery" axis is low
        StickState(slider=LOW_SLIDER, buttons=BUTTON5),  # both: `&` wins
        StickState(slider=LOW_SLIDER),
        StickState(),  # back to `>`, and it stays
    ]
    install(replay_dir / "stick.hid", recording(states, hold_s=0.3))
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    low_wire = scale(LOW_SLIDER, 0, 255)
    try:
        line.wait_for(
            lambda fr: kinds(data_frames(fr, 4)[-60:])[-3:] == [HANDOVER, LOW_BATTERY, LIVE]
        )
    finally:
        assert daemon.stop() == 0, daemon.log()
    frames = [f for f in data_frames(line.frames(), 4) if f.status != FAILSAFE]
    assert frames, "no live frame"
    for frame in frames:  # each frame's status follows from its own (live) data fields
        if frame.group1 & BUTTON5:
            assert (frame.status, frame.code) == (HANDOVER, 7), frame
        elif frame.axes[3] == low_wire:
            assert frame.status == LOW_BATTERY, frame
        else:
            assert frame.status == LIVE, frame
    assert kinds(frames) == [LIVE, HANDOVER, LIVE, LOW_BATTERY, HANDOVER, LOW_BATTERY, LIVE]
    both = [f for f in frames if f.group1 & BUTTON5 and f.axes[3] == low_wire]
    assert both and {f.status for f in both} == {HANDOVER}
    # `&` frames use no message code: the others count on without a gap
    codes = [f.code for f in frames if f.status != HANDOVER]
    assert all(b == (a + 1) % 256 for a, b in itertools.pairwise(codes))
    assert "node 4 asks for a handover to 7 (while held)" in daemon.log()


def test_a_press_sends_the_configured_number_of_frames(tmp_path: Path, line, replay_dir):
    config = tmp_path / "burst.yaml"
    config.write_text(BURST_CONFIG)
    states = [
        StickState(),
        *[StickState(buttons=0x01)] * 5,  # held 0.5 s (25 ticks): still 4 `&` frames
        StickState(),
        StickState(buttons=0x01),  # 0.1 s: 4 `&` frames again
        StickState(),
    ]
    install(replay_dir / "stick.hid", recording(states, hold_s=0.1))
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        line.wait_for(
            lambda fr: (
                [f.status for f in data_frames(fr, 4)].count(HANDOVER) >= 8
                and data_frames(fr, 4)[-1].group1 == 0
                and len(data_frames(fr, 4)) >= 70
            )
        )
    finally:
        assert daemon.stop() == 0, daemon.log()
    frames = [f for f in data_frames(line.frames(), 4) if f.status != FAILSAFE]
    handovers = [(status, count) for status, count in runs([f.status for f in frames])]
    assert [run for run in handovers if run[0] == HANDOVER] == [(HANDOVER, 4), (HANDOVER, 4)]
    assert {f.code for f in frames if f.status == HANDOVER} == {3}
    # the first press is held past its 4 frames: `>` with the button still down
    first = next(i for i, f in enumerate(frames) if f.status == HANDOVER)
    assert all(f.group1 & 1 for f in frames[first : first + 4])
    assert frames[first + 4].status == LIVE and frames[first + 4].group1 & 1


def pad_recording(batteries: list[int], hold_s: float) -> str:
    events = tuple(
        RecordedEvent(i * hold_s, pad_report(battery=level)) for i, level in enumerate(batteries)
    )
    return format_recording(
        Recording(PAD_DESCRIPTOR, "Test Wireless Pad", "", 5, 0x045E, 0x0B13, events)
    )


def test_zero_config_battery_strength_sends_low_battery(tmp_path: Path, line, replay_dir):
    install(replay_dir / "pad.hid", pad_recording([80, 60, 35, 12, 8], hold_s=0.3))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: [f.status for f in data_frames(fr, 0)][-15:] == [LOW_BATTERY] * 15)
    finally:
        assert daemon.stop() == 0, daemon.log()
    statuses = [f.status for f in data_frames(line.frames(), 0) if f.status != FAILSAFE]
    # 80, 60, 35 % are `>`, 12 and 8 % (below 20 %) are `%`: one switch, never back
    assert [status for status, _ in runs(statuses)] == [LIVE, LOW_BATTERY]
    codes = [f.code for f in data_frames(line.frames(), 0)]
    assert all(b == (a + 1) % 256 for a, b in itertools.pairwise(codes))
