"""Signals at every moment of the daemon's life (issue 11): every stop exits 0.

The real daemon runs as a subprocess (daemon_harness). A second signal follows a stop at a
given spacing, or as a flood (one every millisecond until the process is gone), so it also
lands in the last moments of the stop and of the interpreter's exit, where the old code had
already given the default (fatal) actions back. Start-up moments are found from
/proc/PID/status (SigBlk, SigCgt: which signals the process blocks, catches), not guessed
with sleeps.

A signal that arrives before the interpreter runs usb2rc's code (between exec and the first
line of `usb2rc/__main__.main`, which blocks the daemon's signals until their handlers are
in) gets the default action: no test can expect otherwise, so they start at the first moment
the process holds SIGTERM (blocks or catches it).
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_harness import DaemonProcess, PtyLine, StickState, install, recording, run_daemon

EXIT_TIMEOUT_S = 15.0


def signal_sets(pid: int) -> dict[str, int]:
    """The signal masks of /proc/PID/status (SigPnd, SigBlk, SigIgn, SigCgt); empty once it
    is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return {}
    return {
        key: int(value, 16)
        for key, _, value in (ln.partition(":\t") for ln in status.splitlines())
        if key in ("SigPnd", "SigBlk", "SigIgn", "SigCgt")
    }


def caught(pid: int, signum: int) -> bool:
    """Whether the process has a handler for signum (SigCgt)."""
    return bool(signal_sets(pid).get("SigCgt", 0) >> (signum - 1) & 1)


def held(pid: int, signum: int) -> bool:
    """Whether signum can no longer kill the process: it blocks it (SigBlk) or catches it."""
    sets = signal_sets(pid)
    return bool((sets.get("SigBlk", 0) | sets.get("SigCgt", 0)) >> (signum - 1) & 1)


def wait_until(daemon: DaemonProcess, signum: int, holds=caught) -> None:
    """Spin (no sleep: the point is the first moment) until the daemon holds signum."""
    deadline = time.monotonic() + EXIT_TIMEOUT_S
    while not holds(daemon.proc.pid, signum):
        assert daemon.proc.poll() is None, daemon.log()
        assert time.monotonic() < deadline, f"the daemon never {holds.__name__} the signal"


def wait_until_caught(daemon: DaemonProcess, signum: int) -> None:
    wait_until(daemon, signum, caught)


def wait_log(daemon: DaemonProcess, text: str) -> None:
    deadline = time.monotonic() + EXIT_TIMEOUT_S
    while text not in daemon.log():
        assert daemon.proc.poll() is None, daemon.log()
        assert time.monotonic() < deadline, f"no {text!r} in the log"
        time.sleep(0.005)  # polling a file; what we wait for is in it or not


def spin(seconds: float) -> None:
    """Wait exactly this long without giving the scheduler a reason to oversleep."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def send(proc: subprocess.Popen[bytes], signum: int) -> bool:
    """Send signum unless the process is gone; poll() reaps, so the PID cannot be reused."""
    if proc.poll() is not None:
        return False
    try:
        os.kill(proc.pid, signum)
    except ProcessLookupError:
        return False
    return True


def flood(proc: subprocess.Popen[bytes], signum: int, every_s: float = 0.001) -> int:
    """signum every `every_s` until the process has exited; how many were sent."""
    sent = 0
    deadline = time.monotonic() + EXIT_TIMEOUT_S
    while send(proc, signum):
        sent += 1
        assert time.monotonic() < deadline, "the daemon does not exit"
        spin(every_s)
    return sent


def exit_code(daemon: DaemonProcess) -> int:
    try:
        code = daemon.proc.wait(EXIT_TIMEOUT_S)
    finally:
        daemon.stop()  # kills it if it hangs, closes the log
    return code


def running_daemon(tmp_path: Path, line: PtyLine, replay_dir: Path) -> DaemonProcess:
    """The daemon with a plugged stick, once its first frames are on the line."""
    install(replay_dir / "stick.hid", recording([StickState()]))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    seen = len(line.frames())
    line.wait_for(lambda frames: len(frames) > seen + 3)
    return daemon


def assert_clean_stop(daemon: DaemonProcess, what: str) -> None:
    code = exit_code(daemon)
    log = daemon.log()
    assert code == 0, f"{what}: exit {code}\n{log[-2000:]}"
    assert "Traceback" not in log, log[-4000:]


# --- while running: a stop, then more signals -----------------------------------------------

PAIRS = [(signal.SIGTERM, signal.SIGHUP), (signal.SIGINT, signal.SIGINT)]
PAIR_IDS = ["TERM+HUP", "INT+INT"]


@pytest.mark.parametrize(("first", "then"), PAIRS, ids=PAIR_IDS)
def test_signals_flooding_a_stop_exit_0(tmp_path, line, replay_dir, first, then):
    daemon = running_daemon(tmp_path, line, replay_dir)
    assert send(daemon.proc, first)
    flood(daemon.proc, then)
    assert_clean_stop(daemon, f"{first.name} then a flood of {then.name}")
    assert "stopped" in daemon.log()


@pytest.mark.parametrize("spacing_ms", [0, 20, 90])
@pytest.mark.parametrize(("first", "then"), PAIRS, ids=PAIR_IDS)
def test_a_second_signal_after_a_stop_exits_0(tmp_path, line, replay_dir, first, then, spacing_ms):
    daemon = running_daemon(tmp_path, line, replay_dir)
    assert send(daemon.proc, first)
    spin(spacing_ms / 1000)
    send(daemon.proc, then)
    assert_clean_stop(daemon, f"{first.name}, {spacing_ms} ms, {then.name}")


@pytest.mark.slow
@pytest.mark.parametrize("spacing_ms", [0, 1, 5, 20, 50, 90, 200])
@pytest.mark.parametrize(("first", "then"), PAIRS, ids=PAIR_IDS)
def test_a_second_signal_after_a_stop_exits_0_sweep(
    tmp_path, line, replay_dir, first, then, spacing_ms
):
    for run in range(3):
        (tmp_path / str(run)).mkdir()
        daemon = running_daemon(tmp_path / str(run), line, replay_dir)
        assert send(daemon.proc, first)
        spin(spacing_ms / 1000)
        send(daemon.proc, then)
        assert_clean_stop(daemon, f"run {run}: {first.name}, {spacing_ms} ms, {then.name}")


@pytest.mark.slow
def test_random_spacings_and_pairs_exit_0(tmp_path, line, replay_dir):
    rng = random.Random(int(os.environ.get("USB2RC_FUZZ_SEED", "20261123")))
    stops, others = (signal.SIGTERM, signal.SIGINT), (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
    for run in range(20):
        first, then, spacing = rng.choice(stops), rng.choice(others), rng.uniform(0, 0.25)
        (tmp_path / str(run)).mkdir()
        daemon = running_daemon(tmp_path / str(run), line, replay_dir)
        assert send(daemon.proc, first)
        spin(spacing)
        send(daemon.proc, then)
        what = f"run {run}: {first.name}, {spacing * 1000:.1f} ms, {then.name}"
        assert_clean_stop(daemon, what)


# --- while starting -------------------------------------------------------------------------


def sigterm_at_the_first_moment(tmp_path: Path, line: PtyLine, replay_dir: Path, runs: int):
    """SIGTERM the moment the process catches it, then SIGHUPs every 0.2 ms: the handlers
    went in one at a time once, and a SIGHUP in between (~4 % of runs) was fatal."""
    for run in range(runs):
        (tmp_path / str(run)).mkdir()
        daemon = run_daemon(tmp_path / str(run), line.path, replay_dir)
        wait_until_caught(daemon, signal.SIGTERM)
        assert send(daemon.proc, signal.SIGTERM)
        flood(daemon.proc, signal.SIGHUP, every_s=0.0002)
        assert_clean_stop(daemon, f"run {run}: SIGTERM while starting, then SIGHUPs")


def test_sigterm_at_the_first_moment_it_is_caught_then_sighups_exit_0(tmp_path, line, replay_dir):
    """Start-up (imports, config): the stop is at once, and the SIGHUPs after it are ignored."""
    sigterm_at_the_first_moment(tmp_path, line, replay_dir, runs=10)


@pytest.mark.slow
def test_sigterm_at_the_first_moment_many_times(tmp_path, line, replay_dir):
    sigterm_at_the_first_moment(tmp_path, line, replay_dir, runs=300)


def test_the_usb2rc_script_too(tmp_path, line, replay_dir):
    """The installed `usb2rc` script (what the systemd unit runs) starts in usb2rc.__main__ too."""
    script = Path(sys.executable).with_name("usb2rc")
    if not script.exists():
        pytest.skip("no usb2rc script next to the interpreter (not pip-installed)")
    log = (tmp_path / "script.log").open("wb")
    proc = subprocess.Popen(
        [str(script), "run", "--port", line.path, "--replay", str(replay_dir)],
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + EXIT_TIMEOUT_S
        while not held(proc.pid, signal.SIGTERM):  # from the entry point's first line
            assert proc.poll() is None and time.monotonic() < deadline
        assert send(proc, signal.SIGTERM)
        flood(proc, signal.SIGHUP)
        code = proc.wait(EXIT_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
    assert code == 0, (tmp_path / "script.log").read_text()


def test_sigterm_at_the_first_log_line_then_sighups_exit_0(tmp_path, line, replay_dir):
    install(replay_dir / "stick.hid", recording([StickState()]))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    deadline = time.monotonic() + EXIT_TIMEOUT_S
    while not daemon.log().strip():  # spin: the first moment there is a line
        assert daemon.proc.poll() is None and time.monotonic() < deadline, daemon.log()
    assert send(daemon.proc, signal.SIGTERM)
    flood(daemon.proc, signal.SIGHUP)
    assert_clean_stop(daemon, "SIGTERM at the first log line, then SIGHUPs")


def test_sighup_while_starting_is_kept_for_later(tmp_path, line, replay_dir):
    """The daemon's handlers come before the slow imports; a SIGHUP then is no death."""
    install(replay_dir / "stick.hid", recording([StickState()]))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    wait_until_caught(daemon, signal.SIGHUP)
    assert send(daemon.proc, signal.SIGHUP)
    wait_log(daemon, "no config file to re-read")  # the main loop got it, once running
    line.wait_for(lambda frames: len(frames) > 3)
    assert send(daemon.proc, signal.SIGTERM)
    assert_clean_stop(daemon, "SIGHUP while starting, SIGTERM later")


def test_a_sigterm_while_the_modules_load_waits_for_the_handlers_and_exits_0(
    tmp_path, line, replay_dir
):
    """From the entry point's first line the daemon's signals are blocked until their handlers
    are in: a SIGTERM sent then (blocked, not yet caught) is a clean stop, not a death."""
    for run in range(20):
        (tmp_path / str(run)).mkdir()
        daemon = run_daemon(tmp_path / str(run), line.path, replay_dir)
        wait_until(daemon, signal.SIGTERM, held)
        if caught(daemon.proc.pid, signal.SIGTERM):  # the handlers were in by the first look
            assert send(daemon.proc, signal.SIGTERM)
            assert_clean_stop(daemon, f"run {run}: a stop once caught")
            continue
        assert send(daemon.proc, signal.SIGTERM)
        flood(daemon.proc, signal.SIGHUP)
        assert_clean_stop(daemon, f"run {run}: SIGTERM while blocked, then SIGHUPs")
        return
    pytest.fail("20 starts, and never a moment with SIGTERM blocked before its handler")


@pytest.mark.slow
def test_sigterm_at_random_moments_of_start_up_then_floods_exit_0(tmp_path, line, replay_dir):
    rng = random.Random(int(os.environ.get("USB2RC_FUZZ_SEED", "20261123")))
    install(replay_dir / "stick.hid", recording([StickState()]))
    for run in range(20):
        (tmp_path / str(run)).mkdir()
        daemon = run_daemon(tmp_path / str(run), line.path, replay_dir)
        wait_until(daemon, signal.SIGTERM, held)
        delay = rng.uniform(0, 0.6)  # from the first block to well after the first frame
        spin(delay)
        send(daemon.proc, signal.SIGTERM)
        every_s = rng.choice((0.00005, 0.0002, 0.001))  # a flood into the exit's last moments
        flood(daemon.proc, rng.choice((signal.SIGHUP, signal.SIGINT, signal.SIGTERM)), every_s)
        assert_clean_stop(daemon, f"run {run}: SIGTERM {delay * 1000:.0f} ms into start-up")
