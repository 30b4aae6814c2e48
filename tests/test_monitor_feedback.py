"""`usb2rc monitor --outputs`: what the far ends say back, on the live screen and as text.

A real monitor (a subprocess) with a C2-16B, a CRSF and a MAVLink output on ptys whose far
ends talk back (tests/web_harness.py's `FarEnds`: a downlink for node 1, a module's
telemetry, an armed vehicle), a replayed LED stick on node 1 and two feedback rules: the
plain text and the live screen (on a pseudo-terminal) show the telemetry with its age, the
rules' last actions and what the stick shows, each line whole. At 80x24 the live screen
wraps a long telemetry line rather than cut its age off, and keeps those rows ahead of the
counters and events. The tests wait on what the screen shows, never on the clock."""

from __future__ import annotations

import fcntl
import os
import re
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from daemon_harness import ROOT, PtyLine, install
from test_monitor import fake_node, render_at, screen_reader
from web_harness import ARMED_RULE_LINE, FEEDBACK_CONFIG, FarEnds, led_stick_recording

from usb2rc.commands import monitor
from usb2rc.runtime import stats_text

WAIT_S = 30.0
ROWS, COLS = 50, 160
CRSF_LINE = re.compile(
    r"telemetry crsf: LQ 87 %, RSSI -60 dBm, SNR 9 dB, battery 15\.2 V, 76 %, mode ACRO "
    r"\(\d+\.\d s ago\)"
)
MAVLINK_LINE = re.compile(
    r"telemetry mavlink: armed yes, mode LOITER, battery 12\.6 V, 64 %, failsafe no "
    r"\(\d+\.\d s ago\)"
)
RULE_LINE = re.compile(
    rf"feedback rule 1 \(\S*feedback\.yaml:{ARMED_RULE_LINE}\): led LED Caps Lock on leds"
)
STICK_LINE = "feedback LED stick: lit LED Num Lock, LED Caps Lock, LED Scroll Lock, brightness 0.50"


def all_told(screen: str) -> bool:
    return all(
        (CRSF_LINE.search(screen), MAVLINK_LINE.search(screen), RULE_LINE.search(screen))
    ) and (STICK_LINE in screen)


@pytest.fixture
def talking(tmp_path: Path) -> Iterator[tuple[Path, Path]]:
    """The config and the replay folder; the three far ends talking back until the end."""
    lines: list[PtyLine] = []
    far_ends = None
    try:
        for protocol in ("c2-16b", "crsf", "mavlink"):
            lines.append(PtyLine(protocol))
        config = tmp_path / "feedback.yaml"
        config.write_text(
            FEEDBACK_CONFIG.format(c2=lines[0].path, crsf=lines[1].path, mavlink=lines[2].path)
        )
        replay = tmp_path / "replay"
        replay.mkdir()
        install(replay / "leds.hid", led_stick_recording())
        far_ends = FarEnds(lines[0], lines[1], lines[2])
        far_ends.start()
        yield config, replay
    finally:
        if far_ends is not None:
            far_ends.stop()
        for line in lines:
            line.close_at_the_end()


def monitor_argv(config: Path, replay: Path, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "usb2rc", "monitor", "--outputs", "--config", str(config),
        "--replay", str(replay), "--seconds", "120", *extra,
    ]  # fmt: skip


def read_until(read: Callable[[], str], done: Callable[[str], bool]) -> str:
    deadline = time.monotonic() + WAIT_S
    while not done(text := read()):
        if time.monotonic() > deadline:
            raise AssertionError(f"the screen never showed it; last screen:\n{text[-4000:]}")
    return text


def stop(proc: subprocess.Popen[bytes]) -> None:
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def test_plain_text_shows_the_telemetry_the_actions_and_the_stick(
    talking: tuple[Path, Path],
) -> None:
    config, replay = talking
    proc = subprocess.Popen(
        monitor_argv(config, replay, "--plain"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        cwd=ROOT,
    )
    try:
        assert proc.stdout is not None
        text = read_until(screen_reader(proc.stdout.fileno(), bytearray()), all_told)
    finally:
        stop(proc)
    snapshot = text[text.rindex("--- ") :]
    lines = snapshot.splitlines()
    # each on a line of its own, ahead of the counters ("stats: ...")
    crsf = next(i for i, line in enumerate(lines) if CRSF_LINE.fullmatch(line))
    first_stats = next(i for i, line in enumerate(lines) if line.startswith("stats: "))
    assert crsf < first_stats, snapshot
    assert "stats: telemetry" not in snapshot and "stats: feedback" not in snapshot


def test_the_live_screen_shows_them_on_a_pty(talking: tuple[Path, Path]) -> None:
    config, replay = talking
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", ROWS, COLS, 0, 0))
    env = dict(os.environ, TERM="xterm", LANG="C.UTF-8")
    env.pop("COLUMNS", None)
    env.pop("LINES", None)
    proc = None
    try:
        proc = subprocess.Popen(
            monitor_argv(config, replay),
            stdin=slave, stdout=slave, stderr=slave, cwd=ROOT, env=env, start_new_session=True,
        )  # fmt: skip
        os.close(slave)
        slave = -1
        raw = bytearray()
        read_until(screen_reader(master, raw), all_told)
        assert "\x1b[" in raw.decode("utf-8", "replace")  # a live, redrawn screen
    finally:
        if proc is not None:
            stop(proc)
        if slave >= 0:
            os.close(slave)
        os.close(master)


# A record as the daemon builds it (usb2rc.feedback.worker.FeedbackWorker.record).
RECORD = {
    "telemetry": {
        "crsf.link_quality": 87, "crsf.rssi": -60, "crsf.snr": 9, "crsf.battery_voltage": 15.2,
        "crsf.battery_remaining": 76, "crsf.flight_mode": "ACRO", "crsf.age": 0.123,
        "mavlink.armed": None, "mavlink.mode": None, "mavlink.battery_voltage": None,
        "mavlink.battery_remaining": None, "mavlink.failsafe": None, "mavlink.age": 7.5,
    },
    "actions": [
        {"rule": 1, "where": "/etc/usb2rc/usb2rc.yaml:12", "did": "led LED Caps Lock on leds",
         "ago_s": 2.1},
    ],
    "devices": [
        {"name": "LED stick", "indicators": 8, "lit": ["LED Num Lock"],
         "analog": {"brightness": 0.5}, "texts": []},
    ],
}  # fmt: skip


def test_at_80x24_a_long_telemetry_line_wraps_and_keeps_its_age() -> None:
    feedback = stats_text.feedback_lines(RECORD)
    assert len(feedback[0]) > 80  # the CRSF line: too long for the window
    events = [f"node 0: connected {i}" for i in range(30)]
    snap = monitor.Snapshot(
        [fake_node(0, 8)], events, len(events), ["stats line"] * 5, feedback=feedback
    )
    lines = render_at(snap, [], now=0.0)
    assert len(lines) <= 23 and all(len(line) <= 80 for line in lines), lines
    start = next(i for i, line in enumerate(lines) if line.startswith("telemetry crsf: "))
    crsf = lines[start] + " " + lines[start + 1].strip()
    assert crsf == feedback[0]  # whole: its age too
    assert lines[start + 1].startswith(monitor.FEEDBACK_INDENT)
    assert "telemetry mavlink: nothing known (stale) (7.5 s ago)" in lines
    assert any(line.startswith("feedback rule 1 (/etc/usb2rc/usb2rc.yaml:12)") for line in lines)
    assert "feedback LED stick: lit LED Num Lock, brightness 0.50" in lines
    assert any("hidden" in line for line in lines)  # the counters and events gave way
    assert not any(line.startswith("stats: ") for line in lines)
