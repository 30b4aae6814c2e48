"""The daemon's threads run at SCHED_RR where the system grants it, and at normal priority,
saying why, where it does not (usb2rc/runtime/realtime.py): seen from outside, in the
scheduling policy the kernel reports for each of the running daemon's threads."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from daemon_harness import (
    DaemonProcess,
    PtyLine,
    data_frames,
    install,
    real_device_recordings,
    wait_until,
)

from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import Daemon
from usb2rc.hid.replay import ReplayBackend
from usb2rc.runtime import realtime

SCHED_OTHER, SCHED_RR = 0, 2  # /proc/PID/task/TID/stat's policy field (uapi/linux/sched.h)


def may_use_realtime(priority: int) -> bool:
    """Whether a process of this user here gets SCHED_RR at `priority` (CAP_SYS_NICE, or
    RLIMIT_RTPRIO; a container may withhold both even from root): asked of a child."""
    ask = f"import os; os.sched_setscheduler(0, os.SCHED_RR, os.sched_param({priority}))"
    return subprocess.run([sys.executable, "-c", ask], capture_output=True).returncode == 0


needs_realtime = pytest.mark.skipif(
    not may_use_realtime(realtime.DEFAULT_PRIORITY),
    reason="real-time priority is not granted here (no CAP_SYS_NICE, RLIMIT_RTPRIO too low)",
)


def thread_policies(pid: int) -> dict[str, tuple[int, int]]:
    """Each thread's name: (policy, real-time priority), as the kernel reports them."""
    policies = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
            name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
        except (FileNotFoundError, ProcessLookupError):  # the thread has just exited
            continue
        fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (comm) "
        # fields[0] is stat's 3rd field: rt_priority is its 40th, policy its 41st
        policies[f"{name}/{tid}"] = (int(fields[38]), int(fields[37]))
    return policies


def started_daemon(
    tmp_path: Path, *extra: str, prefix: tuple[str, ...] = ()
) -> tuple[DaemonProcess, PtyLine]:
    """A daemon replaying one device onto a pty, once its first frame is written (every
    thread of its outputs started by then)."""
    replay = tmp_path / "replay"
    replay.mkdir()
    (replay / "stick.hid").write_text(real_device_recordings(1, 30.0, 250.0)[0])
    line = PtyLine()
    args = ["--port", line.path, "--replay", str(replay), *extra]
    daemon = DaemonProcess(args, tmp_path / "daemon.log", prefix=prefix)
    wait_until(lambda: "first frame written" in daemon.log(), "the first frame")
    return daemon, line


@needs_realtime
def test_every_thread_of_a_running_daemon_is_real_time(tmp_path: Path) -> None:
    daemon, line = started_daemon(tmp_path)
    try:
        policies = thread_policies(daemon.proc.pid)
        normal = {name: p for name, p in policies.items() if p != (SCHED_RR, 10)}
        # the main thread asks first: every thread it starts after inherits it
        assert not normal, normal
        assert len(policies) >= 4, policies  # main, drivers, node clock, reader, ...
        assert "scheduling: SCHED_RR 10" in daemon.log()
    finally:
        assert daemon.stop() == 0
        line.close()


@needs_realtime
def test_a_device_plugged_later_is_read_by_a_real_time_thread(tmp_path: Path) -> None:
    """Where real-time priority meets hot-plug: the reader of a device plugged while the
    daemon runs is started by the lifecycle thread, not by the one that asked, and inherits
    the priority from it."""
    daemon, line = started_daemon(tmp_path)
    try:
        before = set(thread_policies(daemon.proc.pid))
        second = real_device_recordings(2, 30.0, 250.0)[1]
        install(tmp_path / "replay" / "throttle.hid", second)  # plugged: node 1, zero config
        line.wait_for(lambda frames: data_frames(frames, 1))  # frames of the plugged node 1
        policies = thread_policies(daemon.proc.pid)
        assert set(policies) - before, policies  # its reader is a new thread
        normal = {name: p for name, p in policies.items() if p != (SCHED_RR, 10)}
        assert not normal, normal
    finally:
        assert daemon.stop() == 0
        line.close()


def test_priority_0_runs_every_thread_at_normal_priority_and_says_so(tmp_path: Path) -> None:
    daemon, line = started_daemon(tmp_path, "--realtime-priority", "0")
    try:
        policies = thread_policies(daemon.proc.pid)
        assert all(policy == (SCHED_OTHER, 0) for policy in policies.values()), policies
        assert "scheduling: normal (real-time priority off (--realtime-priority 0))" in (
            daemon.log()
        )
    finally:
        assert daemon.stop() == 0
        line.close()


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="util-linux's setpriv is missing")
def test_a_refused_request_runs_at_normal_priority_and_says_what_would_allow_it(
    tmp_path: Path,
) -> None:
    """No CAP_SYS_NICE and RLIMIT_RTPRIO 0, as a service user under a hardened unit: the
    daemon runs on, its frames go out, the log says why and what to change."""
    drop: tuple[str, ...] = ()  # an ordinary user has no capability to drop
    if os.geteuid() == 0:
        drop = ("setpriv", "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice")
    limit = ("prlimit", "--rtprio=0:0")
    daemon, line = started_daemon(tmp_path, prefix=(*limit, *drop))
    try:
        policies = thread_policies(daemon.proc.pid)
        assert all(policy == (SCHED_OTHER, 0) for policy in policies.values()), policies
        text = daemon.log()
        assert "scheduling: normal (real-time priority refused: Operation not permitted" in text
        assert "RLIMIT_RTPRIO is 0, needs 10 or CAP_SYS_NICE" in text
        wait_until(lambda: line.frames(), "frames at normal priority")
    finally:
        assert daemon.stop() == 0
        line.close()


@pytest.mark.parametrize("value", ["50", "-1", "ten"])
def test_a_priority_out_of_range_is_a_usage_error(value: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "usb2rc", "run", "--realtime-priority", value],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 2
    assert "--realtime-priority" in result.stderr


@needs_realtime
def test_an_in_process_daemon_gives_its_caller_back_its_scheduling(tmp_path: Path) -> None:
    """The tests and benches run daemons one after another in one process: the thread that
    started one is not left real-time once it stops."""
    before = os.sched_getscheduler(0)
    daemon = Daemon(
        Config(outputs=(OutputConfig(protocol="c2-16b", port="loop://"),)),
        ReplayBackend(tmp_path),
    )
    try:
        daemon.start()
        assert os.sched_getscheduler(0) == os.SCHED_RR
        assert daemon.stats_record()["scheduling"] == "SCHED_RR 10"
    finally:
        daemon.stop()
    assert os.sched_getscheduler(0) == before
