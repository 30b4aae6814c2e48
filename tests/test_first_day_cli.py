"""A newcomer's first day at the command line: the live views' log lines carry their time
and go after a while; the slips get a did-you-mean (`protocol: elrs`, `--port ttyUSB0`);
`list --all` does not send the user to `list --all`. Through the real command line: the live
views in a tmux pane (a real terminal), the rest as subprocesses.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import pytest
from cli_harness import usb2rc

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / "usb2rc" / "data" / "demo"
WAIT_S = 60.0  # generous: the machine may be busy
GONE_CAPTURES = 5  # a line is gone once this many captures in a row lack it
SHOWN_S = 10.0  # how long a live view keeps a log line (usb2rc.commands.monitor.LOG_SHOWN_S)
# The neutral guard's warning at the plug, which used to stay on screen for good.
PLUG_WARNING = re.compile(r"log: (\d\d):(\d\d):(\d\d) WARNING node 0 waits for X, Y, Rz still")


class Pane:
    """A command in a detached tmux session of its own (a real terminal, 160x60)."""

    def __init__(self, command: str, cwd: Path) -> None:
        self.tmux = ["tmux", "-L", f"usb2rc-first-day-{os.getpid()}", "-f", os.devnull]
        env = dict(os.environ, TERM="xterm", LANG="C.UTF-8")
        env.pop("COLUMNS", None)
        env.pop("LINES", None)
        shell = f"{command}; echo VIEW-EXITED-$?; sleep 120"
        size = ["-x", "160", "-y", "60"]
        subprocess.run(
            [*self.tmux, "new-session", "-d", "-s", "v", *size, "-c", str(cwd), shell],
            check=True,
            env=env,
            timeout=30,
        )

    def screen(self) -> str:
        """What the terminal shows now (the visible screen, not its history)."""
        return subprocess.run(
            [*self.tmux, "capture-pane", "-p", "-t", "v"],
            capture_output=True,
            text=True,
            check=False,
            timeout=30,
        ).stdout

    def close(self) -> None:
        subprocess.run([*self.tmux, "kill-server"], capture_output=True, check=False, timeout=30)


def wait_screen(pane: Pane, found: re.Pattern[str] | str, what: str, gone: bool = False) -> str:
    """The screen once `found` is on it (or, with gone, once it has been off the whole
    screen, header drawn, in GONE_CAPTURES captures in a row: a capture may catch the
    screen half redrawn)."""
    deadline = time.monotonic() + WAIT_S
    in_a_row = 0
    while True:
        screen = pane.screen()
        there = bool(found.search(screen)) if isinstance(found, re.Pattern) else found in screen
        drawn = "usb2rc monitor:" in screen or "usb2rc demo: daemon" in screen
        in_a_row = in_a_row + 1 if (drawn and there != gone) else 0
        if in_a_row >= (GONE_CAPTURES if gone else 1):
            return screen
        assert "VIEW-EXITED-" not in screen, f"the view ended before {what}:\n{screen}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}:\n{screen}"
        time.sleep(0.2)


def seconds_of_day(hours: str, minutes: str, seconds: str) -> int:
    return int(hours) * 3600 + int(minutes) * 60 + int(seconds)


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
@pytest.mark.parametrize(
    "view",
    [
        "monitor --replay demo --seconds 90",
        pytest.param("demo --seconds 90", marks=pytest.mark.slow),
    ],
)
def test_a_live_view_shows_a_log_line_with_its_time_then_lets_it_go(
    view: str, tmp_path: Path
) -> None:
    pane = Pane(f"{sys.executable} -m usb2rc {view}", tmp_path)
    try:
        screen = wait_screen(pane, PLUG_WARNING, "the plug's warning with its time")
        match = PLUG_WARNING.search(screen)
        assert match is not None
        line = next(row for row in screen.splitlines() if match.group(0) in row).strip()
        stamp = seconds_of_day(*match.groups())
        after = wait_screen(pane, line, "the warning to go", gone=True)  # before: for good
        now = datetime.now()
        gone_at = seconds_of_day(str(now.hour), str(now.minute), str(now.second))
        assert (gone_at - stamp) % 86400 >= SHOWN_S - 1, "it went before it was read"
        header = "usb2rc monitor:" if view.startswith("monitor") else "usb2rc demo: daemon"
        assert header in after and "VIEW-EXITED-" not in after  # the view itself goes on
    finally:
        pane.close()


# --- did-you-mean ---------------------------------------------------------------------------


def test_protocol_elrs_suggests_crsf(tmp_path: Path) -> None:
    config = tmp_path / "elrs.yaml"
    config.write_text("outputs:\n  - protocol: elrs\n    port: /dev/ttyUSB9\n")
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2
    assert result.stderr.startswith(
        f"{config}:2: outputs[0].protocol: 'elrs' is not valid: ExpressLRS receivers take "
        "CRSF; did you mean 'crsf'? (allowed: c2-16b, sumd, crsf, sbus, ibus, mavlink)"
    ), result.stderr
    config.write_text("outputs:\n  - protocol: crfs\n    port: /dev/ttyUSB9\n")
    typo = usb2rc("check", "--config", str(config))
    assert "'crfs' is not valid; did you mean 'crsf'?" in typo.stderr


@pytest.mark.parametrize("command", ["run", "check"])
def test_a_port_without_dev_suggests_dev(command: str, tmp_path: Path) -> None:
    result = usb2rc(command, "--replay", str(DEMO), "--port", "ttyUSB0", cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert "--port: 'ttyUSB0' is a name, not a path: did you mean /dev/ttyUSB0?" in result.stderr


def test_a_config_port_without_dev_suggests_dev(tmp_path: Path) -> None:
    config = tmp_path / "c2.yaml"
    config.write_text("outputs:\n  - protocol: c2-16b\n    port: ttyACM0\n")
    result = usb2rc("check", "--config", str(config), cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.startswith(
        f"{config}:3: outputs[0].port: 'ttyACM0' is a name, not a path: did you mean /dev/ttyACM0?"
    ), result.stderr


def test_a_port_file_in_the_folder_is_taken_as_it_is(tmp_path: Path) -> None:
    master, slave = os.openpty()
    try:
        (tmp_path / "ttyUSB0").symlink_to(os.ttyname(slave))  # ./ttyUSB0 exists: it is meant
        result = usb2rc("check", "--port", "ttyUSB0", cwd=tmp_path)
    finally:
        os.close(master)
        os.close(slave)
    assert result.returncode == 0, result.stderr


# --- list --all -------------------------------------------------------------------------------


def test_list_all_does_not_send_the_user_to_list_all(tmp_path: Path) -> None:
    shown = usb2rc("list", "--all", cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    if "No HID" not in shown.stdout:
        pytest.skip("this machine has HID devices: `list` prints them, not the hint")
    assert "list --all" not in shown.stdout  # before: "(see `usb2rc list --all`)"
    assert ") (" not in shown.stdout and ".)." not in shown.stdout
    plain = usb2rc("list", cwd=tmp_path).stdout
    assert "`usb2rc list --all` shows every HID device and why it is not used" in plain
    assert ") (" not in plain
