"""End to end, the pilot's safety features (issue 13): the daemon as a subprocess, replayed
devices, frames read off real ptys.

- the neutral guard: a device (re)plugged with a guarded axis away from its rest stays `!`
  until a report at rest arrives, then goes `>` (zero config and with a config);
- explicit failsafe on stop: after SIGTERM the last frame of every node is `!` and the last
  SUMD frame has the failsafe bit;
- no lost taps: a 5 ms button tap between two ticks shows in exactly one frame, on C2-16B
  (50 Hz) and SUMD (100 Hz) alike.
"""

from __future__ import annotations

import itertools
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon_harness import (
    PtyLine,
    StickState,
    data_frames,
    expected_frame,
    install,
    recording,
    run_daemon,
    services,
    timed_recording,
)

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd import codec as sumd

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE
CENTRED = StickState()
DEFLECTED = StickState(x=16383, y=0)  # full right, full forward: X and Y far from centre
HELD_S = 1.0  # how long a device is held away from rest after it is plugged

# A throttle quadrant written by hand: a Joystick collection with one Simulation Controls
# Throttle (0..255) and 8 buttons; 2-byte reports, no report ID. The default layout puts the
# Throttle in aux1 (docs/ICD.md, "Default axis layout").
THROTTLE_DESCRIPTOR = bytes.fromhex(
    "05010904a101"  # Generic Desktop, Joystick, Collection (Application)
    "050209bb150026ff0075089501 8102".replace(" ", "")  # Simulation: Throttle 0..255, 8 bit
    + "05091901290815002501750195088102"  # Buttons 1..8
    + "c0"
)


@dataclass(frozen=True)
class ThrottleState:
    throttle: int = 0
    buttons: int = 0

    def report(self) -> bytes:
        return bytes([self.throttle, self.buttons])


def throttle_recording(events: list[tuple[float, ThrottleState]]) -> str:
    return timed_recording(events, "Acme Throttle", descriptor=THROTTLE_DESCRIPTOR, ids="1234 5678")


def held_then_at_rest(at_rest: Any, away: Any) -> list[tuple[float, Any]]:
    """Away from rest for HELD_S (a report every 100 ms), then one report at rest."""
    steps = int(HELD_S / 0.1)
    return [(i * 0.1, away) for i in range(steps)] + [(HELD_S, at_rest)]


def after_plug(line: PtyLine, node_id: int, start: int) -> list[c2_16b.DataFrame]:
    """The node's data frames after `start` (its connect sequence comes before any)."""
    return data_frames(line.frames()[start:], node_id)


def assert_guarded(frames: list[c2_16b.DataFrame], away_axes: tuple[int, ...]) -> None:
    """`!` until the first `>`, which carries the values at rest; never `>` away from rest."""
    statuses = [f.status for f in frames]
    first_live = statuses.index(LIVE)
    assert set(statuses[:first_live]) == {FAILSAFE}
    # held away from rest for HELD_S: about HELD_S * 50 ticks of `!` (half of it is plenty)
    assert first_live >= HELD_S * 50 / 2, first_live
    assert all(f.axes != away_axes for f in frames if f.status == LIVE)


def wait_live(line: PtyLine, node_id: int, start: int = 0) -> None:
    line.wait_for(
        lambda fr: any(f.status == LIVE for f in data_frames(fr[start:], node_id)), timeout=20
    )


def test_a_stick_replugged_at_full_deflection_stays_failsafe_until_centred(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """Zero config: X, Y and Rz of a JOYSTICK must rest near the centre."""
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        install(replay_dir / "stick.hid", recording([CENTRED]))
        wait_live(line, 0)
        before = len(line.frames())
        (replay_dir / "stick.hid").unlink()
        line.wait_for(lambda fr: "disconnected" in services(fr[before:], 0))
        before = len(line.frames())
        install(replay_dir / "stick.hid", timed_recording(held_then_at_rest(CENTRED, DEFLECTED)))
        wait_live(line, 0, before)
        frames = after_plug(line, 0, before)
        assert_guarded(frames, expected_frame(DEFLECTED)[0])
        first_live = next(f for f in frames if f.status == LIVE)
        assert first_live.axes == expected_frame(CENTRED)[0]
        # while it waited, the node held the values from before the unplug (centred)
        assert {f.axes for f in frames if f.status == FAILSAFE} == {expected_frame(CENTRED)[0]}
    finally:
        assert daemon.stop() == 0, daemon.log()
    assert "node 0 waits for X centre, Y centre (Thrustmaster T.16000M)" in daemon.log()


def test_a_throttle_plugged_at_full_stays_failsafe_until_low(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """Zero config: a Simulation Controls Throttle must rest at its low end."""
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: fr[:1])
        events = held_then_at_rest(ThrottleState(0), ThrottleState(255))
        install(replay_dir / "throttle.hid", throttle_recording(events))
        wait_live(line, 0)
        frames = data_frames(line.frames(), 0)
        full = (0,) * 8 + (32767, 0)
        assert_guarded(frames, full)
        assert next(f for f in frames if f.status == LIVE).axes[8] == -32768
        assert {f.axes[8] for f in frames if f.status == FAILSAFE} == {0}  # nothing to hold
    finally:
        assert daemon.stop() == 0, daemon.log()
    assert "node 0 waits for Throttle low (Acme Throttle)" in daemon.log()


GUARD_CONFIG = """
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    node_id: 4
    axes:
      x: X
      slider: {usage: Slider, arm: low, arm_tolerance: 0.05, failsafe: -32768}
"""


def test_with_a_config_a_slider_armed_low_waits_for_its_low_end(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    config = tmp_path / "usb2rc.yaml"
    config.write_text(GUARD_CONFIG)
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        line.wait_for(lambda fr: data_frames(fr, 4))  # the pinned node sends `!` meanwhile
        before = len(line.frames())
        full, low = StickState(slider=255), StickState(slider=0)
        install(replay_dir / "stick.hid", timed_recording(held_then_at_rest(low, full)))
        wait_live(line, 4, before)
        frames = after_plug(line, 4, before)
        assert_guarded(frames, (0, 0, 0, 32767) + (0,) * 6)
        assert next(f for f in frames if f.status == LIVE).axes[3] == -32768
        assert {f.axes[3] for f in frames if f.status == FAILSAFE} == {-32768}  # its failsafe
        # replugged with X at full right (the slider low): `!` until X is centred
        before = len(line.frames())
        (replay_dir / "stick.hid").unlink()
        line.wait_for(lambda fr: "disconnected" in services(fr[before:], 4))
        before = len(line.frames())
        right = StickState(x=16383, slider=0)
        install(replay_dir / "stick.hid", timed_recording(held_then_at_rest(low, right)))
        wait_live(line, 4, before)
        frames = after_plug(line, 4, before)
        assert_guarded(frames, (32767, 0, 0, -32768) + (0,) * 6)
        assert next(f for f in frames if f.status == LIVE).axes[0] == expected_frame(low)[0][0]
    finally:
        assert daemon.stop() == 0, daemon.log()
    assert "node 4 waits for Slider low (Thrustmaster T.16000M)" in daemon.log()
    assert "node 4 waits for X centre (Thrustmaster T.16000M)" in daemon.log()


def two_outputs(tmp_path: Path, sumd_line: PtyLine, channels: str) -> Path:
    """A config: the C2-16B output (its port from --port) and a SUMD output on its own pty."""
    config = tmp_path / "usb2rc.yaml"
    config.write_text(
        "outputs:\n"
        "  - protocol: c2-16b\n"
        "  - protocol: sumd\n"
        f"    port: {sumd_line.path}\n"
        f"    channels: [{channels}]\n"
    )
    return config


def test_sigterm_ends_every_node_and_sumd_in_failsafe(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    sumd_line = PtyLine("sumd")
    try:
        config = two_outputs(tmp_path, sumd_line, "node0.x, node0.y, node1.x")
        for name in ("a", "b"):
            install(replay_dir / f"{name}.hid", recording([CENTRED]))
        daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
        try:
            line.wait_for(
                lambda fr: all(
                    data_frames(fr, n) and data_frames(fr, n)[-1].status == LIVE for n in (0, 1)
                ),
                timeout=20,
            )
            sumd_line.wait_for(lambda fr: fr and not fr[-1].failsafe, timeout=20)
            daemon.signal(signal.SIGTERM)
            assert daemon.proc.wait(10) == 0
        finally:
            code = daemon.stop()
        assert code == 0, daemon.log()
        # the process is gone: what it wrote is all there is; the last frames are failsafe
        line.wait_for(
            lambda fr: all(data_frames(fr, n)[-1].status == FAILSAFE for n in (0, 1)), timeout=5
        )
        sumd_line.wait_for(lambda fr: fr[-1].failsafe, timeout=5)
        last = sumd_line.frames()[-1]
        assert isinstance(last, sumd.SumdFrame)
        assert sumd.encode_sumd(last.channels, failsafe=True)[1] == 0x81
        assert "failsafe frame went out" not in daemon.log()
    finally:
        sumd_line.close()


TAPS = 5
TAP_S = 0.005


def tap_events() -> list[tuple[float, StickState]]:
    """Centred; then 5 taps of button 1, 5 ms each, 300 ms apart, at offsets that fall
    anywhere within a 20 ms tick. From 3 s on: a stick goes live only after its rest, and a
    loaded host may take a second or more to see it (a tap while it is not live shows in no
    frame)."""
    events: list[tuple[float, StickState]] = [(0.0, CENTRED)]
    for k in range(TAPS):
        at = 3.0 + k * 0.3 + k * 0.0037
        events += [(at, StickState(buttons=1)), (at + TAP_S, CENTRED)]
    return events


def pressed_runs(pressed: list[bool]) -> list[int]:
    """The lengths of the runs of consecutive pressed frames."""
    return [len(list(run)) for is_pressed, run in itertools.groupby(pressed) if is_pressed]


def test_a_5_ms_tap_between_ticks_shows_in_one_frame_on_c2_and_sumd(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    sumd_line = PtyLine("sumd")
    try:
        config = two_outputs(tmp_path, sumd_line, "node0.x, node0.button1")
        daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
        try:
            line.wait_for(lambda fr: fr[:1])
            install(replay_dir / "stick.hid", timed_recording(tap_events()))

            def c2_taps(frames: list[Any]) -> list[int]:
                return pressed_runs([bool(f.group1 & 1) for f in data_frames(frames, 0)])

            def sumd_taps(frames: list[Any]) -> list[int]:
                return pressed_runs([f.channels[1] == 0x3B60 for f in frames])

            line.wait_for(lambda fr: len(c2_taps(fr)) >= TAPS, timeout=40)
            sumd_line.wait_for(lambda fr: len(sumd_taps(fr)) >= TAPS, timeout=40)
        finally:
            assert daemon.stop() == 0, daemon.log()
        assert c2_taps(line.frames()) == [1] * TAPS
        assert sumd_taps(sumd_line.frames()) == [1] * TAPS
    finally:
        sumd_line.close()


def test_sigterm_on_a_line_nobody_reads_still_stops(tmp_path: Path, replay_dir: Path) -> None:
    """A far end that never reads: the pty fills, the line stalls; the final failsafe ticks
    give up instead of waiting for it (the wait here only catches a hang)."""
    master, slave = os.openpty()
    try:
        install(replay_dir / "stick.hid", recording([CENTRED], hold_s=0.001))
        daemon = run_daemon(tmp_path, os.ttyname(slave), replay_dir)
        try:
            deadline = time.monotonic() + 30
            while "stalled" not in daemon.log():
                assert time.monotonic() < deadline, daemon.log()[-2000:]
                time.sleep(0.05)
            daemon.signal(signal.SIGTERM)
            assert daemon.proc.wait(10) == 0
        finally:
            daemon.stop()
        assert "Traceback" not in daemon.log()
    finally:
        os.close(master)
        os.close(slave)
