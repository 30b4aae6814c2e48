"""The one driver (`usb2rc.lines.driver.LineDriver`) running its own thread over real links: a pty
whose far end stops reading and reads again, and pyserial's `loop://` whose port fails under
its reader thread. What is judged is what reaches the far end, decoded."""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, NamedTuple

import pytest
import serial
from daemon_harness import PtyLine, StickState
from test_node_table_driver import BINDING, Source, info

from usb2rc.lines.driver import (
    LEAD_FIRST_S,
    LEAD_MARGIN_S,
    LEAD_MAX_SHARE,
    LEAD_WINDOW,
    DriverThread,
    Lead,
    LineDriver,
)
from usb2rc.lines.rx import LinkReader
from usb2rc.lines.serial_link import SerialLink
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.nodes.step import GRID_EPOCH_S, aligned, kernel_tick_s
from usb2rc.nodes.table import NodeTable
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.sumd.channels import SumdChannels
from usb2rc.protocols.sumd.session import SumdSession

WAIT_S = 10.0  # a safety net: every wait ends on its condition
Service = c2_16b.Service


class StallingPty(PtyLine):
    """A pty far end that stops reading while `reads` is clear."""

    def __init__(self) -> None:
        self.reads = threading.Event()
        self.reads.set()
        super().__init__("c2-16b")

    def _reading(self) -> bool:
        if self.reads.is_set():
            return True
        self.reads.wait(0.05)
        return False


def until(condition: Callable[[], Any], what: str) -> Any:
    deadline = time.monotonic() + WAIT_S
    while not (result := condition()):
        assert time.monotonic() < deadline, f"never: {what}"
        time.sleep(0.01)
    return result


def names(frames: list[Any]) -> list[str]:
    return [
        f.service.service_name if isinstance(f, c2_16b.ServiceFrame) else chr(f.status)
        for f in frames
    ]


def test_a_c2_line_on_a_pty_stalls_starts_over_when_read_again_and_stops_failsafe() -> None:
    far = StallingPty()
    table = NodeTable()
    for node in range(4):  # 4 frames a tick at 200 Hz: the pty's ~20 KB fill in a second
        stick = info(f"k{node}", f"1-{node}")
        table.add_device(node, stick, BINDING, Source.of(StickState()), "JOYSTICK")
    link = SerialLink(far.path, 921600)
    session = C2Session(far.path, C2Settings(rate_hz=200, baudrate=921600, version="0.1.0"))
    driver = LineDriver("c2", link, session, table.step_if_due, 1 / 200)
    thread = DriverThread("drivers", [driver])
    assert link.open_now()
    thread.start()
    try:
        far.wait_for(lambda frames: ">" in names(frames), WAIT_S)
        far.reads.clear()  # the far end stops reading: the pty fills, the line stalls
        until(lambda: driver.stats.stalls >= 1, "a stall")
        assert session.stalled
        before = len(far.frames())
        far.reads.set()  # it reads again: what the pty held is dropped, the line starts over

        def restarted(frames: list[Any]) -> bool:
            after = names(frames[before:])
            if "startup" not in after:
                return False
            fresh = after[len(after) - after[::-1].index("startup") :]
            return fresh[:4] == ["connected", "vid-pid", "device-string", "device-type"] and (
                ">" in fresh[4:]
            )

        far.wait_for(restarted, WAIT_S)
        assert link.stats.flushes >= 1
    finally:
        thread.stop()
        thread.join(WAIT_S)
    assert not thread.is_alive()
    last = [f for f in far.wait_for(lambda frames: frames) if isinstance(f, c2_16b.DataFrame)]
    assert last[-1].status == c2_16b.FAILSAFE  # the stop's `!` went out before the close
    far.close()


class FailingReads:
    """pyserial's `serial_for_url`, its `loop://` ports' reads failing while `fail` is set."""

    def __init__(self) -> None:
        self.fail = threading.Event()
        self.ports: list[serial.SerialBase] = []
        self._real = serial.serial_for_url

    def __call__(self, url: str, **kwargs: Any) -> serial.SerialBase:
        port = self._real("loop://", **kwargs)
        real_read = port.read

        def read(size: int = 1) -> bytes:
            if self.fail.is_set():
                self.fail.clear()
                raise serial.SerialException("device disconnected")
            data: bytes = real_read(size)
            return data

        port.read = read  # type: ignore[method-assign]
        self.ports.append(port)
        return port


def test_a_crsf_line_on_loop_reads_its_far_end_and_comes_back_after_a_lost_port(
    monkeypatch: Any,
) -> None:
    """loop:// echoes the RC frames: the reader thread hands them to the driver, which gives
    them to the session (counted as the module's frames). A read that fails loses the line;
    the driver reopens it and the frames go on."""
    opener = FailingReads()
    monkeypatch.setattr(serial, "serial_for_url", opener)
    table = NodeTable()
    table.add_device(0, info("a", "1-1"), BINDING, Source.of(StickState()), "JOYSTICK")
    channels = OutputChannels.scaled([ChannelSource(0, "axis", 0)], RC11_SCALE, crsf.RC_FRAME_LEN)
    session = CrsfSession("crsf", channels, CrsfModule(0.01))
    link = SerialLink("loop://", 400000, reopen_interval_s=0.05)
    driver = LineDriver("crsf", link, session, table.step_if_due, 0.01)
    thread = DriverThread("drivers", [driver])
    reader = LinkReader("crsf-rx", link)
    assert link.open_now()
    thread.start()
    reader.start()
    try:
        until(lambda: session.module.decoder.frames >= 5, "the far end's frames")
        opener.fail.set()  # the next read fails: the driver closes the port and reopens it
        until(lambda: link.stats.losses == 1 and link.stats.opens == 2, "a reopened port")
        heard = session.module.decoder.frames
        until(lambda: session.module.decoder.frames >= heard + 5, "frames on the new port")
        assert session.line_open and len(opener.ports) == 2
    finally:
        thread.stop()
        reader.stop()
        thread.join(WAIT_S)
        reader.join(WAIT_S)
    assert driver.stats.tick_errors == 0
    took = driver.stats.tick_durations()  # one per tick, what `tick_p99_ms` reads
    assert len(took) == driver.stats.ticks and all(0 < t < 1 for t in took)
    assert driver.stats.tick_p99_ms() == sorted(took)[int(len(took) * 0.99)] * 1000


def test_no_tick_falls_on_the_kernels_own_ticks() -> None:
    """Linux runs its tick, and the timer-wheel work that tick wakes (kworkers, kdamond), on
    the multiples of 1/HZ on the monotonic clock; a write there waited for such a thread
    (bench/README.md, "Issue 21: the grid half a kernel tick off the kernel's"). Every tick
    of a period that is a whole number of kernel ticks (20 ms at HZ 100, 250, 300, 1000)
    falls three quarters of the way to the next, and of a period of an odd number of half
    ticks (SUMD's 10 ms and CRSF's 2 ms at HZ 250) a quarter tick from one, wherever the
    output started. (From half a tick, every other of the latter fell on one.)"""
    tick = kernel_tick_s()
    if not tick:
        pytest.skip("the kernel's tick is not known on this platform")
    assert round(1 / tick) in {100, 250, 300, 1000}
    assert tick * 3 / 4 == pytest.approx(GRID_EPOCH_S)
    for period in {0.02, tick, 2 * tick, 5 * tick, tick / 2, 1.5 * tick, 2.5 * tick}:
        for now in (0.0, 123.4567, 98765.4321, 5000.0 + tick / 2 + 1e-7):
            first = aligned(now, period)
            for k in range(50):
                into_the_kernel_tick = (first + k * period) % tick
                off_the_kernel_tick = min(into_the_kernel_tick, tick - into_the_kernel_tick)
                assert off_the_kernel_tick == pytest.approx(tick / 4, abs=1e-6)


def test_every_driver_ticks_on_multiples_of_its_period_from_one_epoch() -> None:
    """Two outputs started apart, at 50 and 100 Hz: every tick of the first is one of the
    second's (the first tick is the next multiple of the period from the grid's epoch on the
    monotonic clock)."""
    epoch = GRID_EPOCH_S
    assert aligned(epoch, 0.02) == epoch and aligned(epoch + 0.0201, 0.02) == epoch + 0.04
    first, second = aligned(123.4567, 0.02), aligned(123.4612, 0.01)
    assert round((first - epoch) / 0.02) * 0.02 == pytest.approx(first - epoch, abs=1e-9)
    assert round((second - epoch) / 0.01) * 0.01 == pytest.approx(second - epoch, abs=1e-9)
    assert 123.4567 <= first < 123.4567 + 0.02 and 123.4612 <= second < 123.4612 + 0.01
    fifty = {round(first + k * 0.02, 6) for k in range(10)}
    hundred = {round(second + k * 0.01, 6) for k in range(20)}
    assert fifty - {round(first, 6)} <= hundred


class TimedWrites(NamedTuple):
    drivers: list[LineDriver]
    writes: list[dict[str, Any]]  # per write: see `timed_writes`
    steps: list[float]  # when the node table was asked for a step (a snapshot)


def timed_writes(
    protocols: list[str], enough: Callable[[list[dict[str, Any]]], bool] | None = None
) -> TimedWrites:
    """A driver of each of `protocols` ("c2-16b" at 100 Hz, "sumd" at 200 Hz, "crsf" at
    100 Hz, sending: its node is live), each over its own pty, on one drivers' thread,
    until each wrote 60 ticks (or `enough` says so of the writes); per write: which output,
    the tick's deadline and planned start, when the tick began, made its bytes (from which
    snapshot) and wrote them. The final ticks (at once, on stop) are left out."""
    table = NodeTable()
    table.add_device(0, info("k0", "1-0"), BINDING, Source.of(StickState()), "JOYSTICK")
    outputs = len(protocols)
    fars = [PtyLine(protocol) for protocol in protocols]
    drivers = []
    written: list[dict[str, Any]] = []
    steps: list[float] = []
    stopping = threading.Event()

    def step_if_due(node_ids: frozenset[int] | None = None) -> Any:
        steps.append(time.monotonic())
        return table.step_if_due(node_ids)

    for index, (protocol, far) in enumerate(zip(protocols, fars, strict=True)):
        link = SerialLink(far.path, 921600)
        session: C2Session | SumdSession | CrsfSession
        if protocol == "sumd":
            channels = SumdChannels.of([ChannelSource(0, "axis", 0), ChannelSource(0, "axis", 1)])
            session = SumdSession(far.path, channels, channels.frame_length, 200.0)
        elif protocol == "crsf":
            axes = [ChannelSource(0, "axis", 0), ChannelSource(0, "axis", 1)]
            scaled = OutputChannels.scaled(axes, RC11_SCALE, crsf.RC_FRAME_LEN)
            session = CrsfSession(far.path, scaled, CrsfModule(0.01))
        else:
            settings = C2Settings(rate_hz=100, baudrate=921600, version="0.1.0")
            session = C2Session(far.path, settings)
        period_s = session.period_s
        name = f"{protocol}-{index}"
        timed = Timed(index, link, session, written, stopping)
        driver = LineDriver(
            name, timed.link, timed.session, step_if_due, period_s, alone=outputs == 1
        )
        drivers.append(driver)
        timed.driver = driver
        assert link.open_now()
    thread = DriverThread("drivers", drivers)
    thread.start()
    try:
        if enough is None:
            until(lambda: _each_wrote(written, outputs, 60), "60 written ticks of each output")
        else:
            until(lambda: enough(list(written)), "the writes the test needs")
    finally:
        stopping.set()
        thread.stop()
        thread.join(WAIT_S)
        for far in fars:
            far.close()
    return TimedWrites(drivers, [w for w in written if not w["final"]], steps)


def _each_wrote(written: list[dict[str, Any]], outputs: int, ticks: int) -> bool:
    """Whether each of the outputs `0..outputs-1` wrote `ticks` ticks or more."""
    counts = Counter(w["output"] for w in list(written))
    return all(counts[index] >= ticks for index in range(outputs))


class Timed:
    """Notes on `written` when each of a driver's ticks began, made its bytes, wrote them,
    through the session and the link it is given (the driver's own methods, compiled, cannot
    be wrapped): a tick begins with its first look at the link (`is_open`, which only a
    tick's start reads), makes its bytes in `session.tick` and writes them in `link.write`;
    its deadline and start are the driver's then."""

    def __init__(
        self,
        index: int,
        link: Any,
        session: Any,
        written: list[dict[str, Any]],
        stopping: threading.Event,
    ) -> None:
        self.driver: LineDriver | None = None
        this_tick: dict[str, Any] = {}
        timed = self

        class TimedLink:
            def __getattr__(self, name: str) -> Any:
                return getattr(link, name)

            @property
            def is_open(self) -> bool:
                driver = timed.driver
                assert driver is not None
                this_tick.clear()
                this_tick.update(
                    output=index,
                    deadline=driver.deadline,
                    start=driver.start,
                    began=time.monotonic(),
                )
                return bool(link.is_open)

            def write(self, data: bytes) -> Any:
                final = stopping.is_set()
                written.append({**this_tick, "written": time.monotonic(), "final": final})
                return link.write(data)

        class TimedSession:
            def __getattr__(self, name: str) -> Any:
                return getattr(session, name)

            def tick(self, now: float, snapshot: Any) -> bytes:
                this_tick.update(made=time.monotonic(), snapshot=snapshot)
                return bytes(session.tick(now, snapshot))

        self.link, self.session = TimedLink(), TimedSession()


def on_the_grid(deadline: float, period_s: float) -> bool:
    steps = (deadline - GRID_EPOCH_S) / period_s
    return round(steps) == pytest.approx(steps, abs=1e-6)


def by_deadline(writes: list[dict[str, Any]]) -> dict[float, list[dict[str, Any]]]:
    """The writes of each deadline, in the order they were written."""
    ticks: dict[float, list[dict[str, Any]]] = {}
    for w in writes:
        ticks.setdefault(round(w["deadline"], 6), []).append(w)
    return ticks


def test_outputs_due_together_are_made_from_one_snapshot_and_each_written_once_made() -> None:
    """Several C2-16B outputs on the drivers' thread: none makes its bytes ahead (C2-16B's
    far end times its frames to the period, not to the microsecond); the ticks due together
    start on their deadline, are made from one step of the node table, asked for once, and
    each is written as soon as it is made, in config order: the first output's write waits
    for the step and its own bytes only, as the only output's does."""
    drivers, on_grid, steps = timed_writes(["c2-16b"] * 3)
    assert not any(driver.leads for driver in drivers)
    for w in on_grid:
        assert w["start"] == w["deadline"] and on_the_grid(w["deadline"], 0.01)
        assert w["deadline"] <= w["began"] <= w["made"] <= w["written"]
    ticks = by_deadline(on_grid)
    deadlines = sorted(ticks)
    together = [at for at in deadlines if len(ticks[at]) == 3]
    assert len(together) >= 50
    for before, at in zip([None, *deadlines], deadlines, strict=False):
        tick = ticks[at]
        if len(tick) != 3:
            continue
        assert [w["output"] for w in tick] == [0, 1, 2]  # in config order
        for first, then in itertools.pairwise(tick):
            assert first["written"] <= then["made"]  # written before the next is made
        # one step asked for since the tick before was made: not counted from the planned
        # start, which a late tick before (a loaded host) may have stepped after
        made = max(w["made"] for w in tick)
        since = max(w["made"] for w in ticks[before]) if before is not None else -math.inf
        assert sum(since < step <= made for step in steps) == 1
        assert len({id(w["snapshot"]) for w in tick}) == 1  # one step's values


def test_the_only_output_reads_the_records_on_its_deadline_and_writes_them_at_once() -> None:
    """No lead: each tick wakes on its deadline (on the grid, from its epoch), makes its
    frame from the records then and writes it at once: never before the deadline, never
    from records read ahead of it (a lead would age every frame's records by itself)."""
    (driver,), on_grid, _ = timed_writes(["c2-16b"])
    assert len(on_grid) >= 60 and driver.lead is None
    for w in on_grid:
        assert w["start"] == w["deadline"] and on_the_grid(w["start"], 0.01)
        assert w["deadline"] <= w["began"] <= w["made"] <= w["written"]


def test_an_output_whose_far_end_times_its_frames_is_made_and_written_first() -> None:
    """SUMD's receiver takes a frame whenever it comes; C2-16B's times its frames. Listed
    after SUMD, C2-16B's ticks due with SUMD's are still made and written first, from one
    snapshot, so SUMD's work never moves C2-16B's write. SUMD's ticks on their own wake on
    their deadline, read the records then and write at once (one wake-up a tick)."""
    (sumd, c2), on_grid, _ = timed_writes(["sumd", "c2-16b"])
    assert not sumd.leads and not c2.leads
    ticks = by_deadline(on_grid)
    own = [tick[0] for tick in ticks.values() if [w["output"] for w in tick] == [0]]
    together = [tick for tick in ticks.values() if len(tick) == 2]
    assert len(own) >= 20 and len(together) >= 20
    for w in own:
        assert w["start"] == w["deadline"] and on_the_grid(w["deadline"], 0.005)
        assert w["deadline"] <= w["began"] <= w["made"] <= w["written"]
    for c2_write, sumd_write in together:
        assert (c2_write["output"], sumd_write["output"]) == (1, 0)
        assert c2_write["snapshot"] is sumd_write["snapshot"]  # made together, one step
        assert c2_write["deadline"] <= c2_write["written"] <= sumd_write["made"]


def test_crsf_makes_its_frames_ahead_while_it_sends_and_the_ticks_due_with_it_are_held() -> None:
    """A sending CRSF output (its module times the frames to the microsecond) makes its
    bytes a lead ahead of its deadline, and so does C2-16B beside it (the thread wakes
    twice a tick anyway, and a batch started on CRSF's lead alone could outgrow it); the
    ticks due together are made in one batch, from one snapshot, and both are written on
    the deadline, never before it, C2-16B first (config order among the outputs whose
    far end times their frames)."""

    def made_in_time(writes: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
        """The ticks due together whose bytes were all made before their deadline (one
        that is not, early or on a loaded host, writes at once: not judged here)."""
        ticks = by_deadline([w for w in writes if not w["final"]]).values()
        return [t for t in ticks if len(t) == 2 and max(w["made"] for w in t) < t[0]["deadline"]]

    (c2, crsf_driver), on_grid, _ = timed_writes(
        ["c2-16b", "crsf"], lambda writes: len(made_in_time(writes)) >= 30
    )
    assert crsf_driver.leads and c2.leads
    assert crsf_driver.lead is not None and 0.0 < crsf_driver.lead.s <= 0.01 * LEAD_MAX_SHARE
    for c2_write, crsf_write in made_in_time(on_grid):
        assert (c2_write["output"], crsf_write["output"]) == (0, 1)
        assert c2_write["snapshot"] is crsf_write["snapshot"]
        assert crsf_write["start"] < crsf_write["deadline"] <= c2_write["written"]
        assert max(c2_write["made"], crsf_write["made"]) <= c2_write["written"]
        assert c2_write["written"] <= crsf_write["written"]


def test_the_lead_is_the_ticks_recent_cost_and_one_held_up_tick_does_not_move_it() -> None:
    lead = Lead(0.02)
    assert lead.s == LEAD_FIRST_S
    costs = [0.0003] * (LEAD_WINDOW - 2) + [0.009, 0.012]  # two ticks the host held up
    for cost in costs:
        lead.took(cost, 0.02)
    assert lead.s == pytest.approx(0.0003 + LEAD_MARGIN_S)
    for _ in range(LEAD_WINDOW):  # a machine slower than a quarter period: capped there
        lead.took(0.009, 0.02)
    assert lead.s == pytest.approx(0.02 * LEAD_MAX_SHARE)
    for _ in range(LEAD_WINDOW):  # a faster one: the lead follows it back down
        lead.took(0.00001, 0.02)
    assert lead.s == pytest.approx(0.00001 + LEAD_MARGIN_S)
    assert Lead(0.001).s == pytest.approx(0.001 * LEAD_MAX_SHARE)  # CRSF at 1 kHz


def test_an_output_whose_far_end_stops_reading_does_not_hold_the_others() -> None:
    """One thread drives every output: C2-16B's far end stops reading, its pty fills and its
    line stalls (the thread waits on that pty between ticks), and SUMD's frames go on at
    their rate meanwhile; when it reads again, C2-16B starts over and SUMD never stopped."""
    c2_far, sumd_far = StallingPty(), PtyLine("sumd")
    table = NodeTable()
    for node in range(4):  # 4 frames a tick at 200 Hz: the pty's ~20 KB fill in a second
        stick = info(f"k{node}", f"1-{node}")
        table.add_device(node, stick, BINDING, Source.of(StickState()), "JOYSTICK")
    c2_link, sumd_link = SerialLink(c2_far.path, 921600), SerialLink(sumd_far.path, 115200)
    c2_session = C2Session(c2_far.path, C2Settings(rate_hz=200, baudrate=921600, version="0.1.0"))
    channels = SumdChannels.of([ChannelSource(0, "axis", 0), ChannelSource(0, "axis", 1)])
    sumd_session = SumdSession(sumd_far.path, channels, channels.frame_length, 100.0)
    c2 = LineDriver("c2", c2_link, c2_session, table.step_if_due, 1 / 200)
    sumd_out = LineDriver("sumd", sumd_link, sumd_session, table.step_if_due, 1 / 100)
    thread = DriverThread("drivers", [c2, sumd_out])
    assert c2_link.open_now() and sumd_link.open_now()
    thread.start()
    try:
        c2_far.wait_for(lambda frames: ">" in names(frames), WAIT_S)
        c2_far.reads.clear()  # C2-16B's far end stops reading
        until(lambda: c2.stats.stalls >= 1, "C2-16B's line stalled")
        heard = len(sumd_far.frames())
        until(lambda: len(sumd_far.frames()) >= heard + 50, "SUMD's frames while C2 stalls")
        assert c2_session.stalled and sumd_out.stats.stalls == 0
        c2_far.reads.set()
        until(lambda: not c2_session.stalled, "C2-16B's line taking bytes again")
        heard = len(sumd_far.frames())
        until(lambda: len(sumd_far.frames()) >= heard + 10, "SUMD's frames after")
    finally:
        thread.stop()
        thread.join(WAIT_S)
        c2_far.close()
        sumd_far.close()
    assert c2.stats.tick_errors == sumd_out.stats.tick_errors == 0
