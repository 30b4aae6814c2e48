"""`usb2rc calibrate` in a real terminal (tmux): keys in, the config written with its comments.

The replayed stick sweeps every axis through its whole range in its first second, then rests:
X and Y jitter by a few counts around their centres, Rz too, and the slider stays at 0 (a
throttle). The test answers the wizard as a user would, waiting for what the screen shows.
"""

from __future__ import annotations

import itertools
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest
from daemon_harness import ROOT, StickState, install, recording

from usb2rc.configfile import Calibration, load_config

WAIT_S = 30.0
SWEEP = [StickState(x=x, y=x, rz=x >> 6, slider=x >> 6) for x in range(0, 16384, 820)]
SWEEP += [StickState(x=16383, y=16383, rz=255, slider=255)]
SWEEP += list(reversed(SWEEP))
X_REST = (8190, 8194, 8192, 8191, 8193)
Y_REST = (8100, 8104, 8102)
RESTING = [
    StickState(x=X_REST[i % 5], y=Y_REST[i % 3], rz=127 + i % 3, slider=0) for i in range(1200)
]  # 60 s at 20 Hz: longer than the test takes
HOLD_S = 0.05

needs_tmux = pytest.mark.skipif(
    shutil.which("tmux") is None and not os.environ.get("CI"),
    reason="tmux is not installed (CI must have it)",
)


SERVERS = itertools.count()


class Pane:
    def __init__(self, name: str) -> None:
        # A server of its own per test: a new session on a server still shutting down after
        # the last test's kill-server fails ("server exited unexpectedly").
        socket = f"{name}-{os.getpid()}-{next(SERVERS)}"
        self.tmux = ["tmux", "-L", socket, "-f", os.devnull]

    def start(self, command: str, cwd: Path) -> None:
        env = dict(os.environ, TERM="xterm", LANG="C.UTF-8")
        size = ["-x", "120", "-y", "40"]
        subprocess.run(
            [*self.tmux, "new-session", "-d", "-s", "t", *size, "-c", str(cwd), command],
            check=True,
            env=env,
        )

    def screen(self) -> str:
        out = subprocess.run(
            [*self.tmux, "capture-pane", "-p", "-t", "t"], capture_output=True, text=True
        )
        return out.stdout

    def wait_for(self, done: Callable[[str], bool] | str) -> str:
        check = done if callable(done) else (lambda text: done in text)
        deadline = time.monotonic() + WAIT_S
        text = self.screen()
        while not check(text):
            if time.monotonic() > deadline:
                raise AssertionError(f"the screen never showed {done!r}; last screen:\n{text}")
            time.sleep(0.05)
            text = self.screen()
        return text

    def keys(self, *keys: str) -> None:
        subprocess.run([*self.tmux, "send-keys", "-t", "t", *keys], check=True)

    def close(self) -> None:
        subprocess.run([*self.tmux, "kill-server"], capture_output=True)


@pytest.fixture
def pane() -> Iterator[Pane]:
    p = Pane("usb2rc-calibrate")
    yield p
    p.close()


def usb2rc(*args: str) -> list[str]:
    return [sys.executable, "-m", "usb2rc", *args]


def stick_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "replay"
    folder.mkdir()
    install(folder / "stick.hid", recording(SWEEP + RESTING, hold_s=HOLD_S))
    return folder


def starter(tmp_path: Path, folder: Path) -> Path:
    config = tmp_path / "x.yaml"
    made = subprocess.run(
        usb2rc("init", "--replay", str(folder), "-o", str(config)),
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert made.returncode == 0, made.stderr
    return config


def calibrate_command(config: Path, folder: Path) -> str:
    argv = usb2rc("calibrate", "--config", str(config), "--replay", str(folder))
    return " ".join(argv) + "; echo EXIT=$?; sleep 60"


def raw_value(screen: str) -> int | None:
    match = re.search(r"^raw\s+(-?\d+)\s", screen, re.MULTILINE)
    return int(match[1]) if match else None


def step(pane: Pane, slot: str, number: int, resting: Sequence[int]) -> None:
    """Waits for axis `slot`'s range step with its whole range seen and the stick back at
    rest (Enter during the sweep would take moving values as the rest)."""
    pane.wait_for(f"axis {number} of 4: thrustmaster-t-16000m.{slot} ")
    pane.wait_for(lambda text: "(100% of the range)" in text and raw_value(text) in resting)


@needs_tmux
def test_calibrate_writes_what_check_accepts_and_keeps_the_comments(tmp_path, pane):
    folder = stick_folder(tmp_path)
    config = starter(tmp_path, folder)
    before = config.read_text()
    pane.start(calibrate_command(config, folder), ROOT)

    for number, slot, resting in ((1, "x", X_REST), (2, "y", Y_REST)):
        step(pane, slot, number, resting)
        pane.keys("Enter")
        pane.wait_for("Enter takes it")
        pane.keys("Enter")
    step(pane, "slider", 3, [0])
    pane.keys("Enter")
    pane.wait_for("at rest 0..0")
    pane.keys("Enter")  # it rests at an end: refused, the screen says why
    pane.wait_for("press m (midpoint)")
    pane.keys("m")
    pane.wait_for("axis 4 of 4: thrustmaster-t-16000m.rz ")
    pane.keys("s")
    summary = pane.wait_for("Enter: write")
    assert "thrustmaster-t-16000m.rz      skipped" in summary
    pane.keys("Enter")
    pane.wait_for("EXIT=0")

    after = config.read_text()
    edited = {"x", "y", "slider"}
    for old, new in zip(before.splitlines(), after.splitlines(), strict=True):
        slot = old.split(":")[0].strip()
        if slot in edited:
            assert new.split("#")[1:] == old.split("#")[1:]  # the comment is still there
        else:
            assert new == old
    axes = {a.slot: a for a in load_config(str(config)).devices[0].axes}
    x, y = axes["x"].calibration, axes["y"].calibration
    assert x is not None and (x.min, x.max) == (0, 16383) and min(X_REST) <= x.center <= max(X_REST)
    assert y is not None and (y.min, y.max) == (0, 16383) and min(Y_REST) <= y.center <= max(Y_REST)
    assert axes["x"].deadband == axes["y"].deadband == 0.01  # a few counts at rest
    assert axes["slider"].calibration == Calibration(0, 127, 255)
    assert axes["slider"].deadband == 0 and axes["rz"].calibration is None
    checked = subprocess.run(
        usb2rc("check", "--config", str(config), "--replay", str(folder), "--port", "/dev/ttyUSB0"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert checked.returncode == 0, checked.stderr
    assert "axis x      <- X (raw 0..16383, signed -32768..32767, calibration 0/" in checked.stdout


@pytest.mark.slow  # a long journey: the fast suite keeps shorter ones of its kind
@needs_tmux
def test_calibrate_over_the_demo_recordings(tmp_path, pane):
    """The shipped demo never rests (circles and sweeps, looped): each axis takes its range,
    then `m` (midpoint) in the rest step, as for a throttle."""
    demo = ROOT / "usb2rc" / "data" / "demo"
    config = starter(tmp_path, demo)
    before = config.read_text()
    argv = usb2rc("calibrate", "--config", str(config), "--replay", str(demo), "--replay-loop")
    pane.start(" ".join(argv) + " thrustmaster-t-16000m; echo EXIT=$?; sleep 60", ROOT)
    ends = {"x": 16383, "y": 16383, "slider": 255, "rz": 255}
    for number, slot in enumerate(ends, start=1):
        pane.wait_for(f"axis {number} of 4: thrustmaster-t-16000m.{slot} ")
        pane.wait_for(f"seen 0..{ends[slot]} (100% of the range)")
        pane.keys("Enter")
        pane.wait_for("step 2 of 2")
        pane.keys("m")
    pane.wait_for("Enter: write")
    pane.keys("Enter")
    pane.wait_for("EXIT=0")
    after = config.read_text()
    assert [line.split("#", 1)[1] for line in after.splitlines() if "#" in line] == [
        line.split("#", 1)[1] for line in before.splitlines() if "#" in line
    ]
    stick, throttle = load_config(str(config)).devices
    assert {a.slot: a.calibration for a in stick.axes} == {
        "x": Calibration(0, 8191, 16383),
        "y": Calibration(0, 8191, 16383),
        "slider": Calibration(0, 127, 255),
        "rz": Calibration(0, 127, 255),
    }
    assert all(a.calibration is None for a in throttle.axes)  # DEVICE named the stick only
    checked = subprocess.run(
        usb2rc("check", "--config", str(config), "--port", "/dev/ttyUSB0"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert checked.returncode == 0, checked.stderr


@needs_tmux
def test_quit_leaves_the_file_as_it_was(tmp_path, pane):
    folder = stick_folder(tmp_path)
    config = starter(tmp_path, folder)
    before = config.read_text()
    pane.start(calibrate_command(config, folder), ROOT)
    step(pane, "x", 1, X_REST)
    pane.keys("Enter")
    pane.wait_for("Enter takes it")
    pane.keys("Enter")
    pane.wait_for("axis 2 of 4")
    pane.keys("q")
    screen = pane.wait_for("EXIT=1")
    assert f"quit: {config} unchanged" in screen
    assert config.read_text() == before


@needs_tmux
def test_init_then_check_in_a_terminal(tmp_path, pane):
    """The issue's commands as typed in a shell, from the source tree."""
    config = tmp_path / "x.yaml"
    # a port that can be a serial line: `check` refuses /dev/null (docs/CONFIG.md, "Reload")
    init = " ".join(usb2rc("init", "--replay", "usb2rc/data/demo", "--port", "/dev/ttyUSB0"))
    check = " ".join(usb2rc("check", "--config", str(config)))
    pane.start(f"{init} -o {config} && {check}; echo EXIT=$?; sleep 60", ROOT)
    screen = pane.wait_for("EXIT=")
    assert "EXIT=0" in screen and f"{config}: OK" in screen, screen


def test_usage_errors_exit_2(tmp_path):
    folder = stick_folder(tmp_path)
    config = starter(tmp_path, folder)
    cases = [
        ((), "--config FILE is required"),
        (("--config", str(config), "thrustmaster-t16000m"), "did you mean 'thrustmaster-t-16000m'"),
        (("--config", str(config), "--replay", str(tmp_path / "nope")), "no such directory"),
        (("--config", str(config), "--replay", str(folder)), "run it in a terminal"),
    ]
    for args, message in cases:
        out = subprocess.run(
            usb2rc("calibrate", *args),
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
            timeout=60,
        )
        assert out.returncode == 2 and message in out.stderr, (args, out.stderr)
