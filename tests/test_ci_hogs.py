""".ci/with-cpu-hogs: CI's second run of the fast suite, beside two CPU-bound processes.

The wrapper runs for real around a small command that finds the hogs (its parent's other
children) and names them; once the wrapper has gone, however it went, none of them runs on.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest
from daemon_harness import ROOT
from process_harness import command_line, end, still_running

WRAPPER = ROOT / ".ci" / "with-cpu-hogs"
WAIT_S = 30.0

# Prints its pid and those of the hogs beside it once both spin; then exits with $EXIT_WITH,
# or waits to be stopped.
FIND_HOGS = """
import os, sys, time
from process_harness import children, command_line
deadline = time.monotonic() + 30
while True:
    beside = children(os.getppid()) - {os.getpid()}
    hogs = [p for p in beside if "while 1: pass" in command_line(p)]
    if len(hogs) == 2 or time.monotonic() > deadline:
        break
    time.sleep(0.01)
print(os.getpid(), *hogs, flush=True)
if os.environ.get("EXIT_WITH"):
    sys.exit(int(os.environ["EXIT_WITH"]))
time.sleep(600)
"""


def start(**env: str) -> tuple[subprocess.Popen[str], int, list[int]]:
    """The wrapper around FIND_HOGS, in a process group of its own and with Ctrl-C's default
    action as in a terminal (a pytest started in the background ignores SIGINT, and so would
    all it starts); FIND_HOGS's pid and the hogs it found."""
    proc = subprocess.Popen(
        ["env", "--default-signal=INT", str(WRAPPER), sys.executable, "-c", FIND_HOGS],
        stdout=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT / "tests"), **env),
        process_group=0,
    )
    assert proc.stdout is not None
    command, *hogs = (int(pid) for pid in proc.stdout.readline().split())
    return proc, command, hogs


def test_the_command_runs_beside_two_hogs_its_status_is_kept_and_the_hogs_go():
    proc, _, hogs = start(EXIT_WITH="3")
    assert len(hogs) == 2, hogs
    assert proc.wait(WAIT_S) == 3
    assert not still_running(hogs, WAIT_S), [command_line(pid) for pid in hogs]


@pytest.mark.parametrize("slow_shell", ["", "1"])
@pytest.mark.parametrize(
    ("signum", "status"), [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGKILL, -9)]
)
def test_the_hogs_go_with_the_wrapper_however_it_is_stopped(signum, status, slow_shell):
    """SIGTERM and SIGKILL to the wrapper alone; SIGINT to its process group, as Ctrl-C.
    `slow_shell`: on a loaded machine the command may run, and be signalled, before the
    wrapper's shell is back from starting it (HOGS_SLOW_SHELL_S stands in for that): its
    traps must already be there, or it waits for a command that is gone."""
    proc, command, hogs = start(HOGS_SLOW_SHELL_S=slow_shell)
    try:
        assert len(hogs) == 2, hogs
        if signum == signal.SIGINT:
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        assert proc.wait(WAIT_S) == status
        assert not still_running(hogs, WAIT_S), [command_line(pid) for pid in hogs]
        if signum != signal.SIGKILL:  # it stopped the command too
            assert not still_running([command], WAIT_S), command_line(command)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        end([command])  # after a SIGKILL the wrapper could not stop it


def test_ci_runs_the_fast_suite_a_second_time_beside_the_hogs():
    steps = (ROOT / ".ci" / "run").read_text()
    first = steps.index(".venv/bin/pytest\n")
    second = steps.index(".ci/with-cpu-hogs .venv/bin/pytest\n")
    assert first < second < steps.index(".venv/bin/pytest -m slow")
