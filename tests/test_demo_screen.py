"""`usb2rc demo`'s live screen fits the window and leaves nothing stale behind.

The demo used to draw every line it had (taller than an 80x24 window once the events piled
up) and to let the daemon's unplug warnings go straight to stderr under rich's live screen:
the terminal kept old copies of the header above the last screen. Now the screen is cut to
the window and the log lines are part of it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from usb2rc.commands import demo
from usb2rc.protocols.c2_16b.receiver import ReceiverModel

ROOT = Path(__file__).resolve().parent.parent
WAIT_S = 60.0


def test_screen_text_fits_80x24_with_the_newest_events_and_logs() -> None:
    model = ReceiverModel()
    for i in range(12):
        model.events.append(f"node {i % 2}: connected with a rather long event line " * 2)
        model.event_total += 1
    logs = ["WARNING device unplugged: Thrustmaster T.16000M (044f:b10a, port replay-stick)"]
    lines = demo.screen_text(model, "/dev/pts/99", logs, (80, 24)).split("\n")
    assert len(lines) <= 23 and all(len(line) <= 79 for line in lines), lines
    assert lines[-1].startswith("log: WARNING device unplugged")  # the warning is kept
    assert lines[-1].endswith("…")


def test_screen_text_at_3_rows_keeps_the_header() -> None:
    lines = demo.screen_text(ReceiverModel(), "/dev/pts/99", [], (80, 3)).split("\n")
    assert len(lines) == 2 and lines[0].startswith("usb2rc demo: daemon")


@pytest.mark.slow  # the demo's unplug (12 s into a cycle) is what used to tear the screen
@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_demo_in_80x24_leaves_one_screen_behind(tmp_path: Path) -> None:
    socket = f"usb2rc-demo-{os.getpid()}"
    tmux = ["tmux", "-L", socket, "-f", os.devnull]
    command = f"{sys.executable} -m usb2rc demo --seconds 14; echo DEMO-EXITED-$?; sleep 60"
    env = dict(os.environ, TERM="xterm", LANG="C.UTF-8")
    env.pop("COLUMNS", None)
    env.pop("LINES", None)
    subprocess.run(
        [
            *tmux,
            "new-session",
            "-d",
            "-s",
            "d",
            "-x",
            "80",
            "-y",
            "24",
            "-c",
            str(tmp_path),
            command,
        ],
        check=True,
        env=env,
    )
    try:
        deadline = time.monotonic() + WAIT_S
        while True:
            pane = subprocess.run(
                [*tmux, "capture-pane", "-p", "-S", "-", "-t", "d"],
                capture_output=True,
                text=True,
                check=False,
            ).stdout
            if "DEMO-EXITED-" in pane:
                break
            assert time.monotonic() < deadline, f"the demo did not exit:\n{pane}"
            time.sleep(0.2)
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True, check=False)
    assert "DEMO-EXITED-0" in pane
    assert pane.count("usb2rc demo: daemon") == 1, pane  # no stale copy above the last screen
    assert "node 0: disconnected" in pane or "WARNING device unplugged" in pane  # it got there
