"""The node step (usb2rc.nodes.step, docs/DESIGN.md "Node state: one step per period"): one
step per base period publishes an immutable snapshot; reading it changes nothing, so the
guard arms and the trims step whichever outputs read, and whether any does."""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest
from daemon_harness import (
    RELEASED,
    T16000M_DESCRIPTOR,
    RecordSource,
    StickState,
    UdpLine,
    channels,
    install,
    of_type,
    pwm_of_int16,
    scale,
    timed_recording,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from table_reader import TableReader

from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import Daemon
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.hid.replay import ReplayBackend
from usb2rc.nodes.binding import default_binding
from usb2rc.nodes.guard import REST_S
from usb2rc.nodes.step import BASE_PERIOD_S
from usb2rc.nodes.table import NodeTable

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)
BINDING = default_binding(LAYOUT, "T.16000M")  # X, Y, Rz guarded at the centre
INFO = DeviceInfo(key="k0", path="k0", vid=0x044F, pid=0xB10A, product="T.16000M")


def free_udp_port() -> int:
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port: int = probe.getsockname()[1]
    probe.close()
    return port


def jittering_stick(seconds: float, every_s: float = 0.01) -> str:
    """A stick at rest that keeps reporting (its sensor jitters by one count): each of its
    records is fresh, so only a step after REST_S of them can arm it."""
    count = int(seconds / every_s)
    return timed_recording([(i * every_s, StickState(x=8192 + i % 2)) for i in range(count)])


def test_a_udpin_output_nobody_called_does_not_delay_arming(tmp_path: Path) -> None:
    """The only output is MAVLink `udpin` and no vehicle has called: it never reads the node
    table. The stick at rest arms anyway (docs/ICD.md, "Neutral guard"): the master clock
    steps the table; when the vehicle calls, its first override is already the stick's.
    (Before, only an output's read armed it: the node stayed `!`.)"""
    install(tmp_path / "stick.hid", jittering_stick(30.0))
    port = free_udp_port()
    outputs = (OutputConfig(protocol="mavlink", port=f"udpin:127.0.0.1:{port}"),)
    daemon = Daemon(Config(outputs=outputs), ReplayBackend(tmp_path))
    vehicle = UdpLine()
    daemon.start()
    try:
        deadline = time.monotonic() + 10
        while daemon.table.describe().get("0", {}).get("failsafe", True):
            assert time.monotonic() < deadline, daemon.table.describe()
            threading.Event().wait(0.02)
        assert daemon.outputs[0].driver.stats.writes == 0  # nobody called: nothing sent
        assert not daemon.table.snapshot().nodes[0].frame.failsafe
        first = first_override_once_called(vehicle, port)
        centre = {pwm_of_int16(scale(x, 0, 16383)) for x in (8192, 8193)}
        assert channels(first) != RELEASED and channels(first)[0] in centre
    finally:
        daemon.stop()
        vehicle.close()


def first_override_once_called(vehicle: UdpLine, port: int) -> object:
    """The vehicle calls (heartbeats) until the daemon answers; its first override."""
    from pymavlink.dialects.v20 import common

    mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
    beat = mav.heartbeat_encode(
        common.MAV_TYPE_QUADROTOR, common.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4
    ).pack(mav)
    deadline = time.monotonic() + 10
    while not of_type(vehicle.frames(), "RC_CHANNELS_OVERRIDE"):
        assert time.monotonic() < deadline, "no answer to the vehicle's heartbeats"
        vehicle.sock.sendto(beat, ("127.0.0.1", port))
        threading.Event().wait(0.1)
    return of_type(vehicle.frames(), "RC_CHANNELS_OVERRIDE")[0]


@dataclass
class Clock:
    now: float = 100.0

    def __call__(self) -> float:
        return self.now


STATES = st.builds(
    StickState,
    x=st.sampled_from([8192, 8000, 0, 16383]),
    buttons=st.integers(0, 3),
)
OPS = st.lists(
    st.one_of(
        st.tuples(st.just("report"), STATES),
        st.tuples(st.just("wait"), st.sampled_from([BASE_PERIOD_S, REST_S, 0.001])),
    ),
    min_size=1,
    max_size=25,
)


def record_of(
    state: StickState, reports: int, at: float, presses: tuple[int, ...] = ()
) -> ReaderRecord:
    """A reader's record: `state` decoded, with its press log (the buttons each press put
    down; every press kept, so the newest's serial is their count)."""
    decoder = LAYOUT.make_decoder()
    decoder.feed(state.report())
    return ReaderRecord(decoder.state(), reports, 0, at, presses, len(presses))


def drive(ops: list, readers: int, reads: int) -> list[tuple]:
    """Feed `ops` to a table, one step after each; between steps `readers` threads (one
    output each) read `reads` times. The snapshots' contents, step by step."""
    clock = Clock()
    table = NodeTable(clock=clock)
    outputs = [TableReader(table) for _ in range(readers)]
    source = RecordSource(ReaderRecord(LAYOUT.initial_state(), 0))
    table.add_device(0, INFO, BINDING, source, "JOYSTICK")
    buttons, reports, seen = 0, 0, []
    presses: tuple[int, ...] = ()
    for op in ops:
        if op[0] == "report":
            rising = op[1].buttons & ~buttons
            buttons, reports = op[1].buttons, reports + 1
            if rising:
                presses = (*presses, rising)
            source.record = record_of(op[1], reports, clock.now, presses)
        else:
            clock.now += op[1]
        snapshot = table.step_if_due()
        threads = [
            threading.Thread(target=lambda k=k: [outputs[k].frames() for _ in range(reads)])
            for k in range(readers)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert table.snapshot() is snapshot  # reads never made a new one
        seen.append((snapshot.frames, tuple(n.waiting_for for n in snapshot.nodes)))
    return seen


@settings(max_examples=60, deadline=None)
@given(OPS, st.integers(1, 3), st.integers(1, 4))
def test_reading_the_snapshot_from_many_threads_changes_nothing(
    ops: list, readers: int, reads: int
) -> None:
    """Any number of reads from any number of outputs, in any interleaving, between two
    steps: the same snapshots as a table nobody read."""
    assert drive(ops, readers, reads) == drive(ops, 0, 0)


def test_a_snapshot_is_immutable() -> None:
    table = NodeTable(clock=Clock())
    table.add_device(0, INFO, BINDING, RecordSource(ReaderRecord(LAYOUT.initial_state(), 0)), "J")
    node = table.step_if_due().nodes[0]
    with pytest.raises(AttributeError):
        node.frame = node.frame  # type: ignore[misc]


def test_a_tap_shows_in_exactly_one_frame_of_each_output_whoever_reads_first() -> None:
    """A tap over between two steps: each output's next frame shows it, once, in either
    order of reading (docs/ICD.md, "Taps")."""
    for order in ([0, 1], [1, 0]):
        clock = Clock()
        table = NodeTable(clock=clock)
        outputs = [TableReader(table), TableReader(table)]
        source = RecordSource(record_of(StickState(), 1, clock.now))
        table.add_device(0, INFO, BINDING, source, "JOYSTICK")
        clock.now += REST_S + BASE_PERIOD_S
        assert not table.step_if_due().frames[0].failsafe
        source.record = record_of(StickState(buttons=1), 2, clock.now, (1,))
        source.record = record_of(StickState(), 3, clock.now, (1,))  # released: a tap
        shown = {k: [] for k in outputs}
        for _ in range(2):
            for k in order:
                shown[outputs[k]].append(outputs[k].frames()[0].group1 & 1)
        assert shown == {outputs[0]: [1, 0], outputs[1]: [1, 0]}
        assert table.snapshot().frames[0].group1 & 1 == 0  # the snapshot: as it is


def test_the_node_clock_runs_at_the_fastest_outputs_period_but_not_faster_than_50_hz() -> None:
    """Each driver steps before its ticks; the clock only keeps the snapshot live for what
    reads it without ticking, at the fastest output's period rounded down onto the 4 ms
    grid, and never more often than LIVENESS_PERIOD_S."""
    from usb2rc.nodes.step import LIVENESS_PERIOD_S, clock_period

    assert clock_period([1 / 50]) == pytest.approx(0.020)  # C2-16B alone: 50 wake-ups, not 250
    assert clock_period([1 / 50, 1 / 100]) == pytest.approx(0.020)  # SUMD's 10 ms: no faster
    assert clock_period([1 / 50, 1 / 250]) == pytest.approx(0.020)  # CRSF's 4 ms: no faster
    assert clock_period([1 / 10]) == pytest.approx(0.100)  # a 10 Hz output alone: its own
    assert clock_period([]) == pytest.approx(LIVENESS_PERIOD_S)  # monitor: no output


def clearance_ms(phase: float, period: float, output_periods: list[float]) -> float:
    """How close the clock's steps (phase + k periods, over 2 s) come to any output's tick."""
    closest = period
    for k in range(round(2.0 / period)):
        at = k * period + phase
        for p in output_periods:
            closest = min(closest, at % p, p - at % p)
    return round(closest * 1000, 6)


def test_the_node_clock_steps_where_no_output_ticks() -> None:
    """The clock's phase keeps its steps away from every output's ticks: half its period
    for outputs on its own grid, elsewhere when a slower output's ticks fall on that half."""
    from usb2rc.nodes.step import clock_period, clock_phase

    assert clock_phase(0.020, [1 / 50]) == pytest.approx(0.010)  # C2-16B alone: halfway
    # the default rates of all five outputs: the clock at 20 ms (no faster); halfway (10 ms)
    # falls on SUMD's and SBUS's ticks, 6 ms (or 14) is 2 ms from CRSF's and 4 from theirs
    five = [1 / 50, 1 / 100, 1 / 250, 1 / 100, 1 / 50]
    period = clock_period(five)
    assert clearance_ms(period / 2, period, five) == 0.0
    phase = clock_phase(period, five)
    assert phase in (pytest.approx(0.006), pytest.approx(0.014))
    assert clearance_ms(phase, period, five) == pytest.approx(2.0)
    # CRSF at 500 Hz ticks on every 2 ms: the clock (4 ms) steps between two of them
    assert clock_phase(0.004, [1 / 50, 1 / 500]) == pytest.approx(0.001)
    # rates that share no grid (SBUS at 70 Hz): no phase misses every tick, the best is taken
    odd = [1 / 50, 1 / 70]
    period = clock_period(odd)
    best = clearance_ms(clock_phase(period, odd), period, odd)
    assert best >= 0.2
    assert all(clearance_ms(period * i / 40, period, odd) <= best + 0.1 for i in range(40))


def test_the_node_clock_leaves_alone_a_table_a_driver_stepped_within_its_period(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every step drains the devices (the readers are pulled): beside one output or
    several, the node clock steps only a table no driver stepped within its period."""
    c2 = OutputConfig(protocol="c2-16b", port="loop://", rate_hz=50)
    sumd = OutputConfig(protocol="sumd", port="loop://", channels=("node0.x",))
    ages: list[float] = []
    for outputs in ((c2,), (c2, sumd)):
        daemon = Daemon(Config(outputs=outputs), ReplayBackend(tmp_path))
        # the clock's step asks the daemon's table (a compiled NodeTable: its methods cannot
        # be swapped) when it steps: a recorder in its place notes the age it is asked for
        monkeypatch.setattr(daemon, "table", SimpleNamespace(step_if_stale=ages.append))
        daemon.node_clock._step()
        assert ages.pop() == pytest.approx(daemon.node_clock.period_s)


def test_the_node_clock_steps_halfway_between_two_grid_ticks() -> None:
    """The drivers tick on the multiples of the period; the clock steps half a period off
    them, so its wake-up and step never make a tick wait."""
    from usb2rc.nodes.step import GRID_EPOCH_S, NodeClock

    period = 0.020
    node_clock = NodeClock(lambda: None, Clock(), period)
    tick = GRID_EPOCH_S + 5000 * period  # a grid tick on the monotonic clock
    halfway = tick + period / 2
    assert tick + node_clock.until_next_step(tick) == pytest.approx(halfway)
    assert node_clock.until_next_step(halfway) == pytest.approx(period)  # on time: the next
    assert node_clock.until_next_step(halfway - 0.00005) == pytest.approx(period + 0.00005)
    late = halfway + 0.6 * period  # a step that ran late waits for the next halfway point
    assert late + node_clock.until_next_step(late) == pytest.approx(halfway + period)


def test_the_node_clock_does_not_step_again_what_a_driver_stepped_within_its_period() -> None:
    """`step_if_stale(age)`, the node clock's call: no step when one ran in the last `age`
    (a driver's, before its tick: the snapshot is that fresh already), the step when none
    did (no output ticks, or none in that long)."""
    from usb2rc.nodes.step import GRID_EPOCH_S

    now = [GRID_EPOCH_S + 1000 * 0.004 + 0.001]
    table = NodeTable(clock=lambda: now[0])
    driver_step = table.step_if_due()  # a driver, before its tick
    now[0] += 0.003
    assert table.step_if_stale(0.004) is driver_step  # 3 ms old: not stepped again
    assert table.step_if_due() is not driver_step  # (a new period: a driver would step)
    stepped = table.snapshot()
    now[0] += 0.0045
    assert table.step_if_stale(0.004) is not stepped  # 4.5 ms old: the clock steps
    assert table.step_if_stale(0.004) is table.snapshot()  # and not twice
