"""The one driver (`usb2rc.lines.driver.Driver`) running its own thread over real links: a pty
whose far end stops reading and reads again, and pyserial's `loop://` whose port fails under
its reader thread. What is judged is what reaches the far end, decoded."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest
import serial
from daemon_harness import PtyLine, StickState
from test_node_table_driver import BINDING, Source, info

from usb2rc.hid.reader import LAST_CALL_S, reader_pause
from usb2rc.lines.driver import (
    LEAD_FIRST_S,
    LEAD_MARGIN_S,
    LEAD_MAX_SHARE,
    LEAD_WINDOW,
    WRITE_SPACING_S,
    Driver,
    Lead,
    Pace,
    aligned,
    earliest,
    write_offset,
)
from usb2rc.lines.rx import LinkReader
from usb2rc.lines.serial_link import SerialLink
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.nodes.step import GRID_EPOCH_S, kernel_tick_s
from usb2rc.nodes.table import NodeTable
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Line
from usb2rc.protocols.channels import RC11_SCALE, OutputChannels
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.session import CrsfLine, CrsfSession

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
    session = C2Line(far.path, C2Settings(rate_hz=200, baudrate=921600, version="0.1.0"))
    driver = Driver("c2", link, session, table.step_if_due, 1 / 200)
    assert link.open_now()
    driver.start()
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
        driver.stop()
        driver.join(WAIT_S)
    assert not driver.is_alive()
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
    session = CrsfLine("crsf", channels, CrsfSession(0.01))
    link = SerialLink("loop://", 400000, reopen_interval_s=0.05)
    driver = Driver("crsf", link, session, table.step_if_due, 0.01)
    reader = LinkReader("crsf-rx", link)
    assert link.open_now()
    driver.start()
    reader.start()
    try:
        until(lambda: session.engine.decoder.frames >= 5, "the far end's frames")
        opener.fail.set()  # the next read fails: the driver closes the port and reopens it
        until(lambda: link.stats.losses == 1 and link.stats.opens == 2, "a reopened port")
        heard = session.engine.decoder.frames
        until(lambda: session.engine.decoder.frames >= heard + 5, "frames on the new port")
        assert session.line_open and len(opener.ports) == 2
    finally:
        driver.stop()
        reader.stop()
        driver.join(WAIT_S)
        reader.join(WAIT_S)
    assert driver.stats.tick_errors == 0
    took = driver.stats.tick_durations()  # one per tick, what `tick_p99_ms` reads
    assert len(took) == driver.stats.ticks and all(0 < t < 1 for t in took)
    assert driver.stats.tick_p99_ms() == sorted(took)[int(len(took) * 0.99)] * 1000


def test_every_tick_falls_half_a_kernel_tick_off_the_kernels_own_ticks() -> None:
    """Linux runs its tick, and the timer-wheel work that tick wakes (kworkers, kdamond), on
    the multiples of 1/HZ on the monotonic clock; a write there waited for such a thread
    (bench/README.md, "Issue 21: the grid half a kernel tick off the kernel's"). Every tick
    of a period that is a whole number of kernel ticks (20 ms at HZ 100, 250, 300, 1000)
    falls halfway between two of them, wherever the output started."""
    tick = kernel_tick_s()
    if not tick:
        pytest.skip("the kernel's tick is not known on this platform")
    assert round(1 / tick) in {100, 250, 300, 1000}
    assert tick / 2 == pytest.approx(GRID_EPOCH_S)
    for period in {0.02, tick, 2 * tick, 5 * tick}:
        for now in (0.0, 123.4567, 98765.4321, 5000.0 + tick / 2 + 1e-7):
            first = aligned(now, period)
            for k in range(50):
                into_the_kernel_tick = (first + k * period) % tick
                assert into_the_kernel_tick == pytest.approx(tick / 2, abs=1e-6)


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
    assert earliest([Pace(0.0, 0.02), Pace(2.0, 0.01), Pace(1.5, 0.02)], 1.0) == Pace(
        1.5, pytest.approx(0.02)
    )
    assert earliest([Pace(0.0, 0.02)], 1.0) is None  # nobody ticks yet


def test_the_readers_pace_is_the_next_tick_and_the_gap_to_the_one_after_of_any_output() -> None:
    """C2-16B (20 ms) and SUMD (10 ms) due together: the tick after is SUMD's, 10 ms on,
    whichever the readers read first; CRSF (4 ms) at 8 ms and SUMD at 10 ms: 2 ms on."""
    now = 0.99
    both = earliest([Pace(1.00, 0.020), Pace(1.00, 0.010)], now)
    assert both == Pace(1.00, pytest.approx(0.010))
    both = earliest([Pace(1.00, 0.010), Pace(1.00, 0.020)], now)
    assert both == Pace(1.00, pytest.approx(0.010))
    crsf_then_sumd = earliest([Pace(0.008, 0.004), Pace(0.010, 0.010)], 0.0)
    assert crsf_then_sumd == Pace(0.008, pytest.approx(0.002))
    # C2-16B due at 0.9995 and SUMD 0.2 ms after it (a CRSF module's phase next to the
    # grid, say): one tick for the readers
    together = earliest([Pace(0.9995, 0.020), Pace(0.9997, 0.010)], now)
    assert together == Pace(0.9995, pytest.approx(1.0097 - 0.9995))
    assert earliest([Pace(1.0, 0.001)], now) == Pace(1.0, pytest.approx(0.001))  # CRSF 1 kHz


def test_a_driver_in_its_tick_paces_the_readers_on_its_next_tick() -> None:
    """C2-16B's tick began at 0.9995 and has not written yet: its records are read, so a
    reader asking now sleeps until the next tick of any output (SUMD's at 1.0097), not
    until the deadline it has passed. That passed deadline had given a reader no pause at
    all on a fast grid: it polled through every tick, a drain per report."""
    c2_mid_tick, sumd = Pace(0.9995, 0.020), Pace(1.0097, 0.010)
    now = 0.9998
    assert earliest([c2_mid_tick, sumd], now) == Pace(1.0097, pytest.approx(1.0195 - 1.0097))
    assert earliest([c2_mid_tick], now) == Pace(pytest.approx(1.0195), pytest.approx(0.020))
    crsf_mid_tick = Pace(0.9995, 0.004)  # CRSF at 250 Hz, alone
    tick = earliest([crsf_mid_tick], now)
    assert tick is not None and reader_pause(tick, now) == pytest.approx(1.0035 - LAST_CALL_S - now)


def timed_writes(alone: bool, write_offset_s: float = 0.0) -> tuple[Driver, list[dict[str, Any]]]:
    """A C2-16B driver at 100 Hz over a pty, 60 ticks or more; per write: the tick's
    deadline and planned start, the pace the readers saw, when it woke, made its bytes and
    wrote them, and whether it was a final tick (at once, on stop)."""
    far = PtyLine("c2-16b")
    table = NodeTable()
    table.add_device(0, info("k0", "1-0"), BINDING, Source.of(StickState()), "JOYSTICK")
    link = SerialLink(far.path, 921600)
    session = C2Line(far.path, C2Settings(rate_hz=100, baudrate=921600, version="0.1.0"))
    driver = Driver(
        "c2", link, session, table.step_if_due, 0.01, alone=alone, write_offset_s=write_offset_s
    )
    this_tick: dict[str, Any] = {}
    written: list[dict[str, Any]] = []
    session_tick, link_write, tick = session.tick, link.write, driver.tick

    def recorded_tick(deadline: float | None = None, start: float = 0.0) -> None:
        this_tick.clear()
        this_tick.update(deadline=deadline, start=start, pace=driver.pace, woke=time.monotonic())
        tick(deadline, start)

    def timed_session_tick(now: float, snapshot: Any) -> bytes:
        this_tick["made"] = time.monotonic()
        return session_tick(now, snapshot)

    def timed_write(data: bytes) -> Any:
        written.append({**this_tick, "written": time.monotonic()})
        return link_write(data)

    driver.tick = recorded_tick  # type: ignore[method-assign]
    session.tick = timed_session_tick  # type: ignore[method-assign]
    link.write = timed_write  # type: ignore[method-assign]
    assert link.open_now()
    driver.start()
    try:
        until(lambda: len(written) >= 60, "60 written ticks")
    finally:
        driver.stop()
        driver.join(WAIT_S)
        far.close()
    return driver, [w for w in written if w["deadline"] is not None]  # not the final ticks


def on_the_grid(deadline: float, period_s: float) -> bool:
    steps = (deadline - GRID_EPOCH_S) / period_s
    return round(steps) == pytest.approx(steps, abs=1e-6)


def test_one_of_several_outputs_makes_its_bytes_ahead_and_writes_them_on_its_deadline() -> None:
    """The records are read and the frame made `lead` before the deadline; the write waits
    for the deadline, so frames go out on the grid whatever the step, the session and the
    other outputs' ticks cost. The readers pace on the tick's start, not on its write."""
    driver, on_grid = timed_writes(alone=False)
    assert len(on_grid) >= 60
    for w in on_grid:
        assert w["start"] < w["deadline"] <= w["written"]  # never before its moment
        assert w["made"] <= w["written"] and on_the_grid(w["deadline"], 0.01)
        assert w["pace"].deadline == w["start"]  # what the readers pace on
    assert driver.lead is not None and 0.0 < driver.lead.s <= 0.01 * LEAD_MAX_SHARE


def test_an_output_listed_after_others_reads_with_them_and_writes_its_offset_later() -> None:
    """Outputs due together start together (the readers wake once for all of them) but
    write apart: this one's write waits for its deadline and its offset, never less."""
    offset = write_offset(2, 5)
    driver, on_grid = timed_writes(alone=False, write_offset_s=offset)
    assert len(on_grid) >= 60 and driver.write_offset_s == offset > 0.0
    for w in on_grid:
        assert w["pace"].deadline == w["start"] < w["deadline"] and on_the_grid(w["deadline"], 0.01)
        # bytes ready late (the host held the tick) go at once: never before their moment
        assert w["made"] <= w["written"] and w["deadline"] + offset <= w["written"]


def test_outputs_write_in_their_config_order_within_half_a_kernel_tick_of_the_grid(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The first listed writes on the grid; each other WRITE_SPACING_S after the one before,
    closer together where that would reach the kernel's next tick (half a tick after the
    grid, `nodes.step.GRID_EPOCH_S`)."""
    from usb2rc.lines import driver as driver_module

    for hz, count in [(250, 5), (100, 8), (1000, 2), (1000, 5), (250, 12)]:
        monkeypatch.setattr(driver_module, "kernel_tick_s", lambda hz=hz: 1 / hz)
        offsets = [write_offset(i, count) for i in range(count)]
        assert offsets[0] == 0.0 and offsets == sorted(set(offsets))
        assert offsets[-1] < 1 / hz / 2  # before the kernel's next tick
        spacing = offsets[1] - offsets[0]
        assert spacing == pytest.approx(min(WRITE_SPACING_S, 1 / hz / 2 / count))
    monkeypatch.setattr(driver_module, "kernel_tick_s", lambda: 0.0)  # not Linux: no tick known
    assert write_offset(3, 5) == pytest.approx(3 * WRITE_SPACING_S)


def test_the_only_output_reads_the_records_on_its_deadline_and_writes_them_at_once() -> None:
    """No lead: each tick wakes on its deadline (on the grid, from its epoch), makes its
    frame from the records then and writes it at once: never before the deadline, never
    from records read ahead of it (a lead would age every frame's records by itself). The
    readers pace on that deadline."""
    driver, on_grid = timed_writes(alone=True)
    assert len(on_grid) >= 60 and driver.lead is None
    for w in on_grid:
        assert w["pace"].deadline == w["start"] == w["deadline"] and on_the_grid(w["start"], 0.01)
        assert w["deadline"] <= w["woke"] <= w["made"] <= w["written"]


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
