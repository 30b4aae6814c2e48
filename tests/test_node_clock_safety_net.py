"""Beside outputs the node clock is a safety net (`daemon.node_clock_period`): every driver
steps the table before each of its ticks, so the clock steps about every 0.25 s, on the
grid's points at its phase (away from every tick), and only a table no driver stepped that
long. With no output (`usb2rc monitor`) it is the only step, at the grid's period. The
status socket's lines keep their 0.1 s cadence on the grid, where no output ticks.

docs/DESIGN.md, "Node state: one step per period"; tests/test_node_step.py holds the
step itself and the grid's period and phase.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from daemon_harness import StickState, install, timed_recording
from thread_wakeups import WAIT_S, until, voluntary_switches

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import SAFETY_NET_PERIOD_S, Daemon, node_clock_period
from usb2rc.hid.replay import ReplayBackend
from usb2rc.nodes.step import GRID_EPOCH_S

C2 = OutputConfig(protocol="c2-16b", port="loop://", rate_hz=50)
X = (ChannelRef(0, "axis", 0, "node0.x"),)
FIVE = (  # each at its default rate
    C2,
    *(
        OutputConfig(protocol=name, port="loop://", rate_hz=rate, channels=X)
        for name, rate in (("sumd", 100), ("crsf", 250), ("sbus", 100), ("mavlink", 50))
    ),
)


def test_beside_outputs_the_clock_steps_on_the_grid_about_every_quarter_second() -> None:
    assert node_clock_period(0.020, every_node_read=True) == pytest.approx(0.240)  # 12 grid steps
    assert node_clock_period(0.004, every_node_read=True) == pytest.approx(0.248)
    assert node_clock_period(0.100, every_node_read=True) == pytest.approx(0.200)
    assert node_clock_period(1.000, every_node_read=True) == pytest.approx(1.000)  # never under it
    assert node_clock_period(0.020, every_node_read=False) == pytest.approx(0.020)  # monitor


def clearance_s(daemon: Daemon) -> float:
    """How close the clock's steps come to any output's tick over two seconds."""
    clock = daemon.node_clock
    periods = [out.driver.period_s for out in daemon.outputs]
    closest = clock.period_s
    for k in range(round(2.0 / clock.period_s)):
        at = k * clock.period_s + clock.phase_s
        for period in periods:
            closest = min(closest, at % period, period - at % period)
    return closest


@pytest.mark.parametrize(
    ("outputs", "phase_s", "clearance"),
    [((C2,), 0.010, 0.010), (FIVE, 0.006, 0.002)],
    ids=["c2-16b", "five"],
)
def test_a_daemons_clock_keeps_off_the_ticks_and_its_status_lines_keep_their_cadence(
    tmp_path: Path, outputs: tuple[OutputConfig, ...], phase_s: float, clearance: float
) -> None:
    """The clock's phase is the grid's (its steps fall between ticks, as before); the
    status socket's lines still go out every 0.1 s on the grid at that phase."""
    status = str(tmp_path / "status.sock")
    daemon = Daemon(Config(outputs=outputs), ReplayBackend(tmp_path), status_socket=status)
    clock = daemon.node_clock
    assert clock.period_s == pytest.approx(0.240)  # 12 periods of the 20 ms grid
    assert clock.phase_s in (pytest.approx(phase_s), pytest.approx(0.020 - phase_s))
    assert clearance_s(daemon) == pytest.approx(clearance)
    server = daemon.status_server
    assert server is not None and server.period_s == pytest.approx(0.100)
    assert server.phase_s == pytest.approx(GRID_EPOCH_S + clock.phase_s)


def test_with_no_output_the_clock_is_the_only_step_and_keeps_the_grid(tmp_path: Path) -> None:
    daemon = Daemon(Config(outputs=()), ReplayBackend(tmp_path), outputs=False)
    assert daemon.node_clock.period_s == pytest.approx(0.020)


@pytest.fixture
def c2_daemon(tmp_path: Path) -> Iterator[Daemon]:
    """A daemon with C2-16B on `loop://` and a stick that keeps reporting; stopped
    whatever happens."""
    stick = [(i * 0.01, StickState(x=8192 + i % 2)) for i in range(int(60 / 0.01))]
    install(tmp_path / "stick.hid", timed_recording(stick))
    daemon = Daemon(Config(outputs=(C2,)), ReplayBackend(tmp_path))
    try:
        daemon.start()
        yield daemon
    finally:
        daemon.stop()


def test_beside_an_output_the_clock_wakes_a_few_times_a_second_and_the_frames_stay_fresh(
    c2_daemon: Daemon,
) -> None:
    """The driver steps the table at each tick: the snapshot is never older than its
    period, and the clock, which used to wake 50 times a second, wakes about 4 times."""
    table, clock = c2_daemon.table, c2_daemon.node_clock
    until(lambda: any(not n.frame.failsafe for n in table.snapshot().nodes), "the stick live")
    native_id = clock._thread.native_id
    assert native_id is not None
    window_s = 1.0
    wakes_before = voluntary_switches(native_id)
    ages = sample_snapshot_ages(c2_daemon, window_s)
    wakes = voluntary_switches(native_id) - wakes_before
    assert wakes <= window_s / SAFETY_NET_PERIOD_S + 3  # the old clock: 50
    period = c2_daemon.outputs[0].driver.period_s
    assert statistics.median(ages) < period, ages  # one tick's age at most, most of the time


def sample_snapshot_ages(daemon: Daemon, window_s: float) -> list[float]:
    """The snapshot's age, looked at every few ms for `window_s`."""
    ages: list[float] = []
    end = time.monotonic() + window_s  # the table's clock
    while (now := time.monotonic()) < end:
        ages.append(now - daemon.table.snapshot().at)
        threading.Event().wait(0.003)
    return ages


def test_the_clock_steps_a_table_no_driver_stepped_within_its_period(tmp_path: Path) -> None:
    """The safety net: with outputs built but no driver ticking (stalled, or not started),
    the clock still steps the table, once per its period."""
    daemon = Daemon(Config(outputs=(C2,)), ReplayBackend(tmp_path))
    clock = daemon.node_clock
    first = daemon.table.snapshot()
    clock.start()
    try:
        until(lambda: daemon.table.snapshot() is not first, "a step of the clock's")
        stepped = daemon.table.snapshot()
        until(lambda: daemon.table.snapshot() is not stepped, "the next one")
        gap = daemon.table.snapshot().at - stepped.at
    finally:
        clock.stop()
        assert clock.join(WAIT_S)
    assert gap >= clock.period_s - 0.005  # not more often than its period (late: later)


def test_beside_outputs_that_read_some_nodes_only_the_clock_steps_the_others_on_the_grid(
    tmp_path: Path,
) -> None:
    """A node no output reads is stepped by the clock alone: at the grid's period, so its
    device's queue is drained as often as a C2-16B output's would (a hidraw queue holds 64
    reports), and `monitor` shows it fresh. Beside an output that reads every node: the
    safety net."""
    crsf = OutputConfig(protocol="crsf", port="loop://", rate_hz=250, channels=X)
    some = Daemon(Config(outputs=(crsf,)), ReplayBackend(tmp_path))
    assert some.node_clock.period_s == pytest.approx(0.020)
    every = Daemon(Config(outputs=(crsf, C2)), ReplayBackend(tmp_path))
    assert every.node_clock.period_s == pytest.approx(0.240)
