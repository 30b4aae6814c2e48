"""A held button is not a press, black-box: a real daemon on replayed devices, a pymavlink
vehicle stand-in that ACKs (ArduPilot Copter), and a SUMD pty read by its decoder.

A press counts only from a rising edge seen while the button's node is live (docs/ICD.md,
"A held button is not a press"). Each journey holds a button through one of the moments
where it must not count, then releases it and presses it for real: what the button
triggers fires only after that press, and once.

The SUMD line shows what the node sends: its failsafe flag and the triggering buttons as
channels (a held-over button shows held: it is a state there). The order of what the far
ends saw (a SUMD frame's and a COMMAND_LONG's arrival) is the test's evidence, not times.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import (
    DaemonProcess,
    PtyLine,
    Seen,
    StickState,
    install,
    timed_recording,
    wait_until,
)
from pymavlink.dialects.v20 import common as mavlink2
from test_controls_e2e import ARDUCOPTER, Vehicle

from usb2rc.protocols.sumd import codec as sumd

HIGH, LOW = sumd.button_to_sumd(True), sumd.button_to_sumd(False)
ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
SET_MODE = mavlink2.MAV_CMD_DO_SET_MODE

# node0.button2 arms (after `hold`), node0.button6 sets LOITER, node0.button3 flips a toggle;
# SUMD shows button 2, button 6 and the toggle.
CONFIG = """
switches:
  gear: {{toggle: node0.button3}}
devices:
{devices}
outputs:
  - protocol: mavlink
    port: {url}
    channels: [node0.x]
    actions:
      - {{button: node0.button2, do: arm, hold: {hold}}}
      - {{button: node0.button6, do: {{mode: LOITER}}}}
  - protocol: sumd
    port: {pty}
    channels: [node0.button2, node0.button6, switch.gear]
"""
# The stick pinned to node 0; `arm: any` makes it live at its first report (a button box:
# no axis to rest), the moment a held button was fired before.
STICK = """  - name: stick
    match: {{vid: 0x044f, pid: 0xb10a}}
    node_id: 0
    axes:
      x: {{usage: X, arm: {arm}}}
      y: {{usage: Y, arm: {arm}}}
    buttons: {buttons}
"""
ALL_BUTTONS = '{"1-16": "1-16"}'


def stick_entry(arm: str = "centre", buttons: str = ALL_BUTTONS) -> str:
    return STICK.format(arm=arm, buttons=buttons)


def held(*spans: tuple[float, float, int], until: float, pid: str = "b10a") -> str:
    """A T.16000M (or another pid) at rest whose HID button k is held over each
    (down, up, k), reporting every 20 ms from its plug until `until` s."""
    events = []
    for i in range(int(until / 0.02) + 1):
        at = i * 0.02
        buttons = sum(1 << (k - 1) for down, up, k in spans if down <= at < up)
        events.append((at, StickState(buttons=buttons)))
    return timed_recording(events, ids=f"044f {pid}")


class Bench:
    """The vehicle, the SUMD line and the daemon of one journey: stopped whatever happens."""

    def __init__(self, tmp_path: Path, replay_dir: Path) -> None:
        self.tmp_path, self.replay_dir = tmp_path, replay_dir
        self.vehicle = Vehicle(*ARDUCOPTER)
        self.line = PtyLine("sumd")
        self.config = tmp_path / "held.yaml"
        self.daemon: DaemonProcess | None = None

    def write_config(self, devices: str, hold: float = 1.0) -> None:
        text = CONFIG.format(devices=devices, url=self.vehicle.url, pty=self.line.path, hold=hold)
        self.config.write_text(text)

    def start(self) -> DaemonProcess:
        args = ["--replay", str(self.replay_dir), "--config", str(self.config)]
        self.daemon = DaemonProcess(args, self.tmp_path / "daemon.log")
        return self.daemon

    def close(self) -> None:
        try:
            if self.daemon is not None:
                self.daemon.stop()
        finally:
            self.vehicle.close()
            self.line.close()

    # --- what the far ends saw ----------------------------------------------------------

    def commands(self, command: int) -> list[Seen]:
        """The COMMAND_LONGs `command` the vehicle received, with their arrival times."""
        return [
            s
            for s in self.vehicle.seen_now()
            if s.frame.get_type() == "COMMAND_LONG" and s.frame.command == command
        ]

    def wait_sumd(self, what: str, *runs: tuple[Any, ...]) -> Seen:
        """Wait until SUMD showed `runs` in this order (each (failsafe, channels...) seen
        after the one before); the first frame of the last run."""

        def found(seen: list[Seen]) -> Seen | None:
            at = 0
            match = None
            for run in runs:
                match = next((s for s in seen[at:] if _sumd_run(s.frame) == run), None)
                if match is None:
                    return None
                at = seen.index(match)
            return match

        try:
            return self.line.wait_seen(found, timeout=30)
        except AssertionError as error:
            raise AssertionError(f"SUMD never showed {what}") from error


def _sumd_run(frame: Any) -> tuple[Any, ...]:
    return (frame.failsafe, *frame.channels[:3])


@pytest.fixture
def bench(tmp_path: Path, replay_dir: Path) -> Iterator[Bench]:
    journey = Bench(tmp_path, replay_dir)
    try:
        yield journey
    finally:
        journey.close()


def live(button2: int, button6: int = LOW, gear: int = LOW) -> tuple[bool, int, int, int]:
    return (False, button2, button6, gear)


def only_after(commands: list[Seen], pressed: Seen, line: PtyLine) -> None:
    """Exactly one command, and it arrived after the SUMD frame before `pressed` (the first
    frame that showed the press): the output that sends it may tick before SUMD's."""
    assert len(commands) == 1, [c.frame for c in commands]
    seen = line.seen_now()
    before = seen[seen.index(pressed) - 1]
    assert commands[0].time > before.time


def wait_quiet(predicate: Callable[[], Any], what: str) -> None:
    wait_until(predicate, what, timeout=30)


def test_a_button_held_at_the_plug_arms_only_after_a_release_and_a_real_press(
    bench: Bench,
) -> None:
    """Plugged with the arm button held for 3 s (longer than the 1 s hold), then released,
    then pressed and held 1.5 s: no arm before the release, exactly one after the press;
    the log says once that the button must be released first."""
    bench.write_config(stick_entry())
    install(bench.replay_dir / "stick.hid", held((0, 3.0, 2), (4.0, 5.5, 2), until=7.0))
    daemon = bench.start()
    bench.wait_sumd("the held button shown held on the live node", live(HIGH))
    released = bench.wait_sumd("its release", live(HIGH), live(LOW))
    assert bench.commands(ARM) == []  # held 3 s from the plug: never armed
    pressed = bench.wait_sumd("the real press", live(HIGH), live(LOW), live(HIGH))
    bench.wait_sumd("its release", live(HIGH), live(LOW), live(HIGH), live(LOW))
    wait_quiet(lambda: bench.commands(ARM), "the arm after the real press")
    only_after(bench.commands(ARM), pressed, bench.line)
    assert bench.commands(ARM)[0].time > released.time
    note = "stick: button 2 held since the plug: release it first"
    assert daemon.log().count(note) == 1, daemon.log()


def test_a_replug_in_the_middle_of_a_hold_does_not_finish_it(bench: Bench) -> None:
    """Pressed for real, unplugged 0.6 s into a 2 s hold, replugged with the button still
    held: no arm until it is released and pressed anew (then one)."""
    bench.write_config(stick_entry(), hold=2.0)
    stick = bench.replay_dir / "stick.hid"
    install(stick, held((2.0, 60.0, 2), until=60.0))
    bench.start()
    pressed = bench.wait_sumd("a real press", live(LOW), live(HIGH))
    wait_until(lambda: bench.line.seen_now()[-1].time > pressed.time + 0.6, "0.6 s of hold")
    os.unlink(stick)
    unplugged = bench.wait_sumd(
        "the unplug's failsafe", live(LOW), live(HIGH), (True, LOW, LOW, LOW)
    )
    assert [c for c in bench.commands(ARM) if c.time < unplugged.time] == []  # 1.4 s margin
    install(stick, held((0, 3.0, 2), (4.0, 6.5, 2), until=8.0))
    back = bench.wait_sumd("the replug, button held", (True, LOW, LOW, LOW), live(HIGH))
    released = bench.wait_sumd("the release", (True, LOW, LOW, LOW), live(HIGH), live(LOW))
    assert bench.commands(ARM) == [], "armed by a hold that the unplug interrupted"
    pressed = bench.line.wait_seen(
        lambda seen: next(
            (s for s in seen if s.time > released.time and _sumd_run(s.frame) == live(HIGH)), None
        ),
        timeout=30,
    )
    wait_quiet(lambda: bench.commands(ARM), "the arm after the new press")
    only_after(bench.commands(ARM), pressed, bench.line)
    assert back.time < released.time < pressed.time


TWO_ON_NODE_0 = """  - name: other
    match: {vid: 0x044f, pid: 0xb10b}
    node_id: 0
    axes:
      rz: {usage: Rz, arm: any}
    buttons: {"1-4": "30-33"}
"""


def test_a_node_that_leaves_failsafe_while_the_button_is_held_does_not_arm(
    bench: Bench,
) -> None:
    """Node 0 is the stick and another device, which is missing (node 0 in failsafe). The
    stick's arm button is pressed and held; the other device is plugged while it is still
    held: no arm. Released and pressed again, it arms once."""
    bench.write_config(stick_entry() + TWO_ON_NODE_0)
    install(bench.replay_dir / "stick.hid", held((1.0, 60.0, 2), until=60.0))
    daemon = bench.start()
    wait_quiet(lambda: "stick" in daemon.log() and "Node-ID 0" in daemon.log(), "the stick")
    bench.wait_sumd("node 0 in failsafe", (True, LOW, LOW, LOW))
    wait_until(
        lambda: bench.line.seen_now()[-1].time > bench.line.seen_now()[0].time + 1.5, "1.5 s"
    )
    install(bench.replay_dir / "other.hid", held(until=30.0, pid="b10b"))
    shown = bench.wait_sumd("node 0 live, button 2 shown held", (True, LOW, LOW, LOW), live(HIGH))
    wait_until(lambda: bench.line.seen_now()[-1].time > shown.time + 2.5, "2.5 s of hold")
    assert bench.commands(ARM) == [], "armed by a button held while the node was in failsafe"
    assert "button 2 held since" in daemon.log()


def test_a_reload_during_a_hold_starts_it_over(bench: Bench) -> None:
    """A reload that remaps the stick's buttons, 0.5 s into a 3 s hold of the arm button:
    the hold does not complete; released and pressed for 3.5 s, it arms once."""
    bench.write_config(stick_entry(), hold=3.0)
    install(bench.replay_dir / "stick.hid", held((2.0, 6.5, 2), (7.5, 11.0, 2), until=13.0))
    daemon = bench.start()
    pressed = bench.wait_sumd("a real press", live(LOW), live(HIGH))
    remapped = stick_entry(buttons='{"1-8": "1-8", "9-16": "25-32"}')
    bench.write_config(remapped, hold=3.0)
    logged = len(daemon.log())
    daemon.signal(signal.SIGHUP)
    wait_quiet(lambda: "reloaded" in daemon.log()[logged:], "the reload")
    released = bench.wait_sumd("the release", live(LOW), live(HIGH), live(LOW))
    assert bench.commands(ARM) == [], "the hold went on through a reload that remapped it"
    again = bench.wait_sumd("the new press", live(LOW), live(HIGH), live(LOW), live(HIGH))
    wait_quiet(lambda: bench.commands(ARM), "the arm after the new press")
    only_after(bench.commands(ARM), again, bench.line)
    assert pressed.time < released.time
    assert "button 2 held since the reload" in daemon.log()


def test_a_mode_and_a_toggle_held_at_the_plug_do_not_fire(bench: Bench) -> None:
    """A stick that is live at its first report (no guarded axis) plugged with the mode
    button (6) and the toggle's button (3) held: no mode, no flip. Released, then each
    pressed once: one mode command, one flip."""
    bench.write_config(stick_entry(arm="any"))
    spans = ((0, 3.0, 6), (0, 3.0, 3), (4.0, 4.3, 3), (5.0, 5.3, 6))
    install(bench.replay_dir / "stick.hid", held(*spans, until=7.0))
    bench.start()
    bench.wait_sumd("button 6 held on the live node", live(LOW, HIGH))
    released = bench.wait_sumd("its release", live(LOW, HIGH), live(LOW, LOW))
    assert bench.commands(SET_MODE) == []
    flipped = bench.wait_sumd("the flip", live(LOW, HIGH), live(LOW, LOW), live(LOW, LOW, HIGH))
    assert not [
        s for s in bench.line.seen_now() if s.time < released.time and s.frame.channels[2] == HIGH
    ]
    pressed = bench.wait_sumd("the mode press", live(LOW, LOW, HIGH), live(LOW, HIGH, HIGH))
    wait_quiet(lambda: bench.commands(SET_MODE), "the mode after its press")
    only_after(bench.commands(SET_MODE), pressed, bench.line)
    assert flipped.time < pressed.time


def test_monitor_says_once_that_the_held_button_must_be_released(tmp_path: Path) -> None:
    """`usb2rc monitor --plain` on a stick plugged with button 2 held: its log lines say
    once that button 2 must be released first."""
    import subprocess
    import sys

    replay = tmp_path / "replay"
    replay.mkdir()
    install(replay / "stick.hid", held((0, 30.0, 2), until=30.0))
    monitor = [sys.executable, "-m", "usb2rc", "monitor", "--plain", "--replay", str(replay)]
    result = subprocess.run(
        [*monitor, "--seconds", "3"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    note = "button 2 held since the plug: release it first"
    assert result.returncode == 0, result.stderr
    # each plain snapshot prints the log lines that came since the one before
    lines = [line for line in result.stdout.splitlines() if note in line]
    assert len(lines) == 1, result.stdout
