"""A test that fails half-way leaves nothing running (tests/conftest.py, process_harness.py).

A small test suite runs in a pytest subprocess, under tests/conftest.py as the real suite has
it: each of its tests starts daemons and fails before it stops them, one through the daemon
harness; one by hand and one orphaned by the shell that started it. Once that pytest has exited,
no process of theirs may be left: each daemon's command line carries a folder of this test's
own, looked for in every process of the machine.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from daemon_harness import ROOT
from process_harness import command_line

TESTS = ROOT / "tests"

FAILING_SUITE = """
import os, subprocess, sys
from pathlib import Path

from daemon_harness import DaemonProcess, wait_until

REPLAY = Path(os.environ["LEFTOVER_MARK"])
ROOT = os.environ["LEFTOVER_ROOT"]
DAEMON = [sys.executable, "-m", "usb2rc", "run", "--port", "loop://", "--replay", str(REPLAY)]


def running(log: Path) -> bool:
    return log.exists() and " running" in log.read_text()


def test_a_harness_daemon_then_a_failure(tmp_path):
    daemon = DaemonProcess(["--port", "loop://", "--replay", str(REPLAY)], tmp_path / "log")
    wait_until(lambda: running(tmp_path / "log"), "the daemon to run", timeout=60)
    assert False, "deliberately, the daemon still running"


def test_daemons_by_hand_then_a_failure(tmp_path):
    with open(tmp_path / "log", "wb") as log:
        subprocess.Popen(DAEMON, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    orphan_log = tmp_path / "orphan.log"
    command = " ".join(DAEMON) + f" >{orphan_log} 2>&1 &"  # the shell exits at once
    subprocess.run(["sh", "-c", command], check=True, cwd=ROOT)
    wait_until(lambda: running(tmp_path / "log") and running(orphan_log), "them to run", timeout=60)
    assert False, "deliberately, the daemons still running"
"""

FAILING_TESTS = ["test_a_harness_daemon_then_a_failure", "test_daemons_by_hand_then_a_failure"]


def processes_with(mark: str) -> list[str]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and mark in (command := command_line(int(entry.name))):
            found.append(f"pid {entry.name}: {command}")
    return found


@pytest.mark.parametrize("workers", [[], ["-n", "2"]], ids=["plain", "xdist"])
def test_failing_tests_leave_no_daemon_running(tmp_path: Path, workers: list[str]) -> None:
    suite = tmp_path / "suite"
    suite.mkdir()
    shutil.copy(TESTS / "conftest.py", suite / "conftest.py")  # the real suite's, as it is
    (suite / "test_failing.py").write_text(textwrap.dedent(FAILING_SUITE))
    mark = tmp_path / "replay-leftover-mark"  # in each daemon's command line
    mark.mkdir()
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(TESTS), str(ROOT)]),
        LEFTOVER_MARK=str(mark),
        LEFTOVER_ROOT=str(ROOT),
    )
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-rA", "-v", *workers, "."],
        cwd=suite,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    try:
        report = result.stdout + result.stderr
        assert result.returncode == 1, report
        for name in FAILING_TESTS:
            assert f"FAILED test_failing.py::{name}" in report
        assert report.count("AssertionError: deliberately, the daemon") >= 2, report
        # those started by hand are named as left running; the harness's is its own to stop
        assert "the test left these running (now ended)" in report, report
        assert report.count(f"--replay {mark}") >= 2, report
        assert processes_with(str(mark)) == [], report
    finally:
        leftovers = [int(p.split()[1].rstrip(":")) for p in processes_with(str(mark))]
        for pid in leftovers:  # this test's own cleanup, should the fixture have failed
            os.kill(pid, 9)
        deadline = time.monotonic() + 10
        while processes_with(str(mark)) and time.monotonic() < deadline:
            time.sleep(0.05)
