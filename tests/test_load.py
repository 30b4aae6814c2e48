"""The daemon's own load (usb2rc/runtime/load.py): its CPU share in the stats, and a missed
tick said in the log, rate limited, by a driver whose host stalled."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import pytest
from daemon_harness import StickState
from test_node_table_driver import BINDING, Source, info

from usb2rc.lines.driver import DriverThread, LineDriver
from usb2rc.lines.serial_link import SerialLink
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.nodes.table import NodeSnapshot, NodeTable
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.sbus import codec as sbus
from usb2rc.protocols.sbus.session import SbusSession
from usb2rc.runtime import stats_text
from usb2rc.runtime.load import CpuMark, MissedTickLog, thread_cpu_s

WAIT_S = 10.0  # a safety net: every wait ends on its condition


def test_cpu_share_is_cpu_time_over_wall_time() -> None:
    assert CpuMark(10.0, 1.0).share_pct(CpuMark(12.0, 1.5)) == pytest.approx(25.0)
    assert CpuMark(10.0, 1.0).share_pct(CpuMark(10.0, 1.0)) is None  # no time passed


def test_a_threads_cpu_time_is_read_from_the_os() -> None:
    if not threading.get_native_id() or thread_cpu_s(threading.get_native_id()) is None:
        pytest.skip("no per-thread CPU time on this platform")
    before = thread_cpu_s(threading.get_native_id())
    spun = time.thread_time() + 0.02
    while time.thread_time() < spun:  # CPU this thread takes, however long that lasts
        pass
    after = thread_cpu_s(threading.get_native_id())
    assert before is not None and after is not None and after - before >= 0.015
    assert thread_cpu_s(None) is None and thread_cpu_s(2**31 - 1) is None  # no such thread


class Moments:
    """A clock that gives these moments in turn, and a CPU mark of the moment last given
    (the process's CPU half of it), counted."""

    def __init__(self, *times: float) -> None:
        self._given = iter(times)
        self.now = 0.0
        self.marks = 0

    def clock(self) -> float:
        self.now = next(self._given)
        return self.now

    def cpu_mark(self) -> CpuMark:
        self.marks += 1
        return CpuMark(self.now, self.now / 2)


def test_the_first_miss_is_said_at_once_then_a_line_per_interval(
    caplog: pytest.LogCaptureFixture,
) -> None:
    moments = Moments(4, 5, 9, 15, 16, 30)
    missed = MissedTickLog(
        "sbus (/dev/ttyAMA0)", CpuMark(0.0, 0.0), 10.0, moments.clock, moments.cpu_mark
    )
    with caplog.at_level(logging.WARNING, logger="usb2rc.load"):
        missed.note(1, 1)  # at 4 s: said
        missed.note(2, 3)  # at 5 s and 9 s: counted, not said
        missed.note(1, 4)
        missed.note(1, 5)  # at 15 s: the four since the first line
        missed.note(1, 6)  # at 16 s: owed
        missed.note(0, 6)  # no tick missed at 30 s, but the one owed is said
        missed.note(0, 6)  # nothing owed: nothing said, no clock read
    first, second, third = (record.getMessage() for record in caplog.records)
    assert first.startswith("sbus (/dev/ttyAMA0): 1 tick(s) missed (1 since start)")
    assert "usb2rc has used 50.0 % of a core since it started" in first
    assert "(more: a line every 10 s at most)" in first
    assert second.startswith(
        "sbus (/dev/ttyAMA0): 4 tick(s) missed in the 11 s since the last such line (5 since"
    )
    assert third.startswith("sbus (/dev/ttyAMA0): 1 tick(s) missed in the 15 s since the last")
    assert missed.unsaid == 0
    assert moments.marks == 3  # the process's CPU time read for the lines only


class StallOnce:
    """The node table's step, stalled once for `stall_s` when `armed` is set: the host not
    running usb2rc for a while (a deliberate fault, not a wait)."""

    def __init__(self, step: Callable[[frozenset[int] | None], NodeSnapshot], stall_s: float):
        self.step, self.stall_s = step, stall_s
        self.armed = threading.Event()

    def __call__(self, nodes: frozenset[int] | None) -> NodeSnapshot:
        if self.armed.is_set():
            self.armed.clear()
            time.sleep(self.stall_s)
        return self.step(nodes)


def until(condition: Callable[[], object], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


def test_a_stalled_host_is_said_in_the_log(caplog: pytest.LogCaptureFixture) -> None:
    """A tick that starts more than a period late is skipped and counted: the log says so
    (with usb2rc's CPU share), never only the stats."""
    table = NodeTable()
    table.add_device(0, info("a", "1-1"), BINDING, Source.of(StickState()), "JOYSTICK")
    channels = OutputChannels.scaled([ChannelSource(0, "axis", 0)], RC11_SCALE, sbus.FRAME_LEN)
    period = 0.01
    step = StallOnce(table.step_if_due, stall_s=5 * period)
    link = SerialLink("loop://", 100000)
    driver = LineDriver("sbus", link, SbusSession("sbus", channels, 1 / period), step, period)
    thread = DriverThread("drivers", [driver])
    assert link.open_now()
    with caplog.at_level(logging.WARNING, logger="usb2rc.load"):
        thread.start()
        try:
            until(lambda: driver.stats.ticks >= 3, "ticks")
            step.armed.set()
            until(lambda: driver.stats.missed_ticks > 0, "a missed tick")
            until(lambda: caplog.records, "the log line")
        finally:
            thread.stop()
            thread.join(WAIT_S)
    (said,) = [r.getMessage() for r in caplog.records if "tick(s) missed" in r.getMessage()]
    assert said.startswith("sbus (loop://): ") and "a stall of the host" in said


def test_the_stats_begin_with_the_daemons_own_line() -> None:
    record = {
        "uptime_s": 12.34,
        "cpu_pct": 4.83,
        "drivers_cpu_pct": 3.9,
        "scheduling": "SCHED_RR 10",
        "outputs": [],
        "devices": [],
    }
    assert stats_text.stats_lines(record) == [
        "usb2rc: up 12.3 s, CPU 4.8 % of a core since start (drivers' thread 3.9 %), "
        "scheduling: SCHED_RR 10"
    ]
    unknown = {**record, "cpu_pct": None, "drivers_cpu_pct": None}
    assert stats_text.daemon_line(unknown) == "usb2rc: up 12.3 s, scheduling: SCHED_RR 10"
